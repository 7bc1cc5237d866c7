"""Orbits of a chief (the target) and a deputy (the servicer, carrying the camera).

Two models of the same motion:

- ``two_body``: exact Keplerian propagation of each spacecraft's classical elements
  (Kepler's equation solved to machine precision), the reference;
- ``RoeModel``: the linear relative-motion model in quasi-nonsingular relative orbital
  elements (ROE) of D'Amico (Autonomous Formation Flying in Low Earth Orbit, TU Delft
  thesis, 2010, sections 2.2-2.3; the Keplerian case of Koenig, Guffanti and D'Amico's
  state transition matrices, JGCD 40(7), 2017), the model the planner uses.

ROE, dimensionless, of the deputy d relative to the chief c (``u = argp + mean anomaly``,
the mean argument of latitude; ``e_x = e cos(argp)``, ``e_y = e sin(argp)``)::

    da      = (a_d - a_c) / a_c
    dlambda = (u_d - u_c) + (raan_d - raan_c) cos(i_c)
    dex     = e_x,d - e_x,c
    dey     = e_y,d - e_y,c
    dix     = i_d - i_c
    diy     = (raan_d - raan_c) sin(i_c)

Configuration gives them scaled by the chief's semi-major axis (``a_c * roe``, metres), as
formation-flying papers do. For a near-circular chief the deputy's position in the chief's
RTN frame (R radial, T along-track, N orbit normal) is, to first order in the ROE and in e::

    r_R / a = da - dex cos(u) - dey sin(u)
    r_T / a = dlambda + 2 dex sin(u) - 2 dey cos(u),   dlambda(t) = dlambda(0) - 1.5 n da t
    r_N / a = dix sin(u) - diy cos(u)

``bench trajectory`` measures the model's error against ``two_body`` over the presets.
Units: metres, seconds, radians; ECI is the inertial frame of ``stages/common/sun.py``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Earth's gravitational parameter (EGM2008/WGS 84), m^3/s^2
MU_EARTH = 3.986004418e14
EARTH_RADIUS_M = 6_378_137.0


@dataclass(frozen=True)
class Elements:
    """Classical Keplerian elements at an epoch (m, rad); for two-body motion the mean
    elements of the configuration are these osculating ones."""

    a_m: float
    e: float
    i_rad: float
    raan_rad: float
    argp_rad: float
    mean_anomaly_rad: float

    @property
    def mean_motion_rad_s(self) -> float:
        return float(np.sqrt(MU_EARTH / self.a_m ** 3))

    def mean_latitude_rad(self, times_s: np.ndarray | float) -> np.ndarray:
        """The mean argument of latitude ``u = argp + M`` at ``times_s`` after the epoch."""
        return self.argp_rad + self.mean_anomaly_rad + self.mean_motion_rad_s * np.asarray(times_s, float)

    def to_json(self) -> dict[str, float]:
        return {"a_m": self.a_m, "e": self.e, "i_rad": self.i_rad, "raan_rad": self.raan_rad,
                "argp_rad": self.argp_rad, "mean_anomaly_rad": self.mean_anomaly_rad}


def eccentric_anomaly(mean_anomaly: np.ndarray, e: float) -> np.ndarray:
    """Kepler's equation ``M = E - e sin E`` solved by Newton's method (e < 1), to 1e-15 rad."""
    mean_anomaly = np.asarray(mean_anomaly, float)
    eccentric = mean_anomaly + e * np.sin(mean_anomaly)
    for _ in range(50):
        step = (eccentric - e * np.sin(eccentric) - mean_anomaly) / (1.0 - e * np.cos(eccentric))
        eccentric = eccentric - step
        if np.max(np.abs(step)) < 1e-15:
            break
    return eccentric


def perifocal_to_eci(elements: Elements) -> np.ndarray:
    """Rotation (3, 3) from the perifocal frame (P towards periapsis, Q, W normal) to ECI."""
    def rz(angle: float) -> np.ndarray:
        c, s = np.cos(angle), np.sin(angle)
        return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])

    c, s = np.cos(elements.i_rad), np.sin(elements.i_rad)
    rx = np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
    return rz(elements.raan_rad) @ rx @ rz(elements.argp_rad)


def two_body(elements: Elements, times_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exact Keplerian position and velocity in ECI (N, 3) m and m/s at ``times_s`` (N,)
    after the elements' epoch."""
    times_s = np.atleast_1d(np.asarray(times_s, float))
    a, e = elements.a_m, elements.e
    eccentric = eccentric_anomaly(elements.mean_anomaly_rad + elements.mean_motion_rad_s * times_s, e)
    cos_e, sin_e = np.cos(eccentric), np.sin(eccentric)
    root = np.sqrt(1.0 - e * e)
    position = np.stack([a * (cos_e - e), a * root * sin_e, np.zeros_like(cos_e)], axis=-1)
    rate = elements.mean_motion_rad_s / (1.0 - e * cos_e)
    velocity = np.stack([-a * sin_e * rate, a * root * cos_e * rate, np.zeros_like(cos_e)], axis=-1)
    rotation = perifocal_to_eci(elements)
    return position @ rotation.T, velocity @ rotation.T


def rtn_from_eci(position: np.ndarray, velocity: np.ndarray) -> np.ndarray:
    """Rotations (N, 3, 3) from ECI to each state's RTN frame (rows R, T, N)."""
    radial = position / np.linalg.norm(position, axis=-1, keepdims=True)
    normal = np.cross(position, velocity)
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    return np.stack([radial, np.cross(normal, radial), normal], axis=-2)


def deputy_elements(chief: Elements, roe: np.ndarray) -> Elements:
    """The deputy's classical elements from the chief's and the dimensionless ROE (6,);
    the exact inverse of the definition above (needs sin(i_c) != 0)."""
    da, dlambda, dex, dey, dix, diy = (float(v) for v in roe)
    ex = chief.e * np.cos(chief.argp_rad) + dex
    ey = chief.e * np.sin(chief.argp_rad) + dey
    e = float(np.hypot(ex, ey))
    argp = float(np.arctan2(ey, ex)) if e > 0 else 0.0
    raan = chief.raan_rad + diy / np.sin(chief.i_rad)
    u = chief.argp_rad + chief.mean_anomaly_rad + dlambda - (raan - chief.raan_rad) * np.cos(chief.i_rad)
    return Elements(chief.a_m * (1.0 + da), e, chief.i_rad + dix, float(raan), argp, float(u - argp))


def relative_two_body(chief: Elements, roe: np.ndarray, times_s: np.ndarray) -> np.ndarray:
    """The deputy's position relative to the chief in the chief's RTN frame (N, 3), m, by
    exact two-body propagation of both orbits: the reference for ``RoeModel``."""
    chief_r, chief_v = two_body(chief, times_s)
    deputy_r, _ = two_body(deputy_elements(chief, roe), times_s)
    return np.einsum("nij,nj->ni", rtn_from_eci(chief_r, chief_v), deputy_r - chief_r)


@dataclass(frozen=True)
class RoeModel:
    """D'Amico's linear relative motion (module docstring) about a chief."""

    chief: Elements
    roe: np.ndarray  # (6,) dimensionless

    NAME = "roe-linear-keplerian (D'Amico 2010)"

    def roe_at(self, times_s: np.ndarray) -> np.ndarray:
        """ROE (N, 6) at ``times_s``: only the mean longitude drifts under Keplerian motion."""
        times_s = np.atleast_1d(np.asarray(times_s, float))
        roe = np.repeat(np.asarray(self.roe, float)[None], len(times_s), axis=0)
        roe[:, 1] -= 1.5 * self.chief.mean_motion_rad_s * roe[:, 0] * times_s
        return roe

    def rtn_m(self, times_s: np.ndarray) -> np.ndarray:
        """The deputy's position in the chief's RTN frame (N, 3), m."""
        times_s = np.atleast_1d(np.asarray(times_s, float))
        u = self.chief.mean_latitude_rad(times_s)
        da, dlambda, dex, dey, dix, diy = self.roe_at(times_s).T
        cos_u, sin_u = np.cos(u), np.sin(u)
        return self.chief.a_m * np.stack([
            da - dex * cos_u - dey * sin_u,
            dlambda + 2.0 * dex * sin_u - 2.0 * dey * cos_u,
            dix * sin_u - diy * cos_u,
        ], axis=-1)
