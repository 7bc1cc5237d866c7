"""The calibration's maths per source: the RWHE solve (robust, with its outliers), k-fold
cross-validation, Table 1's metrics, OpenCV's Shah for comparison, and the PnP poses'
own noise. Arrays: ``a`` (N, 4, 4) the PnP poses ``cam_from_target``, ``b`` (N, 4, 4) a
source's measured ``B``, mock-up scale, metres."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from core import progress
from core.config import Config
from manifests import Workspace, read_manifest, read_marker
from manifests.sidecars import Folds
from stages.calibrate import observations as obs
from stages.common import geometry as g
from stages.common import rwhe
from stages.common.pose_noise import stacked_pnp

if TYPE_CHECKING:
    from stages.common.robots.identification import Verdicts


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


#: fewer determined folds than this cannot judge the data: the in-sample fit alone does
MIN_JUDGED_FOLDS = 2


@dataclass(frozen=True)
class CrossValidation:
    """Out-of-fold predictions ``predicted`` (N, 4, 4), valid where ``determined`` (N,): the
    samples of folds whose training samples determine the offsets. An undetermined fold's
    training set leaves a rotation free (or a fixture unseen): its prediction would be an
    extrapolation of nothing, so it is not made, and the fold is named (from 1)."""

    predicted: np.ndarray
    determined: np.ndarray
    folds: int
    undetermined_folds: tuple[int, ...]
    why: dict[int, str]

    @property
    def judged(self) -> bool:
        """Whether enough folds are determined for their errors to judge the data."""
        return self.folds - len(self.undetermined_folds) >= MIN_JUDGED_FOLDS

    def record(self) -> Folds:
        """calibration.json's ``metrics.cross_validation``: what the cross-validated means are over."""
        return Folds(int(self.determined.sum()), self.folds, tuple(self.undetermined_folds), self.judged)


def _undetermined(config: Config, b: np.ndarray, fixtures: list[str], train: np.ndarray,
                  test: np.ndarray) -> str | None:
    """Why a fold's training samples cannot determine the offsets its test samples need, or None."""
    train_fixtures = [f for f, keep in zip(fixtures, train, strict=True) if keep]
    missing = sorted({f for f, t in zip(fixtures, test, strict=True) if t} - set(train_fixtures))
    if missing:
        return f"no training sample holds fixture(s) {', '.join(missing)}"
    return rwhe.diversity_problem(b[train], train_fixtures, 3, config.calibrate.min_rotation_spread_rad)


def cross_validate(config: Config, a: np.ndarray, b: np.ndarray, fixtures: list[str],
                   used: list[obs.Observation], intrinsics: obs.EstimatedCamera,
                   up: np.ndarray | None = None, arms: tuple[Any, Any] | None = None,
                   label: str = "calibrate", verdicts: Verdicts | None = None) -> CrossValidation:
    """Each determined fold predicted by offsets (and arms, with ``arms``: the arms' model,
    ``arm_models.ArmsModel``, and the samples' readings) fitted without it; ``verdicts``: the
    whole calibration's on the arms' model (``identification.Verdicts``: what its rank and F
    tests held), which each fold fits untested (None: each fold tests for itself)."""
    folds = folds_of(config, b)
    predicted = np.tile(np.eye(4), (len(a), 1, 1))
    determined = np.zeros(len(a), dtype=bool)
    why: dict[int, str] = {}
    for fold in range(config.calibrate.folds):
        test, train = folds == fold, folds != fold
        if not test.any():
            continue
        problem = _undetermined(config, b, fixtures, train, test)
        if problem is not None:
            why[fold + 1] = problem
            progress.note(f"  {label}: fold {fold + 1}'s training samples do not determine the offsets ({problem}); "
                          "it is left out of the cross-validated means")
            continue
        progress.note(f"  {label}: cross-validation fold {fold + 1} of {config.calibrate.folds}"
                      f"{' (offsets and arms)' if arms is not None else ''}")
        train_fixtures = [f for f, keep in zip(fixtures, train, strict=True) if keep]
        train_used = [o for o, keep in zip(used, train, strict=True) if keep]
        solution = solve(config, a[train], b[train], train_fixtures, train_used, intrinsics, _subset(up, train))
        test_fixtures = [f for f, keep in zip(fixtures, test, strict=True) if keep]
        b_test, up_test, before = b[test], _subset(up, test), None
        if arms is not None:
            model, readings = arms
            fitted = model.fit(a[train], readings.subset(train), train_fixtures, solution, up is not None,
                               pose_covariances(config, train_used), verdicts)
            solution = fitted.offsets
            if fitted.fit.capped:
                from stages.common.arms import MAX_ITERATIONS  # read now: the cap as the fit had it

                progress.note(f"  {label}: fold {fold + 1}'s arms' fit stopped at its cap of {MAX_ITERATIONS} "
                              "evaluations before converging (its training poses barely determine some direction); "
                              "its predictions are those of the capped fit")
            b_test, up_arms = fitted.corrected_b(readings.subset(test))
            up_test = None if up is None else up_arms
            before = fitted.up_before(readings.subset(test))
        predicted[test] = solution.predict(b_test, test_fixtures, up_test, before)
        determined |= test
    return CrossValidation(predicted, determined, int(config.calibrate.folds), tuple(sorted(why)), why)


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


def pose_covariances(config: Config, used: list[obs.Observation]) -> np.ndarray | None:
    """(N, 6, 6) the PnP poses' covariances the arms' fit whitens by, or None where
    ``calibrate.pose_weights`` weighs rotations and translations as two groups instead."""
    return stacked_pnp([o.covariance for o in used]) if config.calibrate.pose_weights == "pnp" else None


def pnp_variance(used: list[obs.Observation]) -> tuple[np.ndarray, float]:
    """Mean variance of the PnP poses (per camera axis m^2, rotation angle rad^2)."""
    covariances = [o.covariance for o in used if o.covariance is not None]
    if not covariances:
        return np.zeros(3), 0.0
    mean = np.mean(covariances, axis=0)
    return np.diag(mean)[3:], float(np.trace(mean[:3, :3]))


def load_truth(workspace: Workspace) -> dict[str, np.ndarray] | None:
    """True ``cam_from_target`` per sample, when the backend knows it (virtual testbed)."""
    if read_marker(workspace, "truth") is None:
        return None
    return {r["sample_id"]: g.transform_from_qt(r["cam_from_target_q"], r["cam_from_target_t"])
            for r in read_manifest(workspace, "truth").to_pylist()}
