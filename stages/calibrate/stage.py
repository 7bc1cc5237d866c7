"""The calibrate stage's ``run`` and ``resolve`` (what the stage does: the package's docstring).

Writes ``W/calibration.json`` and the ``calibration_samples`` manifest.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import numpy as np
import pyarrow as pa

from core import progress
from core.config import Config
from core.stage_io import Resolved
from manifests import Workspace, open_sink, read_keys, read_manifest, read_marker
from manifests import clear as clear_manifest
from manifests.sidecars import (
    SOURCES,
    Calibration,
    Screening,
    Session,
    SessionSources,
    SolverRecord,
    read_session,
    write_calibration,
)
from speedplus.errors import InputError, RefusalError
from stages.calibrate import observations as obs
from stages.calibrate import per_source, screening
from stages.calibrate.fitting import load_truth
from stages.calibrate.per_source import SourceFit, markers_of
from stages.calibrate.robots import arm_decision, compliance_decision, source_names, write_robot_urdfs
from stages.common import geometry as g
from stages.common import rwhe
from stages.common.fusion import lever_sq
from stages.common.patterns import PatternSpec, pattern_from_table
from stages.common.robots import lost_motion
from stages.common.sources import measured_b
from stages.common.tables import print_table

__all__ = ["arm_decision", "compliance_decision", "resolve", "run"]


def preflight(config: Config, workspace: Workspace | None = None) -> None:
    """What can be refused before the chain's first stage runs: a virtual session's plan
    that draws fewer calibration samples than calibrate needs (``calibrate.min_samples``)
    would be planned and captured only to be refused here."""
    planned = config.plan.n_calibration
    if config.acquire.backend == "virtual" and planned < config.calibrate.min_samples:
        raise InputError(f"plan.n_calibration = {planned}: calibrate needs at least {config.calibrate.min_samples} "
                         "usable calibration samples (calibrate.min_samples), and screening may drop some; plan "
                         f"{config.calibrate.min_samples} or more")


def resolve(config: Config, workspace: Workspace | None = None) -> Resolved:
    """Reads the calibration session's captures (and ``W/session.json``); writes
    ``calibration_samples`` and ``W/calibration.json``."""
    return Resolved(("captures",), ("calibrate", "testbed", "facility.path"), {}, ("calibration_samples",))


def run(config: Config, workspace: Workspace) -> pa.Table:
    session = read_session(workspace)
    if not session.pattern:
        raise InputError(f"{workspace.session_path}: the capture session defines no calibration pattern")
    spec = pattern_from_table(session.pattern, str(workspace.session_path))
    # in sample_id order: acquire writes rows as its workers finish, and the folds, the
    # solvers' sums and the screening's medians must not depend on that
    session_rows = [r for r in read_manifest(workspace, "captures").to_pylist() if r["session"] == "calibration"]
    captures = sorted((r for r in lost_motion.move_directions(session_rows) if r["status"] == "ok"),
                      key=lambda r: r["sample_id"])
    if read_marker(workspace, "plan") is not None and session.backend == "virtual":
        unknown = sorted({r["sample_id"] for r in captures} - read_keys(workspace, "plan"))
        if unknown:
            raise InputError(f"captures: sample(s) {', '.join(unknown[:5])} are not in the plan")
    observations = obs.detect_all(workspace, captures, spec, config.calibrate.min_corners)
    by_id = {r["sample_id"]: r for r in captures}
    try:
        calibration, fits = _calibrate(config, workspace, session, spec, by_id, observations)
    except InputError as error:  # refused: the images' reasons are still what the user needs
        _write_samples(config, workspace, observations, by_id, {}, session.sources)
        said = screening.advice_for(str(error), session.backend)
        raise RefusalError(f"{said}{_dropped(observations)}", keep=("calibration_samples",)) from None
    write_calibration(workspace, calibration)
    write_robot_urdfs(config, workspace, calibration.kuka.arm_kinematics.chains)
    _write_samples(config, workspace, observations, by_id, fits, session.sources)
    print_table(calibration)
    return read_manifest(workspace, "calibration_samples")


def _dropped(observations: list[obs.Observation], most: int = 10) -> str:
    """The images screening dropped, with why, for the refusal's message (up to ``most``)."""
    dropped = [o for o in observations if o.reason is not None]
    if not dropped:
        return "; screening dropped no image"
    listed = "; ".join(f"{o.sample_id}: {o.reason}" for o in dropped[:most])
    more = f" and {len(dropped) - most} more" if len(dropped) > most else ""
    return (f"; screening dropped {len(dropped)} of {len(observations)} images ({listed}{more}); every image's "
            "reason is in the calibration_samples manifest")


def _write_samples(config: Config, workspace: Workspace, observations: list[obs.Observation],
                   by_id: dict[str, dict[str, Any]], fits: dict[str, SourceFit], sources: Iterable[str]) -> None:
    """One ``calibration_samples`` row per capture, each unusable one with its reason, and
    each that a source could not use with that source's reason; the manifest is rewritten
    whole (a calibration is all or nothing)."""
    clear_manifest(workspace, "calibration_samples")
    with open_sink(workspace, "calibration_samples", config.run.part_rows) as sink:
        for o in observations:
            reason = o.reason
            flagged = [s for s in SOURCES if s in fits and o.sample_id in fits[s].calibration.outliers]
            if reason is None and flagged:
                reason = "outlier of " + " and ".join(flagged) + " (excluded from that source's calibration)"
            if reason is None and "vicon" in sources and measured_b(by_id[o.sample_id], "vicon") is None:
                reason = f"motion capture did not measure it ({markers_of(by_id[o.sample_id])}): robots only"
            row = {"sample_id": o.sample_id, "fixture": by_id[o.sample_id]["fixture"], "corners": len(o.ids),
                   "used": o.cam_from_target is not None, "reason": reason, "pnp_rms_px": o.rms_px,
                   "corners_px": np.asarray(o.pixels, float) if len(o.ids) else None,
                   "corners_target_m": np.asarray(o.object_points, float) if len(o.ids) else None}
            for prefix, pose in (("cam_from_target_cal", o.cam_from_target),
                                 *((f"{s}_cam_from_target", fits[s].in_sample.get(o.sample_id) if s in fits else None)
                                   for s in SOURCES)):
                row.update(g.pose_columns(prefix, pose))
            sink.add(row)


def _calibrate(config: Config, workspace: Workspace, session: Session, spec: PatternSpec,
               by_id: dict[str, dict[str, Any]], observations: list[obs.Observation]
               ) -> tuple[Calibration, dict[str, SourceFit]]:
    """Intrinsics, screening, every source's fit, Table 1's fused column: the calibration."""
    intrinsics = _intrinsics(config, workspace, session, spec, observations)
    obs.solve_pnp(observations, intrinsics)
    checks = _screen(config, spec, by_id, observations, intrinsics)
    dropped = [o for o in observations if o.cam_from_target is None]
    progress.note(f"calibrate: {len(observations)} calibration captures, the pattern posed on "
                  f"{len(observations) - len(dropped)}" + "".join(f"; {o.sample_id}: {o.reason}" for o in dropped[:3])
                  + (f" and {len(dropped) - 3} more (calibration_samples says why)" if len(dropped) > 3 else ""))
    truth = load_truth(workspace)
    fits = {}
    for source in SOURCES:
        if source in session.sources:
            samples = per_source.gather(config, workspace, source, observations, by_id)
            fits[source] = per_source.fit(config, source, samples, intrinsics, truth)[0]
    fused, rejection = (per_source.fused_column(observations, fits, intrinsics, truth) if "vicon" in fits
                        else (None, None))
    pnp_positions = np.array([o.cam_from_target[:3, 3] for o in observations if o.cam_from_target is not None])
    calibration = Calibration(
        intrinsics=intrinsics.to_record(), kuka=fits["kuka"].calibration,
        vicon=fits["vicon"].calibration if "vicon" in fits else None,
        calibration_distance_m=float(np.mean(np.linalg.norm(pnp_positions, axis=1))),
        calibration_lever_sq_m2=tuple(np.mean(lever_sq(pnp_positions), axis=0).tolist()),
        world_up=tuple(float(v) for v in config.calibrate.world_up), fused=fused, rejection=rejection,
        solver=SolverRecord(config.calibrate.solver, config.calibrate.folds, spec.to_json(),
                            tuple(sorted({by_id[o.sample_id]["fixture"] for o in observations}))),
        session=SessionSources(session.backend, tuple(session.sources), source_names(config)),
        screening=Screening.of(checks))
    return calibration, fits


def _intrinsics(config: Config, workspace: Workspace, session: Session, spec: PatternSpec,
                observations: list[obs.Observation]) -> obs.EstimatedCamera:
    """The session's camera (``calibrate.intrinsics`` fixed, or auto with one given), else
    estimated from the detections and checked."""
    camera = session.camera
    fixed = config.calibrate.intrinsics == "fixed" or (config.calibrate.intrinsics == "auto" and camera.camera_matrix)
    if fixed:
        if not camera.camera_matrix:
            raise InputError(f"{workspace.session_path}: calibrate.intrinsics=fixed but the session has no camera K")
        return obs.EstimatedCamera(np.array(camera.camera_matrix, float), np.array(camera.dist, float),
                                   camera.width, camera.height, 0.0, False)
    intrinsics = obs.estimate_intrinsics(observations, camera.width, camera.height, k=config.calibrate.outlier_k)
    screening.check_intrinsics(intrinsics, observations, spec, config.calibrate)
    return intrinsics


def _screen(config: Config, spec: PatternSpec, by_id: dict[str, dict[str, Any]],
            observations: list[obs.Observation], intrinsics: obs.EstimatedCamera) -> dict[str, Any]:
    """The robots' motions diverse enough; each image's pattern facing, its corners in the
    right order, the motions consistent with the PnP poses: what was checked and dropped."""
    robot_b = {o.sample_id: measured_b(by_id[o.sample_id], "kuka") for o in observations}
    fixture_of = {sample_id: row["fixture"] for sample_id, row in by_id.items()}
    posed = [o.sample_id for o in observations if o.cam_from_target is not None]
    rwhe.check_diversity(np.stack([robot_b[s] for s in posed]) if posed else np.zeros((0, 4, 4)),
                         [fixture_of[s] for s in posed], config.calibrate.min_samples,
                         config.calibrate.min_rotation_spread_rad, "kuka calibration")
    return {"facing": screening.check_facing(observations, spec),
            "corner_order": screening.order_corners(observations, robot_b, fixture_of, spec, intrinsics,
                                                    config.calibrate),
            "motions": screening.check_motions(observations, robot_b, fixture_of, spec, config.calibrate,
                                               "the pose file's declared unit")}
