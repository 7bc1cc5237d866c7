"""From calibration images to ``cam_from_target_cal``: pattern detection, intrinsics
(fixed from the session or estimated robustly with ``cv2.calibrateCamera``), PnP with
refinement."""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from core.progress import track
from manifests import Workspace, sidecars
from stages.calibrate.consistency import board_continues
from stages.common import geometry as g
from stages.common.image_io import read_image, to_uint8
from stages.common.patterns import PatternSpec, detect
from stages.common.rwhe import DegenerateError


@dataclass
class Observation:
    """One calibration capture: detected corners and, when usable, its PnP pose."""

    sample_id: str
    ids: np.ndarray
    pixels: np.ndarray  # (M, 2) detected corners
    object_points: np.ndarray  # (M, 3) the same corners in T
    cam_from_target: np.ndarray | None = None
    rms_px: float | None = None
    #: (6, 6) covariance of the PnP pose: a small rotation (rad) applied on the camera side,
    #: then the translation (m), both in the camera frame
    covariance: np.ndarray | None = None
    reason: str | None = None  # why unusable
    extra: dict = field(default_factory=dict)


@dataclass(frozen=True)
class EstimatedCamera:
    camera_matrix: np.ndarray
    dist: np.ndarray
    width: int
    height: int
    rms_px: float
    estimated: bool

    def to_record(self) -> sidecars.Intrinsics:
        return sidecars.Intrinsics(tuple(tuple(row) for row in self.camera_matrix.tolist()),
                                   tuple(self.dist.tolist()), self.width, self.height, float(self.rms_px),
                                   self.estimated)


def target_points(spec: PatternSpec) -> np.ndarray:
    """(M, 3) every pattern corner in the target frame T, metres."""
    target_from_pattern = g.transform_from_qt(spec.target_from_pattern_q, spec.target_from_pattern_t)
    return g.apply(target_from_pattern, spec.object_points())


def relabel(o: Observation, spec: PatternSpec, ids: np.ndarray) -> None:
    """Give the detected corners other ids (a chessboard found from its other end)."""
    o.ids = ids
    o.object_points = target_points(spec)[ids]
    o.extra["pattern_points"] = spec.object_points()[ids]


def detect_all(workspace: Workspace, captures: list[dict], spec: PatternSpec, min_corners: int) -> list[Observation]:
    """Detect the pattern in every capture (images read through ``stages.common.image_io``: an
    unreadable one is an error naming it). For chessboards, also which sides of the grid
    the printed board goes on beyond (``extra["board_continues"]``)."""
    observations = []
    for row in track(captures, len(captures), "detect pattern"):
        image = read_image(workspace.fetch(row["image_path"]), "gray")
        pixels, ids = detect(image, spec)
        observation = Observation(row["sample_id"], ids, pixels, np.zeros((0, 3)))
        relabel(observation, spec, ids)
        if len(ids) < min_corners:
            observation.reason = f"{len(ids)} pattern corners detected, at least {min_corners} needed"
        elif spec.kind == "chessboard":
            observation.extra["board_continues"] = board_continues(to_uint8(image), pixels, spec)
        observations.append(observation)
    return observations


def estimate_intrinsics(observations: list[Observation], width: int, height: int, floor_px: float = 1.0,
                        k: float = 5.0, rounds: int = 4) -> EstimatedCamera:
    """``cv2.calibrateCamera`` on the detected corners (pattern frame coordinates), robustly:
    an image whose own reprojection RMS exceeds max(``floor_px``, median + k robust sigmas)
    does not fit the camera model with the others (corners of another grid, a blurred or
    partly hidden board); it gets its reason and the camera is estimated again without it."""
    for _ in range(rounds):
        usable = [o for o in observations if o.reason is None]
        if len(usable) < 4:
            raise DegenerateError(f"intrinsics: {len(usable)} images with the pattern, at least 4 needed to "
                                  "estimate the camera; capture more or give the camera in the session")
        # calibrateCamera wants planar points with z = 0: use the pattern's own frame
        object_points = [np.ascontiguousarray(o.extra["pattern_points"], np.float32) for o in usable]
        image_points = [np.ascontiguousarray(o.pixels, np.float32) for o in usable]
        threads = cv2.getNumThreads()
        cv2.setNumThreads(1)  # OpenCV's parallel sums vary in the last bits from run to run
        try:
            rms, camera_matrix, dist, _, _, _, _, per_view = cv2.calibrateCameraExtended(
                object_points, image_points, (width, height), None, None)
        except cv2.error as error:
            raise DegenerateError(f"intrinsics: OpenCV's calibrateCamera failed on {len(usable)} images "
                                  f"({' '.join(str(error).split())[-160:]}); the detections do not fit a "
                                  "camera model") from None
        finally:
            cv2.setNumThreads(threads)
        per_view = per_view.ravel()
        median = float(np.median(per_view))
        limit = max(floor_px, median + k * 1.4826 * float(np.median(np.abs(per_view - median))))
        bad = per_view > limit
        if not bad.any():
            break
        for o, error_px in zip(usable, per_view, strict=True):
            if error_px > limit:
                o.reason = (f"does not fit the camera model with the other images: its reprojection RMS is "
                            f"{error_px:.3g} px, the limit {limit:.3g} px (median {median:.3g} px)")
    return EstimatedCamera(camera_matrix, dist.ravel()[:5], width, height, float(rms), True)


def solve_pnp(observations: list[Observation], intrinsics: EstimatedCamera) -> None:
    """Fill ``cam_from_target``, ``rms_px`` and ``covariance`` of every usable observation
    (SQPnP, then Levenberg-Marquardt refinement)."""
    for o in observations:
        if o.reason is None:
            pnp(o, intrinsics)


def pnp(o: Observation, intrinsics: EstimatedCamera) -> None:
    """PnP of one observation with its current ids (see ``solve_pnp``)."""
    points = np.ascontiguousarray(o.object_points, np.float64)
    pixels = np.ascontiguousarray(o.pixels, np.float64)
    try:
        ok, rvec, tvec = cv2.solvePnP(points, pixels, intrinsics.camera_matrix, intrinsics.dist,
                                      flags=cv2.SOLVEPNP_SQPNP)
        if ok:
            rvec, tvec = cv2.solvePnPRefineLM(points, pixels, intrinsics.camera_matrix, intrinsics.dist, rvec, tvec)
    except cv2.error:
        ok = False
    if not ok or not (np.all(np.isfinite(rvec)) and np.all(np.isfinite(tvec))):
        o.reason, o.cam_from_target = "PnP failed", None
        return
    o.cam_from_target = g.make_transform(g.rotvec_to_matrix(rvec.ravel()), tvec.ravel())
    projected = g.project(o.cam_from_target, points, intrinsics.camera_matrix, intrinsics.dist)
    o.rms_px = float(np.sqrt(np.mean(np.sum((projected - pixels) ** 2, axis=1))))
    o.covariance = pnp_covariance(o.cam_from_target, points, projected - pixels, intrinsics)


def pnp_covariance(cam_from_target: np.ndarray, points: np.ndarray, residuals: np.ndarray,
                   intrinsics: EstimatedCamera, step: float = 1e-7) -> np.ndarray | None:
    """(6, 6) covariance of a least-squares PnP pose from its reprojection residuals (M, 2):
    ``s^2 (J^T J)^-1`` with ``s^2`` the residual variance per coordinate and ``J`` the
    projection's Jacobian (central differences) in the rotation-then-translation
    perturbation of ``Observation.covariance``. None when the pose is not determined."""
    dof = residuals.size - 6
    if dof <= 0:
        return None
    jacobian = np.zeros((residuals.size, 6))
    for k in range(6):
        moved = []
        for delta in (step, -step):
            change = np.zeros(6)
            change[k] = delta
            pose = g.make_transform(g.rotvec_to_matrix(change[:3]) @ cam_from_target[:3, :3],
                                    cam_from_target[:3, 3] + change[3:])
            moved.append(g.project(pose, points, intrinsics.camera_matrix, intrinsics.dist).ravel())
        jacobian[:, k] = (moved[0] - moved[1]) / (2 * step)
    information = jacobian.T @ jacobian
    if np.linalg.cond(information) > 1e14:
        return None
    return float(np.sum(residuals**2) / dof) * np.linalg.inv(information)
