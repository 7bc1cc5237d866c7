"""The robots' model choices in calibration: whether to estimate the model fixture's
compliance and the arms' kinematics, each with the reason recorded in ``calibration.json``."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from core.config import Config
from manifests import Workspace
from manifests.files import write_bytes_atomic
from manifests.sidecars import FixtureCompliance
from manifests.sidecars.arm_fit import ChainFit
from speedplus.errors import InputError
from stages.common import geometry as g
from stages.common import rwhe
from stages.common.robots.calibrated_urdf import calibrated_urdf
from stages.common.robots.facility import load_facility


def compliance_decision(config: Config, up: np.ndarray, fixtures: list[str]) -> tuple[bool, str]:
    """Whether to estimate the fixture compliance, and why (for calibration.json and the log).

    Observing ``k_f`` needs the up direction in the flange frame to span two axes for every
    fixture; otherwise the tilt is indistinguishable from the fixed offset ``X_f``."""
    c = config.calibrate
    if c.fixture_compliance == "off":
        return False, "calibrate.fixture_compliance = off"
    if c.solver == "shah":
        if c.fixture_compliance == "on":
            raise InputError("calibrate.fixture_compliance = on needs the frobenius or reprojection solver "
                             "(Shah's closed form has no compliance)")
        return False, "Shah's closed form has no compliance"
    spreads = {f: rwhe.gravity_spread(up[[i for i, name in enumerate(fixtures) if name == f]])
               for f in sorted(set(fixtures))}
    narrow = {f: s for f, s in spreads.items() if s < c.min_gravity_spread_rad}
    summary = ", ".join(f"{f} {np.degrees(s):.1f} deg" for f, s in spreads.items())
    if not narrow:
        return True, f"the target flange's attitude to gravity spreads by {summary}"
    message = (f"the target flange's attitude to gravity spreads by {summary}, under "
               f"{np.degrees(c.min_gravity_spread_rad):.1f} deg for {', '.join(narrow)}")
    if c.fixture_compliance == "on":
        raise rwhe.DegenerateError(f"kuka calibration: {message}; add calibration captures with the model "
                                   "presented at other attitudes, or set calibrate.fixture_compliance = off")
    return False, message


def arm_decision(config: Config, readings: object | None) -> tuple[bool, str]:
    """Whether to calibrate the arms' kinematics, and why (for calibration.json)."""
    mode = config.calibrate.arm_kinematics
    if mode == "off":
        return False, "calibrate.arm_kinematics = off"
    if readings is None:
        if mode == "on":
            raise InputError("calibrate.arm_kinematics = on: the calibration captures lack the robots' encoder "
                             "readings (kuka_camera_joints_rad, kuka_target_joints_rad, kuka_rail_m)")
        return False, "the captures have no encoder readings"
    if config.calibrate.solver == "shah":
        if mode == "on":
            raise InputError("calibrate.arm_kinematics = on needs the frobenius or reprojection solver")
        return False, "Shah's closed form has no arm kinematics"
    return True, f"encoder readings of {len(readings.rail_m)} calibration captures, the arms' URDFs"


def compliance_record(solution: rwhe.Solution, up: np.ndarray | None, fixtures: list[str],
                      note: str, play_why: str = "") -> FixtureCompliance:
    """The estimated compliances ``k_f`` (rad), the plays ``w_f`` (rad; with why where they
    were not fitted, ``play_why``) and the tilts they imply over the samples."""
    if not solution.compliance or up is None:
        return FixtureCompliance(False, note)
    k = np.stack([solution.compliance[f] for f in fixtures])
    d = np.stack([solution.anisotropy[f] for f in fixtures]) if solution.anisotropy else None
    tilt = np.linalg.norm(g.matrix_to_rotvec(rwhe.fixture_tilt(up, k, d)[:, :3, :3]), axis=1)
    return FixtureCompliance(
        True, f"{note}; fixture play: {play_why}" if play_why else note,
        {f: tuple(float(v) for v in k_f) for f, k_f in solution.compliance.items()},
        {f: tuple(float(v) for v in d_f) for f, d_f in solution.anisotropy.items()} if solution.anisotropy else None,
        float(tilt.mean()), float(tilt.max()),
        {f: float(w) for f, w in solution.play.items()} if solution.play else None)


def write_robot_urdfs(config: Config, workspace: Workspace, chains: ChainFit | None) -> None:
    """``W/robots/<robot>.urdf`` of each facility robot whose kinematics were fitted, and
    none left from an earlier calibration when they were not."""
    folder = workspace.root / "robots"
    written = set()
    if chains is not None:
        facility = load_facility(Path(config.facility.path) if config.facility.path else None)
        for correction in chains.robots:
            spec = next(robot.spec for robot in facility.robots if robot.spec.name == correction.robot)
            path = workspace.robot_urdf_path(correction.robot)
            path.parent.mkdir(parents=True, exist_ok=True)
            note = (f"{spec.name} of facility {facility.spec.name} as calibrated by speedplus calibrate "
                    f"(W/calibration.json, kuka.arm_kinematics.chains) from {Path(spec.urdf).name}")
            write_bytes_atomic(path, calibrated_urdf(facility.directory / spec.urdf, spec.flange_link, correction,
                                                     note).encode())
            written.add(path.name)
    for stale in sorted(folder.glob("*.urdf")) if folder.is_dir() else ():
        if stale.name not in written:
            stale.unlink()


def source_names(config: Config) -> tuple[tuple[str, str], ...]:
    """What Table 1 and the report call the sources on a facility folder: its robots by
    name and its motion capture (none: TRON, named as the paper names them)."""
    if not config.facility.path:
        return ()
    facility = load_facility(Path(config.facility.path))
    return (("kuka", " + ".join(robot.spec.name for robot in facility.robots)), ("vicon", "motion capture"))
