"""Typed configuration: one frozen dataclass per section, every field documented with its unit
(``facility``: execution, camera, testbed, virtual testbed; each stage's own sections live in
its package, ``stages/<name>/config.py``, and ``pipeline/config.py`` gathers them all).

Resolution order (``loading.layered``): the workspace's saved ``W/config.toml``, or for a new
workspace (or an explicit ``--profile`` switch) the dataclass defaults and the profile shipped in
``core/profiles`` (``smoke``, ``default``, ``paper``); then ``--config FILE`` (its keys only);
then ``--set section.key=value``. The resolved configuration is written to ``W/config.toml``
when a command succeeds. Units follow docs/architecture.md section 3:
metres and radians (field names end in ``_m``, ``_rad``, ``_px``; quaternions ``_q`` are
Hamilton ``(w, x, y, z)``).
"""

from core.config.facility import (
    UNMODELLED_SOURCES,
    CameraConfig,
    FacilityConfig,
    RunConfig,
    TargetConfig,
    TestbedConfig,
    VirtualConfig,
    resize_camera_matrix,
)
from core.config.loading import (
    PROFILES,
    Override,
    layered,
    load_config,
    parse_override,
    profile_path,
    to_dict,
    with_overrides,
    write_config,
)
from core.config.model import FACILITY_SECTIONS, Config
from core.config.params import ConfigError, documented, param

__all__ = [
    "FACILITY_SECTIONS", "PROFILES", "UNMODELLED_SOURCES", "CameraConfig", "Config", "ConfigError", "FacilityConfig",
    "Override", "RunConfig", "TargetConfig", "TestbedConfig", "VirtualConfig", "documented", "layered",
    "load_config", "param", "parse_override",
    "profile_path", "resize_camera_matrix", "to_dict", "with_overrides", "write_config",
]
