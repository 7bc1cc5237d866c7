"""``W/trajectories.json``: the rendezvous sequences a trajectory plan was made from
(``plan.mode = "trajectory"``, docs/formats.md). Written by plan; read by export (SHIRT's
``metadata.json``) and evaluate (the tracking filter's dynamics).

Units: metres, seconds, radians, kg; ECI as in ``stages/common/sun.py``; the body frame is
the target's T at full scale. ``roe`` are D'Amico's quasi-nonsingular relative orbital
elements (dimensionless, ``stages/common/orbits.py``), ``roe_m`` the same times the chief's
semi-major axis.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from manifests.schema import NAME_PATTERN
from manifests.sidecars.base import Fields, SidecarError, read, save
from manifests.workspace import Workspace

TRAJECTORIES_VERSION = 1
ELEMENT_KEYS = ("a_m", "e", "i_rad", "raan_rad", "argp_rad", "mean_anomaly_rad")
ROE_KEYS = ("da", "dlambda", "dex", "dey", "dix", "diy")


@dataclass(frozen=True)
class SequenceRecord:
    """One sequence: where its frames came from, enough to propagate it again."""

    sequence_id: str
    preset: str
    epoch_utc: str  # ISO 8601, "Z"
    frames: int
    cam_step_s: float
    first_sample_id: str  # the plan row of frame 0; frame k is the k-th dataset row after it
    chief: dict[str, float]  # ELEMENT_KEYS
    roe: tuple[float, ...]  # (6,) ROE_KEYS order, dimensionless
    roe_m: tuple[float, ...]  # (6,) a_chief * roe
    mass_kg: float
    centre_of_mass_m: tuple[float, float, float]  # body frame T, full scale
    inertia_kgm2: tuple[tuple[float, ...], ...]  # (3, 3) about the centre of mass, body frame
    inertia_source: str  # "mesh shell" or "declared"
    omega0_rad_s: tuple[float, float, float]  # body frame, at frame 0
    eci_from_target_q0: tuple[float, float, float, float]  # at frame 0
    pointing_bias_rad: tuple[float, float]  # the camera's constant pointing error (x, y about its axes)
    relative_motion_model: str
    attitude_model: str
    sun_model: str

    def to_json(self) -> dict[str, Any]:
        return {
            "sequence_id": self.sequence_id, "preset": self.preset, "epoch_utc": self.epoch_utc,
            "frames": self.frames, "cam_step_s": self.cam_step_s, "first_sample_id": self.first_sample_id,
            "chief": dict(self.chief), "roe": list(self.roe), "roe_m": list(self.roe_m), "mass_kg": self.mass_kg,
            "centre_of_mass_m": list(self.centre_of_mass_m), "inertia_kgm2": [list(r) for r in self.inertia_kgm2],
            "inertia_source": self.inertia_source, "omega0_rad_s": list(self.omega0_rad_s),
            "eci_from_target_q0": list(self.eci_from_target_q0), "pointing_bias_rad": list(self.pointing_bias_rad),
            "relative_motion_model": self.relative_motion_model, "attitude_model": self.attitude_model,
            "sun_model": self.sun_model,
        }

    @classmethod
    def from_fields(cls, f: Fields) -> SequenceRecord:
        f.only(*cls.__dataclass_fields__)
        if not NAME_PATTERN.fullmatch(f.text("sequence_id")):  # it names export folders
            raise f.fail("sequence_id", "a name (a-z, 0-9, _ and -)")
        chief = f.child("chief")
        chief.only(*ELEMENT_KEYS)
        return cls(
            f.text("sequence_id"), f.text("preset"), f.text("epoch_utc"), f.integer("frames", minimum=1),
            f.number("cam_step_s", positive=True), f.text("first_sample_id"),
            {key: chief.number(key) for key in ELEMENT_KEYS}, f.vector("roe", 6), f.vector("roe_m", 6),
            f.number("mass_kg", positive=True), f.vector("centre_of_mass_m", 3), f.matrix("inertia_kgm2", 3, 3),
            f.text("inertia_source", ("mesh shell", "declared")), f.vector("omega0_rad_s", 3),
            f.vector("eci_from_target_q0", 4), f.vector("pointing_bias_rad", 2), f.text("relative_motion_model"),
            f.text("attitude_model"), f.text("sun_model"))


@dataclass(frozen=True)
class TrajectoriesRecord:
    """Every planned sequence, in plan order."""

    sequences: tuple[SequenceRecord, ...]

    def to_json(self) -> dict[str, Any]:
        return {"version": TRAJECTORIES_VERSION, "sequences": [s.to_json() for s in self.sequences]}

    @classmethod
    def from_fields(cls, f: Fields) -> TrajectoriesRecord:
        f.only("version", "sequences")
        rows = f.raw("sequences")
        if not isinstance(rows, list) or not rows:
            raise f.fail("sequences", "a non-empty list of sequences")
        inner = Fields({str(i): row for i, row in enumerate(rows)}, f.where, "sequences.")
        sequences = tuple(SequenceRecord.from_fields(inner.child(str(i))) for i in range(len(rows)))
        names = [s.sequence_id for s in sequences]
        if len(set(names)) != len(names):
            raise SidecarError(f"{f.where}: key sequences: sequence ids repeat ({', '.join(names)})")
        return cls(sequences)

    def sequence(self, sequence_id: str) -> SequenceRecord:
        for sequence in self.sequences:
            if sequence.sequence_id == sequence_id:
                return sequence
        raise KeyError(sequence_id)


def write_trajectories(workspace: Workspace, record: TrajectoriesRecord) -> None:
    save(workspace.trajectories_path, record.to_json())


def read_trajectories(workspace: Workspace) -> TrajectoriesRecord:
    return read(workspace.trajectories_path, TRAJECTORIES_VERSION, "plan (plan.mode = trajectory)",
                TrajectoriesRecord.from_fields)
