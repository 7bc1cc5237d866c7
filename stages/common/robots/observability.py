"""How well a set of calibration poses determines a facility's robots, before they are
captured (docs/architecture.md section 6): the identification of ``identification.py`` at
the plan's poses, its Jacobian whitened by the PnP noise and scaled by the lab's
tolerances, reduced to the minimum singular value and the parameters left to their prior.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stages.common import arms, rwhe
from stages.common import geometry as g
from stages.common.robots.errors import Holders
from stages.common.robots.identification import (
    WEAK_RATIO,
    Measured,
    central_jacobian,
    identifiable,
    predict_batch,
)

#: the lab's tolerances the plan's observability measure scales by (calibrate's defaults:
#: calibrate.arm_prior_*, whose help gives each its meaning)
REFERENCE_PRIORS = {"joint_rad": 2e-3, "length_m": 2e-3, "frame_rad": 2e-4, "base": (2e-3, 2e-3),
                    "rail_scale": 1e-4, "compliance_rad_per_nm": 3e-5}
#: the calibration's PnP noise the observability measure whitens by (TRON's at 0.75 m:
#: 3e-4 rad, 0.17 mm; docs/accuracy.md)
PNP_NOISE_RAD = 3e-4
PNP_NOISE_M = 2e-4


@dataclass(frozen=True)
class Observability:
    """How well a set of calibration poses determines the robots' identifiable parameters:
    the singular values of the identification Jacobian whitened by the PnP noise and scaled
    by each parameter's prior (a singular value under 1: a direction the poses determine
    less well than the lab's tolerance already does), and each parameter's posterior over
    prior 1-sigma where it is above ``WEAK_RATIO``."""

    parameters: int
    smallest: float
    condition: float
    under_prior: int  # directions with a singular value under 1
    weak: dict[str, float]

    def describe(self, poses: int, brief: bool = False) -> str:
        """In words; ``brief``: one short line (the plan's), without the weak directions' names."""
        if brief:
            return (f"{poses} calibration poses determine the robots' {self.parameters} identifiable parameters, "
                    f"{self.under_prior} direction(s) less well than the priors (speedplus facility names them)")
        weakest = sorted(self.weak.items(), key=lambda item: -item[1])[:4]
        named = ", ".join(f"{name} ({ratio:.0%} of its prior)" for name, ratio in weakest)
        return (f"{poses} calibration poses determine the robots' {self.parameters} identifiable parameters with "
                f"smallest singular value {self.smallest:.3g} (in prior sigmas; condition number "
                f"{self.condition:.3g}); {self.under_prior} direction(s) less well than the priors"
                + (f"; weakly determined: {named}" + (f" and {len(self.weak) - 4} more" if len(self.weak) > 4 else "")
                   if self.weak else ""))


@dataclass(frozen=True)
class Rows:
    """The identification's Jacobian at N poses, whitened by the PnP noise (six rows a
    pose: rotation, then position): ``arm`` (N, 6, A) by the identifiable arm parameters,
    each scaled by its prior 1-sigma (so the prior's information is the identity), and
    ``offsets`` (N, 6, O) by the hand-eye and fixture offsets, which the fit leaves free."""

    arm: np.ndarray
    offsets: np.ndarray
    names: tuple[str, ...]  # (A,) the arm parameters' names


def jacobian_rows(holders: Holders, m: Measured, prior: np.ndarray, payload: arms.Payload,
                  world_up: np.ndarray) -> Rows:
    """``Rows`` of the module's identification at readings ``m``, offsets at identity; the
    parameters whose ``prior`` is 0 are left out (the joints' lost motion, which the order of
    the captures' moves determines, not their poses)."""
    names = sorted(set(m.fixtures))
    start = rwhe.Solution(np.eye(4), {name: np.eye(4) for name in names})
    params = np.concatenate([np.zeros(holders.size), rwhe.pack(start, names, False)])
    free = np.concatenate([np.asarray(prior) > 0, np.ones(len(params) - holders.size, bool)])
    dropped = identifiable(holders, list(m.fixtures), False, params, free, payload, world_up)
    kept = np.array([i for i, name in enumerate(holders.names) if name not in dropped and free[i]])
    centre = predict_batch(holders, params[None], names, False, m, world_up)[0]

    def twists(p: np.ndarray) -> np.ndarray:
        """Each pose's rotation from the centre's (applied on the camera side) and position."""
        poses = predict_batch(holders, p, names, False, m, world_up)
        rotation = g.matrix_to_rotvec(poses[..., :3, :3] @ np.swapaxes(centre[:, :3, :3], -1, -2)) / PNP_NOISE_RAD
        return np.concatenate([rotation, poses[..., :3, 3] / PNP_NOISE_M], axis=-1).reshape(len(p), -1)

    jacobian = central_jacobian(twists, params).reshape(len(m.rail_m), 6, len(params))
    return Rows(jacobian[..., kept] * prior[kept], jacobian[..., holders.size:],
                tuple(holders.names[i] for i in kept))


def _information(rows: Rows, chosen: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The normal matrices of poses ``chosen``: arm-arm (A, A), arm-offsets (A, O), offsets-offsets (O, O)."""
    arm = rows.arm[chosen].reshape(-1, rows.arm.shape[-1])
    offsets = rows.offsets[chosen].reshape(-1, rows.offsets.shape[-1])
    return arm.T @ arm, arm.T @ offsets, offsets.T @ offsets


def _reduced(normal: tuple[np.ndarray, np.ndarray, np.ndarray]) -> np.ndarray:
    """The arm parameters' information with the free offsets eliminated (the Schur
    complement), plus the prior's identity: the posterior precision in prior sigmas."""
    aa, ao, oo = normal
    return aa - ao @ np.linalg.pinv(oo, rcond=1e-10, hermitian=True) @ ao.T + np.eye(len(aa))


def choose(rows: Rows, slots: list[list[int]]) -> list[int]:
    """One pose of each slot's candidates (indices into ``rows``), slot after slot, each the
    one that most raises the smallest eigenvalue of the data's information on the arms'
    parameters (in prior sigmas, the free offsets eliminated) given the poses chosen before
    it: the square of the smallest singular value ``observability`` reports (Nahvi and
    Hollerbach's minimum singular value, ICRA 1996). Ties (within 1%, as while fewer poses
    than parameters leave it at zero) are broken by the log-determinant of the posterior
    precision, which keeps every other direction moving. Greedy, as Sun and Hollerbach's
    active robot calibration (ICRA 2008) is: a slot's choice never depends on later slots,
    so a resumed plan chooses the same poses."""
    chosen: list[int] = []
    aa = np.zeros((rows.arm.shape[-1],) * 2)
    ao = np.zeros((rows.arm.shape[-1], rows.offsets.shape[-1]))
    oo = np.zeros((rows.offsets.shape[-1],) * 2)
    for candidates in slots:
        scores = []
        for candidate in candidates:
            more = _information(rows, np.array([candidate]))
            eigen = np.linalg.eigvalsh(_reduced((aa + more[0], ao + more[1], oo + more[2])))
            # the data's share of the posterior precision (the prior's is the identity); a
            # rounding error's worth of it is none
            smallest = eigen[0] - 1.0
            scores.append((smallest if smallest > 1e-14 * eigen[-1] else 0.0, float(np.sum(np.log(eigen)))))
        best = max(score[0] for score in scores)
        near = [i for i, score in enumerate(scores) if score[0] >= 0.99 * best]
        pick = candidates[max(near, key=lambda i: scores[i][1])]
        more = _information(rows, np.array([pick]))
        aa, ao, oo = aa + more[0], ao + more[1], oo + more[2]
        chosen.append(pick)
    return chosen


def observability(holders: Holders, m: Measured, prior: np.ndarray, payload: arms.Payload,
                  world_up: np.ndarray) -> Observability:
    """The measure of the module's identification at readings ``m`` (the plan's calibration
    poses), offsets at identity: the smallest singular value of the prior-scaled, noise-
    whitened Jacobian (Nahvi and Hollerbach's minimum singular value, "The noise
    amplification index for optimal pose selection in robot calibration", ICRA 1996). It is
    the one a single bad direction cannot hide in, as a determinant or a mean can."""
    return measure_of(jacobian_rows(holders, m, prior, payload, world_up))


def measure_of(rows: Rows) -> Observability:
    """``Observability`` of all of ``rows``' poses."""
    offsets = rows.offsets.reshape(-1, rows.offsets.shape[-1])
    arm = rows.arm.reshape(-1, rows.arm.shape[-1])
    # the offsets are free: only what the arms' parameters add beyond them counts
    u, s, _ = np.linalg.svd(offsets, full_matrices=False)
    basis = u[:, s > s[0] * 1e-9]
    arm = arm - basis @ (basis.T @ arm)
    singular = np.linalg.svd(arm, compute_uv=False)
    posterior = np.linalg.inv(arm.T @ arm + np.eye(arm.shape[1]))
    ratio = np.sqrt(np.diag(posterior))
    weak = {name: round(float(r), 3) for name, r in zip(rows.names, ratio, strict=True) if r > WEAK_RATIO}
    # fewer equations than parameters: the directions past them are not measured at all
    unmeasured = max(0, arm.shape[1] - len(singular))
    smallest = 0.0 if unmeasured else float(singular[-1])
    return Observability(arm.shape[1], smallest, float(singular[0] / max(smallest, 1e-300)),
                         int(np.sum(singular < 1.0)) + unmeasured, weak)
