"""Robot-world/hand-eye calibration: ``A_i X_f = Z B_i`` for each source.

``A_i = cam_from_target`` (PnP), ``B_i`` = the source's measurement (``camee_from_targetee``
for the robots, ``camrb_from_targetrb`` for motion capture), ``Z`` = the camera-side
offset (``cam_from_camee``), ``X_f`` = the target-side offset of fixture f
(``target_from_targetee``). Several fixtures share one ``Z``.

Solvers: Shah's closed form (Kronecker null space, then linear translations; Shah,
"Solving the Robot-World/Hand-Eye Calibration Problem Using the Kronecker Product", ASME
Journal of Mechanisms and Robotics 5(3), 2013), the paper's Levenberg-Marquardt on
``sum |A_i - Z B_i X^-1|_F^2`` over rotation vectors (Tabb and Ahmad Yousef, "Solving the
robot-world hand-eye(s) calibration problem with iterative methods", Machine Vision and
Applications 28, 2017; Park, Bosse and D'Amico, "Robotic Testbed for Rendezvous and Optical
Navigation: Multi-Source Calibration and Machine Learning Use Cases", AAS/AIAA
Astrodynamics Specialist Conference, 2021), and a refinement on the pattern's reprojection
error (maximum likelihood for pixel noise).

Compliant fixtures: the model hangs off its flange on a fixture that tilts under the
model's weight (the paper blames its KUKA-only rotation error on it). To first order
(linear elastostatics, tilt about the flange origin) the tilt's rotation vector in the
flange frame is ``up_i x k_f``: ``up_i`` (3,) the world's up direction in the flange frame
at capture i (from the robot's telemetry), ``k_f = c m g p`` (3,) radians, with ``c`` the
fixture's compliance (rad / N m), ``m g`` the model's weight and ``p`` its centre of mass
in the flange frame. Then ``A_i X_f = Z B_i S(up_i x k_f)``; ``k_f`` is estimated with the
offsets when the flange's attitude varies enough to observe it (``gravity_spread``).

A clamped fixture also micro-slips: its tilt lags its elastic value by up to its play
``w_f`` (rad) against the direction the tilt last changed in (``fixture_lag``: the first-order
play operator of bolted joints' hysteresis, each move taken as longer than the play; Gaul
and Lenz, Acta Mechanica 125, 1997; a target that stood still keeps its lag), so
``S`` becomes ``S(t_i) L(t_i - t_before)`` with ``t`` the elastic tilt at capture i and at
the capture before it (with this fixture's ``k_f``, ``D_f``: a change of mount keeps the
adapter that slips clamped); where no capture came before, no lag.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from speedplus.errors import InputError
from stages.common import geometry as g


class DegenerateError(InputError):
    """The calibration data cannot determine the offsets; the message says what to add."""


def symmetric(anisotropy: np.ndarray) -> np.ndarray:
    """Symmetric matrices (..., 3, 3) of (..., 6) vectors (xx, yy, zz, xy, xz, yz)."""
    d = np.asarray(anisotropy, float)
    xx, yy, zz, xy, xz, yz = np.moveaxis(d, -1, 0)
    return np.stack([np.stack([xx, xy, xz], -1), np.stack([xy, yy, yz], -1), np.stack([xz, yz, zz], -1)], -2)


def fixture_tilt(up_targetee: np.ndarray, compliance: np.ndarray, anisotropy: np.ndarray | None = None) -> np.ndarray:
    """Rotations (..., N, 4, 4) of compliant fixtures about the flange origin: rotation vector
    ``(I + D) (up x k)`` of the up directions (..., N, 3, unit, flange frame), compliances
    ``k`` (..., N, 3, rad) and, for an anisotropic fixture, ``D`` (..., N, 6: ``symmetric``;
    None: 0).

    ``up x k`` is a fixture equally stiff about every axis: the gravity moment of a model
    whose centre lies along ``k``, times one compliance. A bracket is stiffer in one plane
    than in another: ``I + D`` is its compliance's shape (a symmetric matrix, as every
    linear elastic compliance is)."""
    return g.make_transform(g.rotvec_to_matrix(tilt_rotvec(up_targetee, compliance, anisotropy)), np.zeros(3))


def tilt_rotvec(up_targetee: np.ndarray, compliance: np.ndarray, anisotropy: np.ndarray | None = None) -> np.ndarray:
    """The elastic tilt's rotation vector (..., N, 3, rad, flange frame) of ``fixture_tilt``."""
    rotvec = np.cross(up_targetee, compliance)
    if anisotropy is not None:
        rotvec = rotvec + np.einsum("...ij,...j->...i", symmetric(anisotropy), rotvec)
    return rotvec


def fixture_lag(tilt_now: np.ndarray, tilt_before: np.ndarray, play_rad: np.ndarray) -> np.ndarray:
    """Rotations (..., N, 4, 4, flange frame) by which micro-slip holds a fixture back from
    its elastic tilt ``tilt_now`` (..., N, 3, rotation vector): ``min(|c|, w) c / |c|`` against
    the change ``c`` from ``tilt_before`` (NaN: no capture before it, no lag), ``w`` the
    play ``play_rad`` (..., N)."""
    change = np.nan_to_num(tilt_now - tilt_before)
    size = np.linalg.norm(change, axis=-1)
    scale = np.minimum(size, np.asarray(play_rad, float)) / np.maximum(size, 1e-300)
    return g.make_transform(g.rotvec_to_matrix(-scale[..., None] * change), np.zeros(3))


def gravity_spread(up_targetee: np.ndarray) -> float:
    """How much the flange's attitude to gravity varies (rad): the second principal spread
    of the up directions (N, 3). A compliance needs it to span two axes to be observed."""
    centred = up_targetee - up_targetee.mean(axis=0)
    return float(np.linalg.svd(centred, compute_uv=False)[1] / np.sqrt(max(len(up_targetee), 1)))


@dataclass(frozen=True)
class Solution:
    """``cam_from_camee`` (Z) and ``target_from_targetee`` (X) per fixture, (4, 4) each, and
    each compliant fixture's ``k_f`` (3,) in radians (empty: rigid fixtures) and, when
    estimated, its anisotropy ``D_f`` (6,) (``fixture_tilt``; empty: isotropic)."""

    z: np.ndarray
    x: dict[str, np.ndarray]
    compliance: dict[str, np.ndarray] = field(default_factory=dict)
    anisotropy: dict[str, np.ndarray] = field(default_factory=dict)
    play: dict[str, float] = field(default_factory=dict)  # w_f (rad) per compliant fixture; empty: none

    def predict(self, b: np.ndarray, fixtures: list[str], up_targetee: np.ndarray | None = None,
                up_before: np.ndarray | None = None) -> np.ndarray:
        """``cam_from_target`` (N, 4, 4) = Z B_i S_i L_i X_f^-1; ``up_targetee`` (N, 3) is needed
        when the solution has compliant fixtures; ``up_before`` (N, 3): the up direction in
        the flange at each capture's previous one (NaN rows: none; None: no lag at all)."""
        inverses = {f: g.invert(self.x[f]) for f in set(fixtures)}
        x_inv = np.stack([inverses[f] for f in fixtures])
        if not self.compliance:
            return self.z @ b @ x_inv
        if up_targetee is None:
            raise ValueError("a solution with compliant fixtures predicts from the up directions")
        k = np.stack([self.compliance[f] for f in fixtures])
        d = np.stack([self.anisotropy[f] for f in fixtures]) if self.anisotropy else None
        tilt = fixture_tilt(np.asarray(up_targetee, float), k, d)
        if self.play and up_before is not None:
            w = np.array([self.play[f] for f in fixtures], float)
            tilt = tilt @ fixture_lag(tilt_rotvec(np.asarray(up_targetee, float), k, d),
                                      tilt_rotvec(np.asarray(up_before, float), k, d), w)
        return self.z @ b @ tilt @ x_inv


def diversity_problem(b: np.ndarray, fixtures: list[str], min_samples: int, min_spread_rad: float) -> str | None:
    """Why the samples cannot determine the offsets (too few of them, or rotations about
    one axis only, which leave the translations along it free), or None."""
    if len(b) < min_samples:
        return f"{len(b)} usable calibration samples, at least {min_samples} needed; capture more calibration poses"
    for fixture in sorted(set(fixtures)):
        chosen = b[[i for i, f in enumerate(fixtures) if f == fixture]]
        if len(chosen) < 3:
            return f"fixture {fixture!r} has {len(chosen)} samples, at least 3 needed"
        relative = g.matrix_to_rotvec(np.swapaxes(chosen[0, :3, :3], -1, -2) @ chosen[:, :3, :3])
        spread = np.linalg.svd(relative - relative.mean(axis=0), compute_uv=False) / np.sqrt(len(chosen))
        if spread[1] < min_spread_rad:
            return (f"the rotations of fixture {fixture!r} vary about one axis only (second principal spread "
                    f"{np.degrees(spread[1]):.2f} deg < {np.degrees(min_spread_rad):.2f} deg); add captures with the "
                    "target tilted about other axes")
    return None


def check_diversity(b: np.ndarray, fixtures: list[str], min_samples: int, min_spread_rad: float,
                    label: str) -> None:
    """Refuse data that cannot determine the offsets: too few samples, or rotations that
    do not span at least two independent axes."""
    problem = diversity_problem(b, fixtures, min_samples, min_spread_rad)
    if problem is not None:
        raise DegenerateError(f"{label}: {problem}")


def shah(a: np.ndarray, b: np.ndarray, fixtures: list[str]) -> Solution:
    """Closed form (Shah 2013, extended to several fixtures sharing Z). Raises
    ``DegenerateError`` when the null space gives no rotation (``closed_form`` falls back)."""
    names = sorted(set(fixtures))
    n_unknown = 9 * (1 + len(names))
    rows = []
    eye = np.eye(3)
    for a_i, b_i, fixture in zip(a, b, fixtures, strict=True):
        block = np.zeros((9, n_unknown))
        block[:, :9] = -np.kron(b_i[:3, :3].T, eye)  # vec(R_Z R_B) = (R_B^T kron I) vec(R_Z)
        k = 9 * (1 + names.index(fixture))
        block[:, k:k + 9] = np.kron(eye, a_i[:3, :3])  # vec(R_A R_X) = (I kron R_A) vec(R_X)
        rows.append(block)
    _, singular, vt = np.linalg.svd(np.concatenate(rows))
    if singular[-2] < 1e-9 * singular[0]:
        raise DegenerateError("Shah's closed form: the null space has more than one dimension")
    null = vt[-1]
    rz = null[:9].reshape(3, 3, order="F")
    determinant = np.linalg.det(rz)
    if not np.isfinite(determinant) or abs(determinant) < 1e-9:
        raise DegenerateError(f"Shah's closed form: the null space gives no rotation (det {determinant:.3g})")
    scale = np.sign(determinant) / abs(determinant) ** (1 / 3)
    rotations = [g.project_to_so3(scale * null[9 * j:9 * j + 9].reshape(3, 3, order="F"))
                 for j in range(1 + len(names))]
    return _with_translations(a, b, fixtures, names, rotations)


def motion_rotations(a: np.ndarray, b: np.ndarray, fixtures: list[str], min_rad: float,
                     max_rad: float) -> tuple[np.ndarray, np.ndarray]:
    """Rotation vectors (K, 3) of the camera's and the robot's motions ``log(R_Ai R_Aj^T)``
    and ``log(R_Bi R_Bj^T)`` over pairs i < j on one fixture whose robot turn lies in
    [min_rad, max_rad] (near a half turn the axis's sign is ambiguous)."""
    alphas, betas = [], []
    for i, j in _fixture_pairs(fixtures):
        beta = g.matrix_to_rotvec(b[i, :3, :3] @ b[j, :3, :3].T)
        if min_rad <= np.linalg.norm(beta) <= max_rad:
            alphas.append(g.matrix_to_rotvec(a[i, :3, :3] @ a[j, :3, :3].T))
            betas.append(beta)
    return np.array(alphas).reshape(-1, 3), np.array(betas).reshape(-1, 3)


def _fixture_pairs(fixtures: list[str]) -> list[tuple[int, int]]:
    """Index pairs i < j of captures on one fixture (their motions share the offsets)."""
    return [(i, j) for i in range(len(fixtures)) for j in range(i + 1, len(fixtures)) if fixtures[i] == fixtures[j]]


def procrustes(alphas: np.ndarray, betas: np.ndarray) -> np.ndarray:
    """The rotation (3, 3) that best maps ``betas`` onto ``alphas`` (N, 3) (orthogonal Procrustes)."""
    u, _, vt = np.linalg.svd(alphas.T @ betas)
    return u @ np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))]) @ vt


def translation_directions(a: np.ndarray, b: np.ndarray, fixtures: list[str], max_rad: float,
                           min_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Translations (K, 3) of the camera's and the robot's motions ``A_i A_j^-1`` and
    ``B_i B_j^-1`` over pairs i < j on one fixture that barely turn (at most ``max_rad``)
    but move at least ``min_m``. For a motion without rotation ``A_i A_j^-1 = Z B_i B_j^-1
    Z^-1`` gives ``t_A = R_Z t_B`` exactly (with a turn of angle theta, up to theta |t_Z|):
    a set of one orientation on a grid of positions fixes R_Z by its translations alone."""
    alphas, betas = [], []
    for i, j in _fixture_pairs(fixtures):
        motion_b = b[i] @ g.invert(b[j])
        if np.linalg.norm(g.matrix_to_rotvec(motion_b[:3, :3])) <= max_rad and np.linalg.norm(motion_b[:3, 3]) >= min_m:
            alphas.append((a[i] @ g.invert(a[j]))[:3, 3])
            betas.append(motion_b[:3, 3])
    return np.array(alphas).reshape(-1, 3), np.array(betas).reshape(-1, 3)


def park(a: np.ndarray, b: np.ndarray, fixtures: list[str]) -> Solution:
    """Linear rotation estimate from motion pairs (Park and Martin 1994), the fallback start:
    ``A_i A_j^-1 = Z B_i B_j^-1 Z^-1`` gives ``log(R_Ai R_Aj^T) = R_Z log(R_Bi R_Bj^T)`` for
    captures on one fixture, and for pairs that do not turn ``t_A = R_Z t_B``
    (``translation_directions``); R_Z by orthogonal Procrustes on both kinds of direction,
    each R_X as the chordal mean of ``R_Ai^T R_Z R_Bi``, then the translations as in ``shah``.

    Rotation vectors weigh by their angle (rad), translations by their length (m): an
    axis's direction error is about sigma / length either way, and with PnP's typical
    1e-3 rad and 3e-4 m a metre of travel is worth at least a radian of turn, so turns
    dominate where a set has them and travel fixes the axes they leave free."""
    names = sorted(set(fixtures))
    alphas, betas = motion_rotations(a, b, fixtures, 1e-3, np.radians(170.0))
    moves_a, moves_b = translation_directions(a, b, fixtures, np.radians(0.5), 0.01)
    directions_a, directions_b = np.concatenate([alphas, moves_a]), np.concatenate([betas, moves_b])
    if len(directions_a) < 2 or np.linalg.matrix_rank(directions_b, tol=1e-3 * np.abs(directions_b).max()) < 2:
        raise DegenerateError("the robot's motions have too few usable rotations or translations to estimate the "
                              "offsets")
    rz = procrustes(directions_a, directions_b)
    rotations = [rz]
    for name in names:
        chosen = [i for i, f in enumerate(fixtures) if f == name]
        rotations.append(g.chordal_mean(np.stack([a[i, :3, :3].T @ rz @ b[i, :3, :3] for i in chosen])))
    return _with_translations(a, b, fixtures, names, rotations)


def closed_form(a: np.ndarray, b: np.ndarray, fixtures: list[str]) -> Solution:
    """Shah's closed form, or Park's linear estimate where Shah's has no solution."""
    try:
        solution = shah(a, b, fixtures)
        if all(np.all(np.isfinite(m)) for m in (solution.z, *solution.x.values())):
            return solution
    except (DegenerateError, np.linalg.LinAlgError):
        pass
    return park(a, b, fixtures)


def _with_translations(a: np.ndarray, b: np.ndarray, fixtures: list[str], names: list[str],
                       rotations: list[np.ndarray]) -> Solution:
    """Linear translations given the rotations [R_Z, R_X per fixture in ``names`` order]."""
    eye = np.eye(3)
    # R_A t_X + t_A = R_Z t_B + t_Z  ->  R_A t_X - t_Z = R_Z t_B - t_A
    design = np.zeros((3 * len(a), 3 * (1 + len(names))))
    target = np.zeros(3 * len(a))
    for i, (a_i, b_i, fixture) in enumerate(zip(a, b, fixtures, strict=True)):
        k = 3 * (1 + names.index(fixture))
        design[3 * i:3 * i + 3, :3] = -eye
        design[3 * i:3 * i + 3, k:k + 3] = a_i[:3, :3]
        target[3 * i:3 * i + 3] = rotations[0] @ b_i[:3, 3] - a_i[:3, 3]
    t = np.linalg.lstsq(design, target, rcond=None)[0]
    z = g.make_transform(rotations[0], t[:3])
    x = {name: g.make_transform(rotations[1 + j], t[3 + 3 * j:6 + 3 * j]) for j, name in enumerate(names)}
    return Solution(z, x)


def transform_from_vector(vector: np.ndarray) -> np.ndarray:
    """(..., 4, 4) of packed 6-vectors (..., 6): rotation vector (rad), then translation (m)."""
    return g.make_transform(g.rotvec_to_matrix(vector[..., :3]), vector[..., 3:6])


def pack(solution: Solution, names: list[str], compliant: bool, anisotropic: bool = False,
         played: bool = False) -> np.ndarray:
    """Parameter vector: Z, each X_f (rotation vector, translation), then each ``k_f`` when
    ``compliant``, then each ``D_f`` when also ``anisotropic``, then each ``w_f`` when also
    ``played``."""
    parts = [g.matrix_to_rotvec(solution.z[:3, :3]), solution.z[:3, 3]]
    for name in names:
        parts += [g.matrix_to_rotvec(solution.x[name][:3, :3]), solution.x[name][:3, 3]]
    if compliant:
        parts += [solution.compliance.get(name, np.zeros(3)) for name in names]
        if anisotropic:
            parts += [solution.anisotropy.get(name, np.zeros(6)) for name in names]
            if played:
                parts.append(np.array([solution.play.get(name, 0.0) for name in names], float))
    return np.concatenate(parts)


def anisotropy_slice(names: list[str]) -> slice:
    """Where ``pack`` puts the ``D_f`` of an anisotropic, compliant solution."""
    start = 6 * (1 + len(names)) + 3 * len(names)
    return slice(start, start + 6 * len(names))


def play_slice(names: list[str]) -> slice:
    """Where ``pack`` puts the ``w_f`` of a played (so anisotropic and compliant) solution."""
    start = anisotropy_slice(names).stop
    return slice(start, start + len(names))


def unpack(params: np.ndarray, names: list[str], compliant: bool, anisotropic: bool = False,
           played: bool = False) -> Solution:
    vectors = params[:6 * (1 + len(names))].reshape(-1, 6)
    poses = g.make_transform(g.rotvec_to_matrix(vectors[:, :3]), vectors[:, 3:])  # at once: an inner loop

    def pose(k: int) -> np.ndarray:
        return poses[k]

    start = 6 * (1 + len(names))
    compliance = {name: params[start + 3 * j:start + 3 * j + 3] for j, name in enumerate(names)} if compliant else {}
    anisotropy = {}
    if compliant and anisotropic:
        first = anisotropy_slice(names).start
        anisotropy = {name: params[first + 6 * j:first + 6 * j + 6] for j, name in enumerate(names)}
    play = {}
    if compliant and anisotropic and played:
        first = play_slice(names).start
        play = {name: float(params[first + j]) for j, name in enumerate(names)}
    return Solution(pose(0), {name: pose(1 + j) for j, name in enumerate(names)}, compliance, anisotropy, play)


def predict_packed(params: np.ndarray, names: list[str], compliant: bool, anisotropic: bool, b: np.ndarray,
                   fixtures: list[str], up_targetee: np.ndarray | None = None, played: bool = False,
                   up_before: np.ndarray | None = None) -> np.ndarray:
    """``Solution.predict`` of ``unpack`` for a batch of packed parameters (K, Q) at once:
    ``cam_from_target`` (K, N, 4, 4) from ``b`` (K, N, 4, 4) and, when ``compliant``, the
    up directions (K, N, 3) (and, when ``played``, those at the captures before, NaN rows
    where none). A finite-difference Jacobian evaluates every step in one call."""
    count = len(names)
    index = np.array([names.index(f) for f in fixtures])
    poses = transform_from_vector(params[:, :6 * (1 + count)].reshape(len(params), -1, 6))  # (K, 1 + F, 4, 4)
    x_inv = g.invert(poses[:, 1 + index])
    cam_from_targetee = poses[:, :1] @ b
    if not compliant:
        return cam_from_targetee @ x_inv
    if up_targetee is None:
        raise ValueError("a solution with compliant fixtures predicts from the up directions")
    start = 6 * (1 + count)
    k = params[:, start:start + 3 * count].reshape(len(params), count, 3)[:, index]
    d = None
    if anisotropic:
        first = anisotropy_slice(names).start
        d = params[:, first:first + 6 * count].reshape(len(params), count, 6)[:, index]
    up_targetee = np.asarray(up_targetee, float)
    tilt = fixture_tilt(up_targetee, k, d)
    if played and anisotropic and up_before is not None:
        w = params[:, play_slice(names)][:, index]
        tilt = tilt @ fixture_lag(tilt_rotvec(up_targetee, k, d), tilt_rotvec(np.asarray(up_before, float), k, d), w)
    return cam_from_targetee @ tilt @ x_inv


def frobenius(a: np.ndarray, b: np.ndarray, fixtures: list[str], start: Solution,
              up_targetee: np.ndarray | None = None) -> Solution:
    """The paper's cost, Levenberg-Marquardt over rotation vectors and translations; with
    ``up_targetee`` (N, 3) also over the fixtures' compliances (from ``start``'s or zero)."""
    from scipy.optimize import least_squares
    names = sorted(start.x)
    compliant = up_targetee is not None

    def residuals(params: np.ndarray) -> np.ndarray:
        return (a - unpack(params, names, compliant).predict(b, fixtures, up_targetee))[:, :3, :].ravel()

    result = least_squares(residuals, pack(start, names, compliant), method="lm", xtol=1e-15, ftol=1e-15,
                           gtol=1e-15)
    return unpack(result.x, names, compliant)


def reprojection(b: np.ndarray, fixtures: list[str], start: Solution, object_points: list[np.ndarray],
                 pixels: list[np.ndarray], camera_matrix: np.ndarray, dist: np.ndarray,
                 up_targetee: np.ndarray | None = None) -> Solution:
    """Refine on the pattern's reprojection error: the detected corners are what was
    measured, with (nearly) independent pixel noise. object_points[i] (M_i, 3) in T."""
    from scipy.optimize import least_squares
    names = sorted(start.x)
    observed = np.concatenate(pixels)
    compliant = up_targetee is not None

    def residuals(params: np.ndarray) -> np.ndarray:
        poses = unpack(params, names, compliant).predict(b, fixtures, up_targetee)
        projected = [g.project(pose, points, camera_matrix, dist) for pose, points in zip(poses, object_points,
                                                                                          strict=True)]
        return (np.concatenate(projected) - observed).ravel()

    result = least_squares(residuals, pack(start, names, compliant), method="trf", x_scale="jac", xtol=1e-12,
                           ftol=1e-12)
    return unpack(result.x, names, compliant)
