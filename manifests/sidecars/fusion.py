"""``W/fusion.json``: the dataset session's a posteriori variance factor, which scales the
calibrated sigmas in fuse (docs/architecture.md section 6). Written by fuse; read by the
benchmarks and tests that judge the sigmas."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from manifests.sidecars.base import Fields, read, save
from manifests.workspace import Workspace

FUSION_VERSION = 2
#: where a position axis's label comes from: both sources fused, or one of them alone
AXIS_SOURCES = ("fused", "kuka", "vicon")


@dataclass(frozen=True)
class FusionRecord:
    """The variance factor per position axis (3,) and for rotation (sigma multipliers, 1 =
    the calibrated sigmas), the captures it was measured on, why, the rejection k, and per
    camera axis where the labels' position comes from (``AXIS_SOURCES``) and why."""

    factor_t: tuple[float, float, float]
    factor_r: float
    samples: int
    why: str
    rejection_k: float
    axis_sources: tuple[str, str, str] = ("fused", "fused", "fused")
    axis_why: str = ""

    def to_json(self) -> dict[str, Any]:
        return {"version": FUSION_VERSION,
                "variance_factor": {"t": list(self.factor_t), "r": self.factor_r, "samples": self.samples},
                "why": self.why, "rejection_k": self.rejection_k,
                "axes": {"sources": list(self.axis_sources), "why": self.axis_why}}

    @classmethod
    def from_fields(cls, f: Fields) -> FusionRecord:
        f.only("version", "variance_factor", "why", "rejection_k", "axes")
        factor = f.child("variance_factor")
        factor.only("t", "r", "samples")
        t = factor.vector("t", 3)
        if min(t) <= 0:
            raise factor.fail("t", "three positive factors")
        axes = f.child("axes")
        axes.only("sources", "why")
        sources = axes.raw("sources")
        if not isinstance(sources, list) or len(sources) != 3 or any(s not in AXIS_SOURCES for s in sources):
            raise axes.fail("sources", f"a list of three of {', '.join(AXIS_SOURCES)}")
        return cls(t, factor.number("r", positive=True), factor.integer("samples"), f.text("why"),
                   f.number("rejection_k", positive=True), tuple(sources), axes.text("why"))


def write_fusion(workspace: Workspace, record: FusionRecord) -> None:
    save(workspace.fusion_path, record.to_json())


def read_fusion(workspace: Workspace) -> FusionRecord:
    return read(workspace.fusion_path, FUSION_VERSION, "fuse", FusionRecord.from_fields)
