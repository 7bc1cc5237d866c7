"""``W/fusion.json``: the dataset session's a posteriori variance factor, which scales the
calibrated sigmas in fuse, the offset between the sources it removed before fusing, and
what else shaped the sigmas (motion capture's marker noise and fit, a short session's widening)
(docs/architecture.md section 6). Written by fuse; read by the
benchmarks and tests that judge the sigmas."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from manifests.sidecars.base import Fields, read, save
from manifests.workspace import Workspace

#: 3: the session offset; 4: the factor as measured beside the one applied; 5: the sigmas'
#: notes; 6: the rejection test's count and its bound; 7: each source's own factor
FUSION_VERSION = 7
#: where a position axis's label comes from: both sources fused, or one of them alone
AXIS_SOURCES = ("fused", "kuka", "vicon")
SOURCES = ("kuka", "vicon")


@dataclass(frozen=True)
class FusionRecord:
    """The variance factor applied per position axis (3,) and for rotation (sigma
    multipliers, 1 = the calibrated sigmas), the captures it was measured on, why, the
    rejection k, per camera axis where the labels' position comes from (``AXIS_SOURCES``)
    and why, and the position factor as measured on the differences, session offset
    included, which the consistency test judged (the applied one is measured with the
    offset removed)."""

    factor_t: tuple[float, float, float]
    factor_r: float
    samples: int
    why: str
    rejection_k: float
    axis_sources: tuple[str, str, str] = ("fused", "fused", "fused")
    axis_why: str = ""
    measured_t: tuple[float, float, float] = (1.0, 1.0, 1.0)
    #: per camera axis (m): the median by which motion capture's position exceeded the
    #: robots' over the session's two-source captures, removed from the source named in
    #: ``offset_from`` before fusing; its standard error; why (zeros when not estimated)
    offset_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    offset_sigma_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    offset_from: tuple[str, str, str] = ("vicon", "vicon", "vicon")
    offset_why: str = ""
    #: motion capture's marker noise (m) measured from its fits' residuals (None: not
    #: recorded), and what else shaped the sigmas (its fit's geometry, a short session's widening)
    marker_sigma_m: float | None = None
    sigma_why: str = ""
    #: two-source captures the rejection test refused, and the count that consistent
    #: sources stay under at the tails' test level (None: the session was too short to test)
    rejected: int = 0
    rejected_bound: int | None = None
    #: per camera axis, the factor that scales each source's own sigma: ``factor_t`` on a
    #: fused axis, the source's expected share of the excess on an axis kept from one source
    #: (stages/fuse/kept_axes.py); the kept source's is its labels'. None: ``factor_t``
    kuka_t: tuple[float, float, float] | None = None
    vicon_t: tuple[float, float, float] | None = None

    def __post_init__(self) -> None:
        for name in ("kuka_t", "vicon_t"):  # no kept axis: each source's factor is the common one
            if getattr(self, name) is None:
                object.__setattr__(self, name, tuple(self.factor_t))

    def source_factor(self, source: str) -> tuple[float, float, float]:
        """The factors (per camera axis) of ``source`` ("kuka" or "vicon")."""
        return self.kuka_t if source == "kuka" else self.vicon_t

    def to_json(self) -> dict[str, Any]:
        return {"version": FUSION_VERSION,
                "variance_factor": {"t": list(self.factor_t), "measured_t": list(self.measured_t), "r": self.factor_r,
                                    "samples": self.samples,
                                    "by_source": {"kuka": list(self.kuka_t), "vicon": list(self.vicon_t)}},
                "why": self.why, "rejection_k": self.rejection_k,
                "axes": {"sources": list(self.axis_sources), "why": self.axis_why, "rejected": self.rejected,
                         "rejected_bound": self.rejected_bound},
                "offset": {"t_m": list(self.offset_m), "sigma_m": list(self.offset_sigma_m),
                           "removed_from": list(self.offset_from), "why": self.offset_why},
                "sigmas": {"marker_sigma_m": self.marker_sigma_m, "why": self.sigma_why}}

    @classmethod
    def from_fields(cls, f: Fields) -> FusionRecord:
        f.only("version", "variance_factor", "why", "rejection_k", "axes", "offset", "sigmas")
        factor = f.child("variance_factor")
        factor.only("t", "measured_t", "r", "samples", "by_source")
        t, measured_t = factor.vector("t", 3), factor.vector("measured_t", 3)
        by_source = factor.child("by_source")
        by_source.only(*SOURCES)
        kuka_t, vicon_t = by_source.vector("kuka", 3), by_source.vector("vicon", 3)
        for fields, key, value in ((factor, "t", t), (factor, "measured_t", measured_t), (by_source, "kuka", kuka_t),
                                   (by_source, "vicon", vicon_t)):
            if min(value) <= 0:
                raise fields.fail(key, "three positive factors")
        axes = f.child("axes")
        axes.only("sources", "why", "rejected", "rejected_bound")
        sources = axes.raw("sources")
        if not isinstance(sources, list) or len(sources) != 3 or any(s not in AXIS_SOURCES for s in sources):
            raise axes.fail("sources", f"a list of three of {', '.join(AXIS_SOURCES)}")
        offset = f.child("offset")
        offset.only("t_m", "sigma_m", "removed_from", "why")
        removed_from = offset.raw("removed_from")
        if not isinstance(removed_from, list) or len(removed_from) != 3 or any(s not in SOURCES for s in removed_from):
            raise offset.fail("removed_from", f"a list of three of {', '.join(SOURCES)}")
        if min(offset.vector("sigma_m", 3)) < 0:
            raise offset.fail("sigma_m", "three standard errors >= 0")
        sigmas = f.child("sigmas")
        sigmas.only("marker_sigma_m", "why")
        marker = None if sigmas.raw("marker_sigma_m") is None else sigmas.number("marker_sigma_m", positive=True)
        return cls(t, factor.number("r", positive=True), factor.integer("samples"), f.text("why"),
                   f.number("rejection_k", positive=True), tuple(sources), axes.text("why"), measured_t,
                   offset.vector("t_m", 3), offset.vector("sigma_m", 3), tuple(removed_from), offset.text("why"),
                   marker, sigmas.text("why"), axes.integer("rejected"),
                   None if axes.raw("rejected_bound") is None else axes.integer("rejected_bound"),
                   tuple(kuka_t), tuple(vicon_t))


def write_fusion(workspace: Workspace, record: FusionRecord) -> None:
    save(workspace.fusion_path, record.to_json())


def read_fusion(workspace: Workspace) -> FusionRecord:
    return read(workspace.fusion_path, FUSION_VERSION, "fuse", FusionRecord.from_fields)
