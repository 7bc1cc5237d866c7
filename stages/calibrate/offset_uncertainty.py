"""How well a source's hand-eye offsets are determined (docs/architecture.md section 6): their
covariance, and the directions the calibration poses leave weak, named in words.

Without the arms, the covariance is the offsets' own: ``(J^T W J)^-1`` of the twist
residuals (each pose's rotation vector and translation, ``stages.common.arms.map_fit``)
at the solution, each group weighed by its Helmert scale (sum of squares over redundancy).
With the arms fitted, it is the fit's block for the offsets, marginal over the arms'.

A pose set whose motions turn about one axis cannot fix the offsets' translation along
that axis (Tsai and Lenz 1989: the rotation axes of two motions must not be parallel);
a direction whose 1-sigma exceeds ``WEAK_M`` (or ``WEAK_RAD``) is named with the axis the
poses turn about, so that a lab learns it before its labels carry it.
"""

from __future__ import annotations

import numpy as np

from manifests.sidecars import OffsetUncertainty
from stages.common import arms, rwhe
from stages.common import geometry as g

#: a translation direction of an offset is weakly determined above this 1-sigma (m)
WEAK_M = 2e-3
#: a rotation direction above this 1-sigma (rad; 0.057 deg)
WEAK_RAD = 1e-3
#: a direction whose 1-sigma exceeds its limit this many times over is said undetermined (the
#: data hold nothing of it; its variance is the information's floor, not a measurement)
UNDETERMINED = 1000.0
#: the poses turn about one axis when the second singular value of their rotation axes is
#: under this share of the first
ONE_AXIS = 0.2


def _inverse(information: np.ndarray) -> np.ndarray:
    """The covariance of an information matrix; a direction the data leave undetermined gets
    a huge finite variance (a pseudo-inverse would give it none, and call it certain)."""
    values, vectors = np.linalg.eigh(0.5 * (information + information.T))
    floor = max(float(values[-1]), 1e-300) * 1e-14
    return (vectors / np.maximum(values, floor)) @ vectors.T


def offsets_covariance(a: np.ndarray, b: np.ndarray, fixtures: list[str], solution: rwhe.Solution,
                       up: np.ndarray | None, step: float = 1e-7) -> np.ndarray:
    """(6 + 6 F, 6 + 6 F) covariance of ``rwhe.pack(solution)``'s Z and X_f (the first 6 + 6 F
    entries) from PnP poses ``a`` and measurements ``b`` (N, 4, 4), the fixtures' compliance
    held at the solution's."""
    names = sorted(solution.x)
    compliant, anisotropic = bool(solution.compliance), bool(solution.anisotropy)
    params = rwhe.pack(solution, names, compliant, anisotropic)
    size = 6 + 6 * len(names)
    moved = np.repeat(params[None], size + 1, axis=0)
    moved[1 + np.arange(size), np.arange(size)] += step
    count = len(moved)
    predicted = rwhe.predict_packed(moved, names, compliant, anisotropic, np.broadcast_to(b, (count, *b.shape)),
                                    fixtures, None if up is None else np.broadcast_to(up, (count, *up.shape)))
    residual = arms.pose_difference(a[None], predicted)  # (P + 1, N, 6)
    jacobian = ((residual[0] - residual[1:]) / step).reshape(size, -1).T  # (6 N, P): d(prediction)/dp
    values = residual[0]
    scale = np.array([np.sqrt(np.mean(values[:, :3] ** 2)), np.sqrt(np.mean(values[:, 3:] ** 2))])
    for _ in range(3):  # Helmert: each group's scale from its redundancy
        weights = np.tile(np.repeat(1.0 / np.maximum(scale, 1e-12), 3), len(a))
        whitened = jacobian * weights[:, None]
        covariance = _inverse(whitened.T @ whitened)
        leverage = np.einsum("ij,jk,ik->i", whitened, covariance, whitened).reshape(len(a), 6)
        redundancy = [max(3 * len(a) - leverage[:, :3].sum(), 1.0), max(3 * len(a) - leverage[:, 3:].sum(), 1.0)]
        scale = np.array([np.sqrt(np.sum(values[:, :3] ** 2) / redundancy[0]),
                          np.sqrt(np.sum(values[:, 3:] ** 2) / redundancy[1])])
    weights = np.tile(np.repeat(1.0 / np.maximum(scale, 1e-12), 3), len(a))
    whitened = jacobian * weights[:, None]
    return _inverse(whitened.T @ whitened)


def turning_axes(b: np.ndarray, side: str) -> tuple[np.ndarray, float]:
    """The axis (3,) the measurements' rotations (``b``: (N, 4, 4), ``B = camee_from_targetee``
    or its motion-capture counterpart) mostly turn about, in the camera side's frame
    (``side`` "camera": of ``B_i B_0^-1``) or the target side's ("target": of
    ``B_0^-1 B_i``), and the share of the second axis's spread (0: all about one axis)."""
    rotations = b[:, :3, :3]
    first = np.swapaxes(rotations[0], -1, -2)
    relative = rotations @ first[None] if side == "camera" else first[None] @ rotations
    axes = g.matrix_to_rotvec(relative)
    _, singular, vt = np.linalg.svd(axes, full_matrices=False)
    return vt[0], float(singular[1] / singular[0]) if singular[0] > 0 else 0.0


def _axis_name(vector: np.ndarray) -> str:
    index = int(np.argmax(np.abs(vector)))
    if abs(vector[index]) > 0.9:
        return "xyz"[index]
    return "(" + ", ".join(f"{v:+.2f}" for v in vector) + ")"


def weak_directions(covariance: np.ndarray, solution: rwhe.Solution, z_name: str, x_name: str,
                    b: np.ndarray) -> list[str]:
    """Sentences naming each offset direction whose 1-sigma exceeds ``WEAK_M``/``WEAK_RAD``,
    each with the axis the poses turn about, in the offset's own frame (the camera's for
    ``Z``, the target's for each ``X_f``): a translation along it is what they cannot fix."""
    names = sorted(solution.x)
    frames = [("camera", z_name, solution.z, "the camera frame")]
    frames += [("target", f"{x_name}[{name}]", solution.x[name], "the target frame") for name in names]
    out = []
    for block, (side, label, offset, frame) in enumerate(frames):
        axis, spread = turning_axes(b, side)
        why = (f"the poses turn about one axis ({_axis_name(offset[:3, :3] @ axis)} of {frame})" if spread < ONE_AXIS
               else "the poses' rotations and positions vary too little to fix it")
        for part, unit, limit, scale in ((slice(3, 6), "mm", WEAK_M, 1000.0),
                                         (slice(0, 3), "deg", WEAK_RAD, float(np.degrees(1.0)))):
            at = slice(6 * block + part.start, 6 * block + part.stop)
            values, vectors = np.linalg.eigh(covariance[at, at])
            sigma = float(np.sqrt(max(values[-1], 0.0)))
            if sigma > limit:
                kind = "" if unit == "mm" else " rotation about"
                size = "undetermined" if sigma > UNDETERMINED * limit else f"+-{sigma * scale:.3g} {unit}"
                out.append(f"{label}{kind} {_axis_name(vectors[:, -1])} {size}: {why}")
    return out


def uncertainty(covariance: np.ndarray, solution: rwhe.Solution, z_name: str, x_name: str,
                b: np.ndarray) -> OffsetUncertainty:
    """The record of ``offsets_covariance`` (or the arms' fit's offset block) of ``solution``."""
    names = sorted(solution.x)
    sigma = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
    by_fixture = {name: tuple(float(v) for v in sigma[6 + 6 * i:12 + 6 * i]) for i, name in enumerate(names)}
    return OffsetUncertainty(tuple(float(v) for v in sigma[:6]), by_fixture,
                             tuple(tuple(float(v) for v in row) for row in covariance),
                             tuple(weak_directions(covariance, solution, z_name, x_name, b)))
