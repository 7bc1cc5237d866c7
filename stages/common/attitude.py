"""A target's torque-free attitude motion: its inertia, and Euler's equations integrated.

Inertia from the mesh treats the target as a shell of uniform areal density (its mass in
its skin: panels, walls, solar arrays), which any mesh defines, watertight or not; a lab
that knows its target's inertia declares it instead (``trajectory.inertia_kgm2``).
Only the ratios of the principal moments shape torque-free motion; the mass scales the
angular momentum. A declared inertia is checked where the configuration is read
(``core/config/loading.py``: positive moments, the triangle inequality).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stages.common import geometry as g
from stages.common.target import Target


@dataclass(frozen=True)
class MassProperties:
    """Mass (kg), centre of mass (3,) m and inertia about it (3, 3) kg m^2, target body frame."""

    mass_kg: float
    centre_of_mass_m: np.ndarray
    inertia_kgm2: np.ndarray

    def principal_axes(self) -> tuple[np.ndarray, np.ndarray]:
        """Principal moments (3,) ascending and axes as columns (3, 3), right-handed."""
        moments, axes = np.linalg.eigh(self.inertia_kgm2)
        if np.linalg.det(axes) < 0:
            axes[:, 2] = -axes[:, 2]
        return moments, axes


def shell_mass_properties(target: Target, mass_kg: float) -> MassProperties:
    """The full-scale target as a uniform shell of ``mass_kg`` over all its parts' triangles.

    A triangle's second moment is exact: ``area / 12 * (sum v v^T + s s^T)``, ``s`` the sum of
    its vertices.
    """
    area_total, first, second = 0.0, np.zeros(3), np.zeros((3, 3))
    for part in target.parts.values():
        corners = part.vertices[part.faces]  # (F, 3, 3)
        areas = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
        sums = corners.sum(axis=1)
        area_total += float(areas.sum())
        first += (areas[:, None] * sums).sum(axis=0) / 3.0
        second += np.einsum("f,fki,fkj->ij", areas, corners, corners) / 12.0
        second += np.einsum("f,fi,fj->ij", areas, sums, sums) / 12.0
    if area_total <= 0:
        raise ValueError(f"target {target.name!r}: its mesh has no surface to take an inertia from")
    centre = first / area_total
    covariance = (second - area_total * np.outer(centre, centre)) * (mass_kg / area_total)
    inertia = np.trace(covariance) * np.eye(3) - covariance
    return MassProperties(mass_kg, centre, 0.5 * (inertia + inertia.T))


def torque_free(inertia_kgm2: np.ndarray, eci_from_body_q: np.ndarray, omega_body_rad_s: np.ndarray,
                times_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Attitude ``eci_from_body`` quaternions (N, 4) and body rates (N, 3) rad/s at ``times_s``
    (N,), ascending from 0: Euler's equations ``I dw/dt = -w x I w`` and ``dq/dt = q (0, w) / 2``,
    integrated with DOP853 at a relative tolerance of 1e-13."""
    from scipy.integrate import solve_ivp
    inertia = np.asarray(inertia_kgm2, float)
    inverse = np.linalg.inv(inertia)

    def derivative(_: float, state: np.ndarray) -> np.ndarray:
        q, omega = state[:4], state[4:]
        omega_dot = inverse @ -np.cross(omega, inertia @ omega)
        q_dot = 0.5 * g.quat_multiply(q, np.concatenate([[0.0], omega]))
        return np.concatenate([q_dot, omega_dot])

    times_s = np.asarray(times_s, float)
    start = np.concatenate([g.quat_normalize(eci_from_body_q), np.asarray(omega_body_rad_s, float)])
    if times_s[-1] == 0.0:
        states = start[:, None].repeat(len(times_s), axis=1)
    else:
        solution = solve_ivp(derivative, (0.0, float(times_s[-1])), start, method="DOP853", t_eval=times_s,
                             rtol=1e-13, atol=1e-15)
        states = solution.y
    quats = g.quat_normalize(states[:4].T)
    quats = np.where(quats[:, :1] < 0, -quats, quats)
    return quats, states[4:].T


def angular_momentum_eci(inertia_kgm2: np.ndarray, eci_from_body_q: np.ndarray,
                         omega_body_rad_s: np.ndarray) -> np.ndarray:
    """The angular momentum in ECI (N, 3), kg m^2/s: constant in torque-free motion."""
    rotations = g.quat_to_matrix(eci_from_body_q)
    return np.einsum("nij,jk,nk->ni", rotations, np.asarray(inertia_kgm2, float), omega_body_rad_s)
