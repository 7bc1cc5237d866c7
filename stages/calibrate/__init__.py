"""The calibrate stage: offsets of every measurement source, their uncertainty, the
rejection thresholds of motion capture, and the paper's Table 1 (in-sample, k-fold
cross-validated, and against the hidden truth when there is one).

Writes ``W/calibration.json`` and the ``calibration_samples`` manifest.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pyarrow as pa

from manifests import Workspace, open_sink, read_keys, read_manifest, read_success
from manifests import clear as clear_manifest
from manifests.sidecars import SOURCES, Calibration, Session, SourceCalibration, read_session, write_calibration
from pipeline import progress
from pipeline.config import Config
from pipeline.stage_io import Resolved
from speedplus.errors import InputError, RefusalError
from stages.calibrate import observations as obs
from stages.calibrate import screening
from stages.calibrate.robots import arm_decision, compliance_decision, compliance_json
from stages.common import arms, rwhe
from stages.common import geometry as g
from stages.common.fusion import Sigma, fuse, lever_sq, sigma_between, without_reference_noise
from stages.common.json_arrays import record
from stages.common.patterns import PatternSpec, pattern_from_table
from stages.common.sources import measured_b, up_targetee
from stages.common.tables import print_table
from stages.common.workspace_target import workspace_target


def metrics(predicted: np.ndarray, reference: np.ndarray, observations: list[obs.Observation],
            intrinsics: obs.EstimatedCamera, reference_pixels: list[np.ndarray] | None = None
            ) -> dict[str, list[float]]:
    """E_T, E_R, E_p (paper eqs.) as [mean, std]. E_p is the RMS distance of the corners
    projected with ``predicted`` from the detected corners (or from ``reference_pixels``)."""
    e_t = np.linalg.norm(predicted[:, :3, 3] - reference[:, :3, 3], axis=1)
    e_r = g.angular_distance(predicted[:, :3, :3], reference[:, :3, :3])
    e_p = []
    for k, (pose, o) in enumerate(zip(predicted, observations, strict=True)):
        projected = g.project(pose, o.object_points, intrinsics.camera_matrix, intrinsics.dist)
        target = o.pixels if reference_pixels is None else reference_pixels[k]
        e_p.append(np.sqrt(np.mean(np.sum((projected - target) ** 2, axis=1))))
    return {name: [float(np.mean(v)), float(np.std(v))] for name, v in
            (("E_T_m", e_t), ("E_R_rad", e_r), ("E_p_px", np.array(e_p)))}


def solve(config: Config, a: np.ndarray, b: np.ndarray, fixtures: list[str], used: list[obs.Observation],
          intrinsics: obs.EstimatedCamera, up: np.ndarray | None = None, method: str | None = None) -> rwhe.Solution:
    """Offsets from ``A`` (PnP) and ``B`` (N, 4, 4); ``up`` (N, 3): also the fixtures' compliance."""
    method = method or config.calibrate.solver
    try:
        solution = rwhe.closed_form(a, b, fixtures)
        if method in ("frobenius", "reprojection"):
            solution = rwhe.frobenius(a, b, fixtures, solution, up)
        if method == "reprojection":
            solution = rwhe.reprojection(b, fixtures, solution, [o.object_points for o in used],
                                         [o.pixels for o in used], intrinsics.camera_matrix, intrinsics.dist, up)
    except (ValueError, np.linalg.LinAlgError) as error:  # SciPy's refusal of non-finite residuals, singular fits
        raise rwhe.DegenerateError(f"the {method} solver failed on {len(a)} samples ({error}); the poses and "
                                   "images do not determine the offsets") from None
    return solution


def _subset(up: np.ndarray | None, mask: np.ndarray) -> np.ndarray | None:
    return None if up is None else up[mask]


def robust_solve(config: Config, a: np.ndarray, b: np.ndarray, fixtures: list[str], used: list[obs.Observation],
                 intrinsics: obs.EstimatedCamera, up: np.ndarray | None = None) -> tuple[rwhe.Solution, np.ndarray]:
    """Solve, then drop samples whose residual against PnP is an outlier (a ghost marker, a
    bad detection) and solve again, until nothing changes. Returns the solution and the
    inlier mask. Outlier: position or angle residual beyond median + k * 1.4826 * MAD."""
    keep = np.ones(len(a), dtype=bool)
    for _ in range(5):
        chosen = [f for f, k in zip(fixtures, keep, strict=True) if k]
        solution = solve(config, a[keep], b[keep], chosen, [o for o, k in zip(used, keep, strict=True) if k],
                         intrinsics, _subset(up, keep))
        predicted = solution.predict(b, fixtures, up)
        residual_t = np.linalg.norm(predicted[:, :3, 3] - a[:, :3, 3], axis=1)
        residual_r = g.angular_distance(predicted[:, :3, :3], a[:, :3, :3])
        new_keep = np.ones(len(a), dtype=bool)
        excess = np.zeros(len(a))
        for residual in (residual_t, residual_r):
            median = np.median(residual[keep])
            limit = median + config.calibrate.outlier_k * max(1.4826 * np.median(np.abs(residual[keep] - median)),
                                                              1e-12)
            new_keep &= residual <= limit
            excess = np.maximum(excess, residual / limit)
        new_keep = _determinate(config, b, fixtures, new_keep, excess)
        if np.array_equal(new_keep, keep):
            break
        keep = new_keep
    return solution, keep


def _determinate(config: Config, b: np.ndarray, fixtures: list[str], keep: np.ndarray,
                 excess: np.ndarray) -> np.ndarray:
    """``keep``, with flagged samples taken back (the least flagged first) until the kept
    ones determine the offsets: in a set of one orientation on a grid plus a few tilted
    views, the tilted ones carry the rotations, and a poor first solve fits them worst;
    rejecting them would leave nothing to calibrate from."""
    limits = config.calibrate
    keep = keep.copy()
    chosen = [f for f, k in zip(fixtures, keep, strict=True) if k]
    for index in np.argsort(np.where(keep, np.inf, excess), kind="stable"):
        if rwhe.diversity_problem(b[keep], chosen, limits.min_samples, limits.min_rotation_spread_rad) is None:
            break
        if not keep[index]:
            keep[index] = True
            chosen = [f for f, k in zip(fixtures, keep, strict=True) if k]
    return keep


def folds_of(config: Config, b: np.ndarray) -> np.ndarray:
    """Each sample's cross-validation fold (N,): samples of one orientation (within 1 deg)
    are dealt round the folds together, larger groups first, so that every training set
    keeps views of every orientation group it can (a grid of positions in one orientation
    plus a few tilted views: each tilted view in its own fold). A set of distinct
    orientations gets the plain seeded shuffle."""
    rank = np.random.default_rng(config.calibrate.seed).permutation(len(b))
    groups: list[list[int]] = []
    for i in np.argsort(rank, kind="stable"):
        for group in groups:
            if g.angular_distance(b[group[0], :3, :3][None], b[i, :3, :3][None])[0] < np.radians(1.0):
                group.append(int(i))
                break
        else:
            groups.append([int(i)])
    folds = np.zeros(len(b), dtype=int)
    position = 0
    for group in sorted(groups, key=len, reverse=True):  # stable: ties keep the shuffled order
        for i in group:
            folds[i] = position % config.calibrate.folds
            position += 1
    return folds


def cross_validate(config: Config, a: np.ndarray, b: np.ndarray, fixtures: list[str],
                   used: list[obs.Observation], intrinsics: obs.EstimatedCamera,
                   up: np.ndarray | None = None, readings: arms.Readings | None = None,
                   label: str = "calibrate") -> np.ndarray:
    """Out-of-fold predictions (N, 4, 4): each fold predicted by offsets (and arms, with
    ``readings``) fitted without it."""
    folds = folds_of(config, b)
    predicted = np.zeros_like(a)
    for fold in range(config.calibrate.folds):
        progress.note(f"  {label}: cross-validation fold {fold + 1} of {config.calibrate.folds}"
                      f"{' (offsets and arms)' if readings is not None else ''}")
        test, train = folds == fold, folds != fold
        train_fixtures = [f for f, keep in zip(fixtures, train, strict=True) if keep]
        problem = rwhe.diversity_problem(b[train], train_fixtures, 3, config.calibrate.min_rotation_spread_rad)
        if problem is not None:  # its error is then an extrapolation: say so, it is real
            progress.note(f"  {label}: fold {fold + 1}'s training samples do not determine the offsets ({problem}); "
                          "its cross-validated error measures that")
        solution = solve(config, a[train], b[train], train_fixtures,
                         [o for o, keep in zip(used, train, strict=True) if keep], intrinsics, _subset(up, train))
        test_fixtures = [f for f, keep in zip(fixtures, test, strict=True) if keep]
        missing = set(test_fixtures) - set(solution.x)
        if missing:
            raise rwhe.DegenerateError(f"cross-validation: fold {fold} leaves fixture(s) {missing} without "
                                       "training samples; capture more calibration poses")
        b_test, up_test = b[test], _subset(up, test)
        if readings is not None:
            fitted = arms.fit(config.testbed, config.calibrate, a[train], readings.subset(train), train_fixtures,
                              solution, up is not None)
            solution = fitted.offsets
            b_test, up_arms = arms.corrected_b(config.testbed, fitted.errors, readings.subset(test),
                                               config.calibrate.world_up)
            up_test = None if up is None else up_arms
        predicted[test] = solution.predict(b_test, test_fixtures, up_test)
    return predicted


def opencv_shah_metrics(a: np.ndarray, b: np.ndarray, fixtures: list[str], used: list[obs.Observation],
                        intrinsics: obs.EstimatedCamera) -> dict[str, Any]:
    """In-sample metrics of OpenCV's Shah solution (one fixture), or why it has none: its
    closed form fails on some data ("Rotation normalization issue"), ours falls back."""
    import cv2

    try:
        r_x, t_x, r_z, t_z = cv2.calibrateRobotWorldHandEye(
            [m[:3, :3] for m in a], [m[:3, 3] for m in a], [m[:3, :3] for m in b], [m[:3, 3] for m in b],
            method=cv2.CALIB_ROBOT_WORLD_HAND_EYE_SHAH)
    except cv2.error as error:
        return {"failed": " ".join(str(error).split())[-200:]}
    baseline = rwhe.Solution(g.make_transform(r_z, t_z.ravel()), {fixtures[0]: g.make_transform(r_x, t_x.ravel())})
    return metrics(baseline.predict(b, fixtures), a, used, intrinsics)


def pnp_variance(used: list[obs.Observation]) -> tuple[np.ndarray, float]:
    """Mean variance of the PnP poses (per camera axis m^2, rotation angle rad^2)."""
    covariances = [o.covariance for o in used if o.covariance is not None]
    if not covariances:
        return np.zeros(3), 0.0
    mean = np.mean(covariances, axis=0)
    return np.diag(mean)[3:], float(np.trace(mean[:3, :3]))


def load_truth(workspace: Workspace) -> dict[str, np.ndarray] | None:
    """True ``cam_from_target`` per sample, when the backend knows it (virtual testbed)."""
    if read_success(workspace, "truth") is None:
        return None
    return {r["sample_id"]: g.transform_from_qt(r["cam_from_target_q"], r["cam_from_target_t"])
            for r in read_manifest(workspace, "truth").to_pylist()}



def resolve(config: Config, workspace: Workspace | None = None) -> Resolved:
    """Reads the calibration session's captures (and ``W/session.json``); writes
    ``calibration_samples`` and ``W/calibration.json``."""
    return Resolved(("captures",), ("calibrate", "testbed"), {}, ("calibration_samples",))


def run(config: Config, workspace: Workspace) -> pa.Table:
    session = read_session(workspace)
    if not session.pattern:
        raise InputError(f"{workspace.session_path}: the capture session defines no calibration pattern")
    spec = pattern_from_table(session.pattern, str(workspace.session_path))
    # in sample_id order: acquire writes rows as its workers finish, and the folds, the
    # solvers' sums and the screening's medians must not depend on that
    captures = sorted((r for r in read_manifest(workspace, "captures").to_pylist()
                       if r["session"] == "calibration" and r["status"] == "ok"), key=lambda r: r["sample_id"])
    if read_success(workspace, "plan") is not None and session.backend == "virtual":
        unknown = sorted({r["sample_id"] for r in captures} - read_keys(workspace, "plan"))
        if unknown:
            raise InputError(f"captures: sample(s) {', '.join(unknown[:5])} are not in the plan")
    observations = obs.detect_all(workspace, captures, spec, config.calibrate.min_corners)
    by_id = {r["sample_id"]: r for r in captures}
    try:
        calibration, predictions = _calibrate(config, workspace, session, spec, by_id, observations)
    except InputError as error:  # refused: the images' reasons are still what the user needs
        _write_samples(config, workspace, observations, by_id, {})
        raise RefusalError(f"{error}{_dropped(observations)}", keep=("calibration_samples",)) from None
    write_calibration(workspace, calibration)
    _write_samples(config, workspace, observations, by_id, predictions)
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
                   by_id: dict[str, dict[str, Any]], predictions: dict[str, dict[str, np.ndarray]]) -> None:
    """One ``calibration_samples`` row per capture, each unusable one with its reason; the
    manifest is rewritten whole (a calibration is all or nothing)."""
    clear_manifest(workspace, "calibration_samples")
    with open_sink(workspace, "calibration_samples", config.run.part_rows) as sink:
        for o in observations:
            reason = o.reason
            flagged = [s for s in SOURCES if o.extra.get(f"{s}_outlier")]
            if reason is None and flagged:
                reason = "outlier of " + " and ".join(flagged) + " (excluded from that source's calibration)"
            row = {"sample_id": o.sample_id, "fixture": by_id[o.sample_id]["fixture"], "corners": len(o.ids),
                   "used": o.cam_from_target is not None, "reason": reason, "pnp_rms_px": o.rms_px,
                   "corners_px": np.asarray(o.pixels, float) if len(o.ids) else None,
                   "corners_target_m": np.asarray(o.object_points, float) if len(o.ids) else None}
            for prefix, pose in (("cam_from_target_cal", o.cam_from_target),
                                 ("kuka_cam_from_target", predictions.get("kuka", {}).get(o.sample_id)),
                                 ("vicon_cam_from_target", predictions.get("vicon", {}).get(o.sample_id))):
                row.update(g.pose_columns(prefix, pose))
            sink.add(row)


def _calibrate(config: Config, workspace: Workspace, session: Session, spec: PatternSpec,
               by_id: dict[str, dict[str, Any]], observations: list[obs.Observation]
               ) -> tuple[Calibration, dict[str, dict[str, np.ndarray]]]:
    """Intrinsics, screening, and the offsets of every source with Table 1's figures."""
    captures = list(by_id.values())
    camera = session.camera
    fixed = config.calibrate.intrinsics == "fixed" or (config.calibrate.intrinsics == "auto" and camera.camera_matrix)
    if fixed:
        if not camera.camera_matrix:
            raise InputError(f"{workspace.session_path}: calibrate.intrinsics=fixed but the session has no camera K")
        intrinsics = obs.EstimatedCamera(np.array(camera.camera_matrix, float), np.array(camera.dist, float),
                                    camera.width, camera.height, 0.0, False)
    else:
        intrinsics = obs.estimate_intrinsics(observations, camera.width, camera.height,
                                             k=config.calibrate.outlier_k)
        screening.check_intrinsics(intrinsics, observations, spec, config.calibrate)
    obs.solve_pnp(observations, intrinsics)
    robot_b = {r["sample_id"]: measured_b(r, "kuka") for r in captures}
    fixture_of = {r["sample_id"]: r["fixture"] for r in captures}
    posed = [o.sample_id for o in observations if o.cam_from_target is not None]
    rwhe.check_diversity(np.stack([robot_b[s] for s in posed]) if posed else np.zeros((0, 4, 4)),
                         [fixture_of[s] for s in posed], config.calibrate.min_samples,
                         config.calibrate.min_rotation_spread_rad, "kuka calibration")
    checks = {"facing": screening.check_facing(observations, spec),
              "corner_order": screening.order_corners(observations, robot_b, fixture_of, spec, intrinsics,
                                                      config.calibrate),
              "motions": screening.check_motions(observations, robot_b, fixture_of, spec, config.calibrate,
                                                 "the pose file's declared unit")}
    truth = load_truth(workspace)

    results: dict[str, SourceCalibration | None] = {}
    predictions: dict[str, dict[str, np.ndarray]] = {}
    for source in SOURCES:
        if source not in session.sources:
            results[source] = None
            continue
        used = [o for o in observations if o.cam_from_target is not None
                and measured_b(by_id[o.sample_id], source) is not None]
        a = np.stack([o.cam_from_target for o in used]) if used else np.zeros((0, 4, 4))
        b = np.stack([measured_b(by_id[o.sample_id], source) for o in used]) if used else np.zeros((0, 4, 4))
        fixtures = [by_id[o.sample_id]["fixture"] for o in used]
        rwhe.check_diversity(b, fixtures, config.calibrate.min_samples, config.calibrate.min_rotation_spread_rad,
                             f"{source} calibration")
        up, readings, kinematic = None, None, False
        compliance_note = arm_note = "motion capture tracks the model itself"
        if source == "kuka":
            up = np.stack([up_targetee(by_id[o.sample_id], config.calibrate.world_up) for o in used])
            compliant, compliance_note = compliance_decision(config, up, fixtures)
            up = up if compliant else None
            readings = arms.readings([by_id[o.sample_id] for o in used],
                                     arms.Payload.of(workspace_target(config, workspace)))
            kinematic, arm_note = arm_decision(config, readings)
        progress.note(f"calibrate {source}: robust solve on {len(used)} samples")
        solution, inliers = robust_solve(config, a, b, fixtures, used, intrinsics, up)
        screening.check_inliers(source, int(inliers.sum()), len(inliers))
        for o, inlier in zip(used, inliers, strict=True):
            if not inlier:
                o.extra[f"{source}_outlier"] = True
        outliers = [o.sample_id for o, inlier in zip(used, inliers, strict=True) if not inlier]
        used = [o for o, inlier in zip(used, inliers, strict=True) if inlier]
        a, b, up = a[inliers], b[inliers], _subset(up, inliers)
        fixtures = [f for f, inlier in zip(fixtures, inliers, strict=True) if inlier]
        fitted = None
        if kinematic:
            readings = readings.subset(inliers)
            cross = cross_validate(config, a, b, fixtures, used, intrinsics, up, readings, f"calibrate {source}")
            progress.note(f"calibrate {source}: the arms' fit on all {len(used)} samples")
            fitted = arms.fit(config.testbed, config.calibrate, a, readings, fixtures, solution, up is not None)
            solution = fitted.offsets
            b, up_arms = arms.corrected_b(config.testbed, fitted.errors, readings, config.calibrate.world_up)
            up = None if up is None else up_arms
        else:
            cross = cross_validate(config, a, b, fixtures, used, intrinsics, up, label=f"calibrate {source}")
        predicted = solution.predict(b, fixtures, up)
        cross_metrics = metrics(cross, a, used, intrinsics)
        screening.check_result(f"{source}", cross_metrics, intrinsics, config.calibrate)
        truth_metrics = None
        if truth is not None:
            true = np.stack([truth[o.sample_id] for o in used])
            true_pixels = [g.project(t, o.object_points, intrinsics.camera_matrix, intrinsics.dist)
                           for t, o in zip(true, used, strict=True)]
            truth_metrics = metrics(predicted, true, used, intrinsics, true_pixels)
        results[source] = SourceCalibration(
            source, record(solution.z), {f: record(x) for f, x in solution.x.items()},
            compliance_json(solution, up, fixtures, compliance_note),
            {"estimated": fitted is not None, "why": arm_note, **(fitted.to_json() if fitted is not None else {})},
            without_reference_noise(sigma_between(predicted, a), *pnp_variance(used)).to_record(), len(used),
            tuple(outliers), {"in_sample": metrics(predicted, a, used, intrinsics), "cross_validated": cross_metrics,
                              "truth": truth_metrics},
            # OpenCV's Shah on the same detections and intrinsics, for comparison
            opencv_shah_metrics(a, b, fixtures, used, intrinsics) if len(solution.x) == 1 else None)
        predictions[source] = {o.sample_id: p for o, p in zip(used, predicted, strict=True)}
        predictions[f"{source}_cv"] = {o.sample_id: p for o, p in zip(used, cross, strict=True)}

    rejection = fused_column = None
    if results.get("vicon") is not None:
        both = [o for o in observations if o.sample_id in predictions["kuka"] and o.sample_id in predictions["vicon"]]
        kuka = np.stack([predictions["kuka"][o.sample_id] for o in both])
        vicon = np.stack([predictions["vicon"][o.sample_id] for o in both])
        rejection = sigma_between(vicon, kuka).to_record()
        sigma = {s: Sigma.from_record(results[s].sigma) for s in SOURCES}
        fused = {}
        for label, suffix in (("in_sample", ""), ("cross_validated", "_cv")):
            fused[label] = np.stack([fuse(predictions[f"kuka{suffix}"][o.sample_id], sigma["kuka"],
                                          predictions[f"vicon{suffix}"][o.sample_id], sigma["vicon"])[0]
                                     for o in both])
        a = np.stack([o.cam_from_target for o in both])
        # each column of Table 1 is over its own samples, as in the paper; fusion is judged
        # against the single sources on the samples both measured
        estimates = {"fused": fused}
        for source in SOURCES:
            estimates[source] = {label: np.stack([predictions[f"{source}{suffix}"][o.sample_id] for o in both])
                                 for label, suffix in (("in_sample", ""), ("cross_validated", "_cv"))}
        true = true_pixels = None
        if truth is not None:
            true = np.stack([truth[o.sample_id] for o in both])
            true_pixels = [g.project(t, o.object_points, intrinsics.camera_matrix, intrinsics.dist)
                           for t, o in zip(true, both, strict=True)]
        on_both = {name: {"in_sample": metrics(e["in_sample"], a, both, intrinsics),
                          "cross_validated": metrics(e["cross_validated"], a, both, intrinsics),
                          "truth": None if true is None else metrics(e["in_sample"], true, both, intrinsics,
                                                                     true_pixels)}
                   for name, e in estimates.items()}
        fused_column = {"samples": len(both), "metrics": on_both["fused"],
                        "sources_on_the_same_samples": {source: on_both[source] for source in SOURCES}}

    pnp_positions = np.array([o.cam_from_target[:3, 3] for o in observations if o.cam_from_target is not None])
    calibration = Calibration(
        intrinsics.to_record(), results["kuka"], results["vicon"],
        float(np.mean(np.linalg.norm(pnp_positions, axis=1))),
        tuple(np.mean(lever_sq(pnp_positions), axis=0).tolist()), tuple(float(v) for v in config.calibrate.world_up),
        fused_column, rejection,
        {"method": config.calibrate.solver, "folds": config.calibrate.folds, "pattern": spec.to_json(),
         "fixtures": sorted({by_id[o.sample_id]["fixture"] for o in observations})},
        {"backend": session.backend, "sources": list(session.sources)}, checks)
    return calibration, predictions

