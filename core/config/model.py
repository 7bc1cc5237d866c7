"""The whole configuration: one typed section per field."""

from __future__ import annotations

import typing
from dataclasses import dataclass, field
from typing import Any

from core.config.facility import (
    CameraConfig,
    FacilityConfig,
    RunConfig,
    TargetConfig,
    TestbedConfig,
    VirtualConfig,
)
from core.config.stages import (
    AcquireConfig,
    CalibrateConfig,
    EvaluateConfig,
    ExportConfig,
    FuseConfig,
    LabelConfig,
    PlanConfig,
    ReferenceConfig,
    RenderConfig,
    TrajectoryConfig,
)


@dataclass(frozen=True)
class Config:
    """The whole configuration of a run."""

    profile: str = "default"
    run: RunConfig = field(default_factory=RunConfig)
    target: TargetConfig = field(default_factory=TargetConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    facility: FacilityConfig = field(default_factory=FacilityConfig)
    testbed: TestbedConfig = field(default_factory=TestbedConfig)
    plan: PlanConfig = field(default_factory=PlanConfig)
    trajectory: TrajectoryConfig = field(default_factory=TrajectoryConfig)
    acquire: AcquireConfig = field(default_factory=AcquireConfig)
    virtual: VirtualConfig = field(default_factory=VirtualConfig)
    calibrate: CalibrateConfig = field(default_factory=CalibrateConfig)
    fuse: FuseConfig = field(default_factory=FuseConfig)
    label: LabelConfig = field(default_factory=LabelConfig)
    render: RenderConfig = field(default_factory=RenderConfig)
    reference: ReferenceConfig = field(default_factory=ReferenceConfig)
    evaluate: EvaluateConfig = field(default_factory=EvaluateConfig)
    export: ExportConfig = field(default_factory=ExportConfig)

    def section(self, name: str) -> Any:
        return getattr(self, name)


#: section name -> its dataclass, read off ``Config`` (every field but ``profile``)
SECTION_TYPES: dict[str, type] = {name: hint for name, hint in typing.get_type_hints(Config).items()
                                  if name != "profile"}

