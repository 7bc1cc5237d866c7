"""Rigid-body geometry shared by every stage.

Conventions (docs/architecture.md section 3), one rule everywhere:

- A transform ``a_from_b`` is a (..., 4, 4) homogeneous matrix mapping coordinates in
  frame b to frame a: ``x_a = a_from_b @ x_b``. Composition cancels inner names:
  ``cam_from_target = cam_from_camee @ camee_from_target``.
- Quaternions are Hamilton, scalar-first ``(w, x, y, z)``, unit, canonical with ``w >= 0``.
- Rotation vectors are axis * angle (radians), as OpenCV's Rodrigues.
- Translations are metres. Millimetres and degrees appear only in the KUKA boundary
  functions ``kuka_to_transform`` / ``transform_to_kuka``.
- Camera frame is OpenCV's: x right, y down, z along the boresight; pixel centres at
  integer coordinates.

Every function is vectorised over leading batch dimensions.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]

# Below this angle (rad) the rotation-vector conversions switch to Taylor series so that
# they stay accurate (and differentiable) at the identity.
_SMALL_ANGLE = 1e-8


# ----------------------------------------------------------------------------- quaternions
def quat_normalize(q: ArrayLike) -> Array:
    """Unit quaternion with ``w >= 0`` (the stored canonical form). q: (..., 4)."""
    q = np.asarray(q, dtype=np.float64)
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    if np.any(norm == 0):
        raise ValueError("zero-length quaternion cannot be normalised")
    q = q / norm
    return np.where(q[..., :1] < 0, -q, q)


def quat_multiply(a: ArrayLike, b: ArrayLike) -> Array:
    """Hamilton product ``a * b`` (rotation b first, then a). (..., 4) each."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def quat_conjugate(q: ArrayLike) -> Array:
    """Inverse of a unit quaternion. (..., 4)."""
    q = np.asarray(q, dtype=np.float64)
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def quat_to_matrix(q: ArrayLike) -> Array:
    """Rotation matrix (..., 3, 3) of quaternion(s) (..., 4); q and -q give the same matrix."""
    q = np.asarray(q, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    # filled in place rather than stacked: this sits in the calibration's inner loop
    out = np.empty(q.shape[:-1] + (3, 3))
    out[..., 0, 0], out[..., 0, 1], out[..., 0, 2] = 1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)
    out[..., 1, 0], out[..., 1, 1], out[..., 1, 2] = 2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)
    out[..., 2, 0], out[..., 2, 1], out[..., 2, 2] = 2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)
    return out


def matrix_to_quat(rotation: ArrayLike) -> Array:
    """Canonical quaternion (..., 4) of rotation matrices (..., 3, 3).

    Shepperd's method: pick the largest of w, x, y, z as pivot so that no division by a
    small number happens anywhere on SO(3).
    """
    m = np.asarray(rotation, dtype=np.float64)
    m00, m11, m22 = m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]
    trace = m00 + m11 + m22
    candidates = np.stack([trace, m00, m11, m22], axis=-1)
    pivot = np.argmax(candidates, axis=-1)

    def from_w() -> Array:
        s = 2.0 * np.sqrt(np.maximum(1.0 + trace, 1e-300))
        return np.stack(
            [0.25 * s, (m[..., 2, 1] - m[..., 1, 2]) / s, (m[..., 0, 2] - m[..., 2, 0]) / s,
             (m[..., 1, 0] - m[..., 0, 1]) / s], -1)

    def from_x() -> Array:
        s = 2.0 * np.sqrt(np.maximum(1.0 + m00 - m11 - m22, 1e-300))
        return np.stack(
            [(m[..., 2, 1] - m[..., 1, 2]) / s, 0.25 * s, (m[..., 0, 1] + m[..., 1, 0]) / s,
             (m[..., 0, 2] + m[..., 2, 0]) / s], -1)

    def from_y() -> Array:
        s = 2.0 * np.sqrt(np.maximum(1.0 - m00 + m11 - m22, 1e-300))
        return np.stack(
            [(m[..., 0, 2] - m[..., 2, 0]) / s, (m[..., 0, 1] + m[..., 1, 0]) / s, 0.25 * s,
             (m[..., 1, 2] + m[..., 2, 1]) / s], -1)

    def from_z() -> Array:
        s = 2.0 * np.sqrt(np.maximum(1.0 - m00 - m11 + m22, 1e-300))
        return np.stack(
            [(m[..., 1, 0] - m[..., 0, 1]) / s, (m[..., 0, 2] + m[..., 2, 0]) / s,
             (m[..., 1, 2] + m[..., 2, 1]) / s, 0.25 * s], -1)

    with np.errstate(invalid="ignore", divide="ignore"):
        options = np.stack([from_w(), from_x(), from_y(), from_z()], axis=-2)
    q = np.take_along_axis(options, pivot[..., None, None], axis=-2)[..., 0, :]
    return quat_normalize(q)


def rotvec_to_quat(rotvec: ArrayLike) -> Array:
    """Quaternion (..., 4) of rotation vectors (..., 3) (axis * angle, radians)."""
    r = np.asarray(rotvec, dtype=np.float64)
    angle = np.linalg.norm(r, axis=-1, keepdims=True)
    small = angle < _SMALL_ANGLE
    safe = np.where(small, 1.0, angle)
    # sin(a/2)/a -> 1/2 - a^2/48 near zero
    scale = np.where(small, 0.5 - angle**2 / 48.0, np.sin(safe / 2.0) / safe)
    return quat_normalize(np.concatenate([np.cos(angle / 2.0), scale * r], axis=-1))


def quat_to_rotvec(q: ArrayLike) -> Array:
    """Rotation vector (..., 3), angle in [0, pi], of quaternion(s) (..., 4)."""
    q = quat_normalize(q)
    vec = q[..., 1:]
    sin_half = np.linalg.norm(vec, axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(sin_half, q[..., :1])
    small = sin_half < _SMALL_ANGLE
    scale = np.where(small, 2.0 / np.maximum(q[..., :1], 1e-300), angle / np.where(small, 1.0, sin_half))
    return scale * vec


def rotvec_to_matrix(rotvec: ArrayLike) -> Array:
    """Rotation matrix (..., 3, 3) of rotation vectors (..., 3) (Rodrigues)."""
    return quat_to_matrix(rotvec_to_quat(rotvec))


def matrix_to_rotvec(rotation: ArrayLike) -> Array:
    """Rotation vector (..., 3) of rotation matrices (..., 3, 3)."""
    return quat_to_rotvec(matrix_to_quat(rotation))


def axis_angle_matrix(axis: str, angle: ArrayLike) -> Array:
    """Elementary rotation about ``"x"``, ``"y"`` or ``"z"`` by angle(s) (...) in radians."""
    angle = np.asarray(angle, dtype=np.float64)
    c, s = np.cos(angle), np.sin(angle)
    i, j = {"x": (1, 2), "y": (2, 0), "z": (0, 1)}[axis]  # the plane it turns: j = i + 1 cyclically
    out = np.zeros(angle.shape + (3, 3))
    out[..., 3 - i - j, 3 - i - j] = 1.0
    out[..., i, i], out[..., i, j], out[..., j, i], out[..., j, j] = c, -s, s, c
    return out


# ------------------------------------------------------------------------------ transforms
def make_transform(rotation: ArrayLike, translation: ArrayLike) -> Array:
    """Homogeneous (..., 4, 4) from rotation (..., 3, 3) and translation (..., 3) in metres."""
    rotation = np.asarray(rotation, dtype=np.float64)
    translation = np.asarray(translation, dtype=np.float64)
    batch = np.broadcast_shapes(rotation.shape[:-2], translation.shape[:-1])
    out = np.zeros(batch + (4, 4))
    out[..., :3, :3] = rotation
    out[..., :3, 3] = translation
    out[..., 3, 3] = 1.0
    return out


def transform_from_qt(q: ArrayLike, t: ArrayLike) -> Array:
    """Homogeneous (..., 4, 4) from quaternion (..., 4) and translation (..., 3) metres."""
    return make_transform(quat_to_matrix(q), t)


def transform_to_qt(a_from_b: ArrayLike) -> tuple[Array, Array]:
    """Canonical quaternion (..., 4) and translation (..., 3) of a transform (..., 4, 4)."""
    a_from_b = np.asarray(a_from_b, dtype=np.float64)
    return matrix_to_quat(a_from_b[..., :3, :3]), a_from_b[..., :3, 3].copy()


def pose_columns(prefix: str, a_from_b: ArrayLike | None) -> dict[str, Array | None]:
    """Manifest values ``<prefix>_q`` / ``<prefix>_t`` of a transform (both None when absent)."""
    if a_from_b is None:
        return {f"{prefix}_q": None, f"{prefix}_t": None}
    q, t = transform_to_qt(a_from_b)
    return {f"{prefix}_q": q, f"{prefix}_t": t}


def invert(a_from_b: ArrayLike) -> Array:
    """``b_from_a`` for rigid transforms ``a_from_b`` (..., 4, 4), exact (no matrix inverse)."""
    a_from_b = np.asarray(a_from_b, dtype=np.float64)
    rotation_t = np.swapaxes(a_from_b[..., :3, :3], -1, -2)
    translation = -np.einsum("...ij,...j->...i", rotation_t, a_from_b[..., :3, 3])
    return make_transform(rotation_t, translation)


def apply(a_from_b: ArrayLike, points_b: ArrayLike) -> Array:
    """Points (..., N, 3) in frame b mapped to frame a by ``a_from_b`` (..., 4, 4)."""
    a_from_b = np.asarray(a_from_b, dtype=np.float64)
    points_b = np.asarray(points_b, dtype=np.float64)
    return np.einsum("...ij,...nj->...ni", a_from_b[..., :3, :3], points_b) + a_from_b[..., None, :3, 3]


def rotation_angle(rotation: ArrayLike) -> Array:
    """Rotation angle (...) in [0, pi] radians of matrices (..., 3, 3), accurate near 0."""
    return np.linalg.norm(matrix_to_rotvec(rotation), axis=-1)


def angular_distance(rotation_a: ArrayLike, rotation_b: ArrayLike) -> Array:
    """Geodesic distance (radians) between rotation matrices (..., 3, 3)."""
    rotation_a = np.asarray(rotation_a, dtype=np.float64)
    return rotation_angle(np.swapaxes(rotation_a, -1, -2) @ np.asarray(rotation_b, dtype=np.float64))


def quat_angular_distance(q_a: ArrayLike, q_b: ArrayLike) -> Array:
    """Geodesic distance (radians) between quaternions (..., 4); sign-invariant (q ~ -q)."""
    q_a = np.asarray(q_a, dtype=np.float64)
    q_b = np.asarray(q_b, dtype=np.float64)
    q_a = q_a / np.linalg.norm(q_a, axis=-1, keepdims=True)
    q_b = q_b / np.linalg.norm(q_b, axis=-1, keepdims=True)
    relative = quat_multiply(quat_conjugate(q_a), q_b)
    return 2.0 * np.arctan2(np.linalg.norm(relative[..., 1:], axis=-1), np.abs(relative[..., 0]))


def project_to_so3(matrix: ArrayLike) -> Array:
    """Closest rotation (Frobenius) to matrices (..., 3, 3); determinant forced to +1."""
    u, _, vt = np.linalg.svd(np.asarray(matrix, dtype=np.float64))
    det = np.linalg.det(u @ vt)
    fix = np.ones(u.shape[:-2] + (3,))
    fix[..., 2] = np.sign(det) + (det == 0)
    return (u * fix[..., None, :]) @ vt


def chordal_mean(rotations: ArrayLike, weights: ArrayLike | None = None) -> Array:
    """Weighted chordal L2 mean of rotations (..., N, 3, 3) with weights (..., N).

    ``argmin_R sum_i w_i ||R - R_i||_F^2`` = SO(3) projection of ``sum_i w_i R_i``
    (Moakher 2002; the paper's fusion equation). Weights need not sum to one.
    """
    rotations = np.asarray(rotations, dtype=np.float64)
    if weights is None:
        weights = np.ones(rotations.shape[:-2])
    weights = np.asarray(weights, dtype=np.float64)
    if np.any(weights < 0) or np.any(weights.sum(axis=-1) <= 0):
        raise ValueError("chordal_mean needs non-negative weights with a positive sum")
    weighted_sum = np.einsum("...n,...nij->...ij", weights, rotations)
    return project_to_so3(weighted_sum)


def random_quats(rng: np.random.Generator, n: int) -> Array:
    """n quaternions (n, 4) uniform on SO(3) (normalised 4-D Gaussians are isotropic)."""
    return quat_normalize(rng.standard_normal((n, 4)))


# ------------------------------------------------------------------ KUKA boundary (mm, deg)
def kuka_to_transform(xyzabc: ArrayLike) -> Array:
    """KUKA ``X Y Z A B C`` (..., 6) in millimetres and degrees to transforms (..., 4, 4) in metres.

    KUKA's convention: the frame is rotated by A about Z, then B about the new Y, then C
    about the newest X (intrinsic Z-Y'-X''), i.e. ``R = Rz(A) @ Ry(B) @ Rx(C)``.
    """
    xyzabc = np.asarray(xyzabc, dtype=np.float64)
    a, b, c = np.deg2rad(xyzabc[..., 3]), np.deg2rad(xyzabc[..., 4]), np.deg2rad(xyzabc[..., 5])
    rotation = axis_angle_matrix("z", a) @ axis_angle_matrix("y", b) @ axis_angle_matrix("x", c)
    return make_transform(rotation, xyzabc[..., :3] / 1000.0)


def transform_to_kuka(a_from_b: ArrayLike) -> Array:
    """Transforms (..., 4, 4) in metres to KUKA ``X Y Z A B C`` (..., 6), mm and degrees.

    B is in [-90, 90]; at the gimbal lock (|B| = 90) C is set to 0 and A absorbs it.
    """
    a_from_b = np.asarray(a_from_b, dtype=np.float64)
    r = a_from_b[..., :3, :3]
    b = np.arctan2(-r[..., 2, 0], np.hypot(r[..., 0, 0], r[..., 1, 0]))
    locked = np.hypot(r[..., 0, 0], r[..., 1, 0]) < 1e-12
    a = np.where(locked, np.arctan2(-r[..., 0, 1], r[..., 1, 1]), np.arctan2(r[..., 1, 0], r[..., 0, 0]))
    c = np.where(locked, 0.0, np.arctan2(r[..., 2, 1], r[..., 2, 2]))
    return np.concatenate(
        [a_from_b[..., :3, 3] * 1000.0, np.rad2deg(np.stack([a, b, c], axis=-1))], axis=-1
    )


# ------------------------------------------------------------------------------ projection
def distort_normalized(xy: ArrayLike, dist: ArrayLike) -> Array:
    """OpenCV 5-coefficient model ``(k1, k2, p1, p2, k3)`` on normalised coordinates (..., 2)."""
    xy = np.asarray(xy, dtype=np.float64)
    k1, k2, p1, p2, k3 = np.asarray(dist, dtype=np.float64)
    x, y = xy[..., 0], xy[..., 1]
    r2 = x * x + y * y
    radial = 1.0 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return np.stack([xd, yd], axis=-1)


def project_points(points_cam: ArrayLike, camera_matrix: ArrayLike, dist: ArrayLike) -> Array:
    """Pixel coordinates (..., N, 2) of camera-frame points (..., N, 3), metres.

    camera_matrix: (3, 3) K; dist: (5,) OpenCV ``(k1, k2, p1, p2, k3)``. Points must be in
    front of the camera (z > 0); callers check visibility.
    """
    points_cam = np.asarray(points_cam, dtype=np.float64)
    k = np.asarray(camera_matrix, dtype=np.float64)
    normalized = points_cam[..., :2] / points_cam[..., 2:3]
    distorted = distort_normalized(normalized, dist)
    u = k[0, 0] * distorted[..., 0] + k[0, 1] * distorted[..., 1] + k[0, 2]
    v = k[1, 1] * distorted[..., 1] + k[1, 2]
    return np.stack([u, v], axis=-1)


def project(
    cam_from_target: ArrayLike, points_target: ArrayLike, camera_matrix: ArrayLike, dist: ArrayLike
) -> Array:
    """Pixels (..., N, 2) of target-frame points (N, 3) seen through ``cam_from_target`` (..., 4, 4)."""
    return project_points(apply(cam_from_target, points_target), camera_matrix, dist)


def look_at_rotation(direction: ArrayLike, up_hint: ArrayLike) -> Array:
    """``world_from_cam`` rotation (..., 3, 3) whose boresight (+z) points along ``direction``.

    The camera's -y (image up) is as close as possible to ``up_hint``; both (..., 3) in the
    world frame, not parallel.
    """
    z = np.asarray(direction, dtype=np.float64)
    z = z / np.linalg.norm(z, axis=-1, keepdims=True)
    up = np.broadcast_to(np.asarray(up_hint, dtype=np.float64), z.shape)
    x = np.cross(z, up)  # image right = boresight x up for an OpenCV camera (y down)
    norm = np.linalg.norm(x, axis=-1, keepdims=True)
    if np.any(norm < 1e-9):
        raise ValueError("look_at_rotation: direction is parallel to up_hint")
    x = x / norm
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=-1)
