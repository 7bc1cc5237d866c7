"""From calibration images to ``cam_from_target_cal``: pattern detection, intrinsics
(fixed from the session or estimated with ``cv2.calibrateCamera``), PnP with refinement."""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from manifests import Workspace
from pipeline.progress import track
from stages import geometry as g
from stages.calibrate.rwhe import DegenerateError
from stages.patterns import PatternSpec, detect


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
class Intrinsics:
    camera_matrix: np.ndarray
    dist: np.ndarray
    width: int
    height: int
    rms_px: float
    estimated: bool

    def to_json(self) -> dict:
        return {"K": self.camera_matrix.tolist(), "dist": self.dist.tolist(), "width": self.width,
                "height": self.height, "rms_px": self.rms_px, "estimated": self.estimated}


def detect_all(workspace: Workspace, captures: list[dict], spec: PatternSpec, min_corners: int) -> list[Observation]:
    target_from_pattern = g.transform_from_qt(spec.target_from_pattern_q, spec.target_from_pattern_t)
    all_points = g.apply(target_from_pattern, spec.object_points())
    observations = []
    for row in track(captures, len(captures), "detect pattern"):
        image = cv2.imread(str(workspace.resolve(row["image_path"])), cv2.IMREAD_GRAYSCALE)
        if image is None:
            observations.append(Observation(row["sample_id"], np.zeros(0, int), np.zeros((0, 2)), np.zeros((0, 3)),
                                            reason=f"image {row['image_path']} is unreadable"))
            continue
        pixels, ids = detect(image, spec)
        observation = Observation(row["sample_id"], ids, pixels, all_points[ids])
        if len(ids) < min_corners:
            observation.reason = f"{len(ids)} pattern corners detected, at least {min_corners} needed"
        observations.append(observation)
    return observations


def estimate_intrinsics(observations: list[Observation], width: int, height: int) -> Intrinsics:
    """``cv2.calibrateCamera`` on the detected corners (pattern frame coordinates)."""
    usable = [o for o in observations if o.reason is None]
    if len(usable) < 4:
        raise DegenerateError(f"intrinsics: {len(usable)} images with the pattern, at least 4 needed to estimate "
                              "the camera; capture more or give the camera in the session")
    # calibrateCamera wants planar points with z = 0: use the pattern's own frame
    object_points = [np.ascontiguousarray(o.extra["pattern_points"], np.float32) for o in usable]
    image_points = [np.ascontiguousarray(o.pixels, np.float32) for o in usable]
    rms, camera_matrix, dist, _, _ = cv2.calibrateCamera(object_points, image_points, (width, height), None, None)
    return Intrinsics(camera_matrix, dist.ravel()[:5], width, height, float(rms), True)


def solve_pnp(observations: list[Observation], intrinsics: Intrinsics) -> None:
    """Fill ``cam_from_target`` and ``rms_px`` of every usable observation (IPPE or
    iterative start, then Levenberg-Marquardt refinement)."""
    for o in observations:
        if o.reason is not None:
            continue
        points = np.ascontiguousarray(o.object_points, np.float64)
        pixels = np.ascontiguousarray(o.pixels, np.float64)
        ok, rvec, tvec = cv2.solvePnP(points, pixels, intrinsics.camera_matrix, intrinsics.dist,
                                      flags=cv2.SOLVEPNP_SQPNP)
        if not ok:
            o.reason = "PnP failed"
            continue
        rvec, tvec = cv2.solvePnPRefineLM(points, pixels, intrinsics.camera_matrix, intrinsics.dist, rvec, tvec)
        o.cam_from_target = g.make_transform(g.rotvec_to_matrix(rvec.ravel()), tvec.ravel())
        projected = g.project(o.cam_from_target, points, intrinsics.camera_matrix, intrinsics.dist)
        o.rms_px = float(np.sqrt(np.mean(np.sum((projected - pixels) ** 2, axis=1))))
        o.covariance = pnp_covariance(o.cam_from_target, points, projected - pixels, intrinsics)


def pnp_covariance(cam_from_target: np.ndarray, points: np.ndarray, residuals: np.ndarray,
                   intrinsics: Intrinsics, step: float = 1e-7) -> np.ndarray | None:
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
