"""``W/calibration.json``: what calibrate estimated and measured (docs/architecture.md
section 4). Written by calibrate; read by fuse (offsets, compliance, arms, sigmas), label,
render, evaluate and export (the camera), and report (Table 1).

Poses are ``Pose`` records ({q, t}); each source's offsets keep the names of their frames
(``OFFSET_KEYS``): the KUKA telemetry ends at the flanges (camee, targetee), motion capture
at the rigid bodies (camrb, targetrb). Table 1's records are ``manifests/sidecars/table1.py``,
the screening's ``manifests/sidecars/screening.py``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from manifests.sidecars.arm_fit import ChainFit
from manifests.sidecars.base import Fields, Pose, SidecarError, read, save
from manifests.sidecars.screening import Screening
from manifests.sidecars.table1 import Baseline, FusedColumn, Metrics
from manifests.workspace import Workspace

# 2: the arms' joint compliances (arm_kinematics); 3: metrics.cross_validation (the folds
# that could not determine the offsets, left out of the cross-validated means); 4: every
# arm from its URDF (arm_kinematics.chains; TRON's KR 16-2 record, arm_kinematics' own
# corrections, is gone); 5: each joint's lost motion (arm_kinematics.chains: robots[].lost_motion_rad and
# its parameters); 6: each compliant fixture's play (fixture_compliance.play_rad_by_fixture, and its
# parameters after the anisotropy's in arm_kinematics.chains); 7: what the arms' fit whitened
# the poses by (arm_kinematics.chains.residual_noise)
CALIBRATION_VERSION = 7
WRITER = "calibrate"
#: each source's (camera offset, target offset) key in calibration.json
OFFSET_KEYS = {"kuka": ("cam_from_camee", "target_from_targetee"), "vicon": ("cam_from_camrb", "target_from_targetrb")}


@dataclass(frozen=True)
class Intrinsics:
    """The camera of the labels: K (3 x 3, px), OpenCV distortion (5,), size (px), the
    calibration's RMS reprojection (px), and whether calibrate estimated them."""

    camera_matrix: tuple[tuple[float, ...], ...]
    dist: tuple[float, ...]
    width: int
    height: int
    rms_px: float
    estimated: bool

    def to_json(self) -> dict[str, Any]:
        return {"K": [list(row) for row in self.camera_matrix], "dist": list(self.dist), "width": self.width,
                "height": self.height, "rms_px": self.rms_px, "estimated": self.estimated}

    @classmethod
    def from_fields(cls, f: Fields) -> Intrinsics:
        f.only("K", "dist", "width", "height", "rms_px", "estimated")
        return cls(f.matrix("K", 3, 3), f.vector("dist", 5), f.integer("width", minimum=1),
                   f.integer("height", minimum=1), f.number("rms_px"), f.boolean("estimated"))


@dataclass(frozen=True)
class SigmaRecord:
    """A pose uncertainty: per-axis translation (3,) m, rotation rad, and pointing rad."""

    t_m: tuple[float, float, float]
    r_rad: float
    pointing_rad: float | None

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"sigma_t_m": list(self.t_m), "sigma_r_rad": self.r_rad}
        if self.pointing_rad is not None:
            out["sigma_pointing_rad"] = self.pointing_rad
        return out

    @classmethod
    def from_fields(cls, f: Fields) -> SigmaRecord:
        return cls(f.vector("sigma_t_m", 3), f.number("sigma_r_rad"),
                   f.number("sigma_pointing_rad") if f.optional("sigma_pointing_rad") else None)


@dataclass(frozen=True)
class FixtureCompliance:
    """The model fixtures' gravity sag (stages.common.rwhe.fixture_tilt), when calibrate
    estimated it: per fixture ``k`` (3,) rad and, with anisotropy, ``D_f`` (6,), and with
    the arms' kinematics its play ``w_f`` (rad, ``fixture_lag``; 0 where the captures did
    not show it); the tilts they imply over the calibration samples (rad)."""

    estimated: bool
    why: str | None  # the decision's reason (None: a file that did not record it)
    k_rad_by_fixture: dict[str, tuple[float, ...]] | None = None
    anisotropy_by_fixture: dict[str, tuple[float, ...]] | None = None
    tilt_rad_mean: float | None = None
    tilt_rad_max: float | None = None
    play_rad_by_fixture: dict[str, float] | None = None

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"estimated": self.estimated}
        if self.why is not None:
            out["why"] = self.why
        out["k_rad_by_fixture"] = None if self.k_rad_by_fixture is None else {
            name: list(k) for name, k in self.k_rad_by_fixture.items()}
        if self.estimated:
            out["anisotropy_by_fixture"] = None if self.anisotropy_by_fixture is None else {
                name: list(d) for name, d in self.anisotropy_by_fixture.items()}
            out["tilt_rad_mean"], out["tilt_rad_max"] = self.tilt_rad_mean, self.tilt_rad_max
            out["play_rad_by_fixture"] = None if self.play_rad_by_fixture is None else dict(self.play_rad_by_fixture)
        return out

    @classmethod
    def from_fields(cls, f: Fields) -> FixtureCompliance:
        f.only("estimated", "why", "k_rad_by_fixture", "anisotropy_by_fixture", "tilt_rad_mean", "tilt_rad_max",
               "play_rad_by_fixture")
        by_fixture: dict[str, dict[str, tuple[float, ...]] | None] = {}
        for key, length in (("k_rad_by_fixture", 3), ("anisotropy_by_fixture", 6)):
            entry = f.child(key) if f.optional(key) else None
            by_fixture[key] = None if entry is None else {name: entry.vector(name, length) for name in entry.data}
        return cls(f.boolean("estimated"), f.text("why") if f.optional("why") else None,
                   by_fixture["k_rad_by_fixture"], by_fixture["anisotropy_by_fixture"],
                   f.number("tilt_rad_mean") if f.optional("tilt_rad_mean") else None,
                   f.number("tilt_rad_max") if f.optional("tilt_rad_max") else None, _plays(f))


def _plays(f: Fields) -> dict[str, float] | None:
    """Each fixture's play (rad): a lag, so at least 0 (calibrate holds a negative fit at 0)."""
    entry = f.child("play_rad_by_fixture") if f.optional("play_rad_by_fixture") else None
    if entry is None:
        return None
    plays = {name: entry.number(name) for name in entry.data}
    for name, value in plays.items():
        if value < 0:
            raise entry.fail(name, "a play of at least 0 rad")
    return plays


@dataclass(frozen=True)
class ArmKinematics:
    """The arms' identified kinematics, when calibrate estimated them (``chains``,
    ``manifests/sidecars/arm_fit.py``), and why or why not."""

    estimated: bool
    why: str | None
    chains: ChainFit | None = None  # the facility's robots, from their URDFs

    def to_json(self) -> dict[str, Any]:
        return {"estimated": self.estimated, **({"why": self.why} if self.why is not None else {}),
                **({"chains": self.chains.to_json()} if self.chains is not None else {})}

    @classmethod
    def from_fields(cls, f: Fields) -> ArmKinematics:
        estimated = f.boolean("estimated")
        why = f.text("why") if f.optional("why") else None
        if not estimated:
            f.only("estimated", "why")
            return cls(False, why)
        f.only("estimated", "why", "chains")
        return cls(True, why, ChainFit.from_fields(f.child("chains")))

    @property
    def covariance(self) -> tuple[tuple[float, ...], ...]:
        return () if self.chains is None else self.chains.covariance


@dataclass(frozen=True)
class OffsetUncertainty:
    """How well a source's offsets are determined: the 1-sigma of ``cam_from_offset`` and of
    each fixture's ``target_from_offset`` (6,) each, rotation vector (rad) then translation
    (m) of their packed form (``stages.common.rwhe.pack``), their covariance (P, P) in that
    order (6 + 6 per fixture; with the arms fitted, marginal over the arms' parameters), and
    the directions the samples leave weakly determined, in words."""

    cam_from_offset_sigma: tuple[float, ...]
    target_from_offset_sigma_by_fixture: dict[str, tuple[float, ...]]
    covariance: tuple[tuple[float, ...], ...]
    weak: tuple[str, ...]

    def to_json(self) -> dict[str, Any]:
        return {"cam_from_offset_sigma": list(self.cam_from_offset_sigma),
                "target_from_offset_sigma_by_fixture": {k: list(v) for k, v in
                                                        self.target_from_offset_sigma_by_fixture.items()},
                "covariance": [list(row) for row in self.covariance], "weak": list(self.weak)}

    @classmethod
    def from_fields(cls, f: Fields) -> OffsetUncertainty:
        f.only("cam_from_offset_sigma", "target_from_offset_sigma_by_fixture", "covariance", "weak")
        by_fixture = f.child("target_from_offset_sigma_by_fixture")
        sigmas = {name: by_fixture.vector(name, 6) for name in by_fixture.data}
        size = 6 + 6 * len(sigmas)
        weak = f.raw("weak")
        if not isinstance(weak, list) or not all(isinstance(w, str) for w in weak):
            raise f.fail("weak", "a list of sentences")
        return cls(f.vector("cam_from_offset_sigma", 6), sigmas, f.matrix("covariance", size, size), tuple(weak))


@dataclass(frozen=True)
class SourceCalibration:
    """One source's calibrated offsets, fixture compliance, arm kinematics and sigmas."""

    source: str  # "kuka" or "vicon"
    cam_from_offset: Pose  # cam_from_camee (kuka) or cam_from_camrb (vicon)
    target_from_offset_by_fixture: dict[str, Pose]  # target_from_targetee / _targetrb per fixture
    fixture_compliance: FixtureCompliance
    arm_kinematics: ArmKinematics
    sigma: SigmaRecord
    samples: int
    outliers: tuple[str, ...]
    metrics: Metrics  # its column of Table 1
    opencv_shah_in_sample: Baseline | None = None  # None: several fixtures, which OpenCV's Shah cannot take
    offset_uncertainty: OffsetUncertainty | None = None

    @property
    def compliance_k_rad(self) -> dict[str, tuple[float, ...]]:
        return self.fixture_compliance.k_rad_by_fixture or {}

    @property
    def compliance_anisotropy(self) -> dict[str, tuple[float, ...]]:
        """Per fixture (6,): stages.common.rwhe.fixture_tilt's D_f; empty: isotropic."""
        return self.fixture_compliance.anisotropy_by_fixture or {}

    @property
    def compliance_play_rad(self) -> dict[str, float]:
        """Per fixture: stages.common.rwhe.fixture_lag's w_f; empty: no play."""
        return self.fixture_compliance.play_rad_by_fixture or {}

    def to_json(self) -> dict[str, Any]:
        z_key, x_key = OFFSET_KEYS[self.source]
        first = self.target_from_offset_by_fixture[sorted(self.target_from_offset_by_fixture)[0]]
        out = {z_key: self.cam_from_offset.to_json(), x_key: first.to_json(),
               f"{x_key}_by_fixture": {k: p.to_json() for k, p in self.target_from_offset_by_fixture.items()},
               "fixture_compliance": self.fixture_compliance.to_json(), "arm_kinematics": self.arm_kinematics.to_json(),
               **self.sigma.to_json(), "samples": self.samples, "outliers": list(self.outliers),
               "metrics": self.metrics.to_json()}
        if self.opencv_shah_in_sample is not None:
            out["opencv_shah_in_sample"] = self.opencv_shah_in_sample.to_json()
        if self.offset_uncertainty is not None:
            out["offset_uncertainty"] = self.offset_uncertainty.to_json()
        return out

    @classmethod
    def from_fields(cls, source: str, f: Fields) -> SourceCalibration:
        z_key, x_key = OFFSET_KEYS[source]
        f.only(z_key, x_key, f"{x_key}_by_fixture", "fixture_compliance", "arm_kinematics", "sigma_t_m",
               "sigma_r_rad", "sigma_pointing_rad", "samples", "outliers", "metrics", "opencv_shah_in_sample",
               "offset_uncertainty")
        by_fixture_fields = f.child(f"{x_key}_by_fixture")
        by_fixture = {name: by_fixture_fields.pose(name) for name in by_fixture_fields.data}
        if not by_fixture:
            raise f.fail(f"{x_key}_by_fixture", "at least one fixture")
        f.pose(x_key)
        compliance = FixtureCompliance.from_fields(f.child("fixture_compliance"))
        kinematics = ArmKinematics.from_fields(f.child("arm_kinematics"))
        outliers = f.raw("outliers")
        if not isinstance(outliers, list) or not all(isinstance(s, str) for s in outliers):
            raise f.fail("outliers", "a list of sample ids")
        shah = Baseline.from_fields(f.child("opencv_shah_in_sample")) if f.optional("opencv_shah_in_sample") else None
        uncertainty = (OffsetUncertainty.from_fields(f.child("offset_uncertainty"))
                       if f.optional("offset_uncertainty") else None)
        return cls(source, f.pose(z_key), by_fixture, compliance, kinematics, SigmaRecord.from_fields(f),
                   f.integer("samples", minimum=1), tuple(outliers), Metrics.from_fields(f.child("metrics")), shah,
                   uncertainty)


@dataclass(frozen=True)
class SolverRecord:
    """How the offsets were solved: ``calibrate.solver``'s method, the cross-validation's
    folds, the pattern (a ``stages.common.patterns.PatternSpec``'s JSON) and the fixtures."""

    method: str
    folds: int
    pattern: dict[str, Any]
    fixtures: tuple[str, ...]

    def to_json(self) -> dict[str, Any]:
        return {"method": self.method, "folds": self.folds, "pattern": self.pattern, "fixtures": list(self.fixtures)}

    @classmethod
    def from_fields(cls, f: Fields) -> SolverRecord:
        f.only("method", "folds", "pattern", "fixtures")
        pattern = f.child("pattern")
        pattern.text("kind")
        pattern.vector("size", 2)
        pattern.number("square_m", positive=True)
        fixtures = f.raw("fixtures")
        if not isinstance(fixtures, list) or not all(isinstance(name, str) for name in fixtures):
            raise f.fail("fixtures", "a list of fixture names")
        return cls(f.text("method"), f.integer("folds", minimum=2), pattern.data, tuple(fixtures))


#: how Table 1, the report and the logs name each source on TRON (the paper's names)
TRON_SOURCE_NAMES = {"kuka": "KUKA", "vicon": "Vicon"}


@dataclass(frozen=True)
class SessionSources:
    """The session calibrated: its backend, its measurement sources, and what the facility
    calls them where it is not TRON (``names``: source -> name; empty: the paper's)."""

    backend: str
    sources: tuple[str, ...]
    names: tuple[tuple[str, str], ...] = ()

    def name(self, source: str) -> str:
        """The source's name in tables and messages ("KUKA", "robots ur10_camera, ur5_target")."""
        return dict(self.names).get(source, TRON_SOURCE_NAMES.get(source, source))

    def to_json(self) -> dict[str, Any]:
        return {"backend": self.backend, "sources": list(self.sources),
                **({"names": dict(self.names)} if self.names else {})}

    @classmethod
    def from_fields(cls, f: Fields) -> SessionSources:
        f.only("backend", "sources", "names")
        sources = f.raw("sources")
        if not isinstance(sources, list) or not all(name in OFFSET_KEYS for name in sources):
            raise f.fail("sources", f"a list of {' or '.join(OFFSET_KEYS)}")
        names: tuple[tuple[str, str], ...] = ()
        if f.optional("names"):
            entry = f.child("names")
            entry.only(*OFFSET_KEYS)
            names = tuple((key, entry.text(key)) for key in OFFSET_KEYS if key in entry.data)
        return cls(f.text("backend"), tuple(sources), names)


@dataclass(frozen=True)
class Calibration:
    """``W/calibration.json``."""

    intrinsics: Intrinsics
    kuka: SourceCalibration
    vicon: SourceCalibration | None  # None: no motion capture in the session
    calibration_distance_m: float  # mean camera-to-target distance of the calibration captures
    calibration_lever_sq_m2: tuple[float, float, float]  # mean squared lever of the line of sight, per axis
    world_up: tuple[float, float, float]  # the up the fixture compliance was fitted with, robot world frame
    fused: FusedColumn | None  # Table 1's fused column (None: no motion capture)
    rejection: SigmaRecord | None  # spread of motion capture against the robots (the rejection test's sigma)
    solver: SolverRecord
    session: SessionSources
    screening: Screening  # what stages.calibrate.screening checked and set aside

    def source(self, name: str) -> SourceCalibration | None:
        return {"kuka": self.kuka, "vicon": self.vicon}[name]

    def to_json(self) -> dict[str, Any]:
        return {"version": CALIBRATION_VERSION, "intrinsics": self.intrinsics.to_json(), "kuka": self.kuka.to_json(),
                "vicon": None if self.vicon is None else self.vicon.to_json(),
                "calibration_distance_m": self.calibration_distance_m,
                "calibration_lever_sq_m2": list(self.calibration_lever_sq_m2), "world_up": list(self.world_up),
                "fused": None if self.fused is None else self.fused.to_json(),
                "rejection": None if self.rejection is None else self.rejection.to_json(),
                "solver": self.solver.to_json(), "session": self.session.to_json(),
                "screening": self.screening.to_json()}

    @classmethod
    def from_fields(cls, f: Fields) -> Calibration:
        f.only("version", "intrinsics", "kuka", "vicon", "calibration_distance_m", "calibration_lever_sq_m2",
               "world_up", "fused", "rejection", "solver", "session", "screening")
        vicon = SourceCalibration.from_fields("vicon", f.child("vicon")) if f.optional("vicon") else None
        fused = FusedColumn.from_fields(f.child("fused")) if f.optional("fused") else None
        if (vicon is None) != (fused is None) or (vicon is None) != (not f.optional("rejection")):
            raise SidecarError(f"{f.where}: keys vicon, fused and rejection: all null or all present")
        kuka = SourceCalibration.from_fields("kuka", f.child("kuka"))
        return cls(Intrinsics.from_fields(f.child("intrinsics")), kuka, vicon,
                   f.number("calibration_distance_m", positive=True), f.vector("calibration_lever_sq_m2", 3),
                   f.vector("world_up", 3), fused,
                   SigmaRecord.from_fields(f.child("rejection")) if f.optional("rejection") else None,
                   SolverRecord.from_fields(f.child("solver")), SessionSources.from_fields(f.child("session")),
                   Screening.from_fields(f.child("screening")))

    @classmethod
    def from_json(cls, data: dict[str, Any], where: str = "calibration.json") -> Calibration:
        return cls.from_fields(Fields(data, where, ""))


def write_calibration(workspace: Workspace, calibration: Calibration) -> None:
    save(workspace.calibration_path, calibration.to_json())


def read_calibration(workspace: Workspace) -> Calibration:
    """``W/calibration.json``, validated; a SidecarError that names the file and the key."""
    return read(workspace.calibration_path, CALIBRATION_VERSION, WRITER, Calibration.from_fields)
