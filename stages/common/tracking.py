"""A navigation filter over a sequence of per-frame pose estimates (a CNN's), the tracking
baseline of evaluate for rendezvous sequences.

Two filters, both fed the measured ``cam_from_target`` and the servicer's own knowledge of
its attitude (``eci_from_cam``) and orbit (the chief's RTN frame):

- attitude: a multiplicative EKF (Markley, JGCD 26(2), 2003) of ``eci_from_target`` and the
  body rate, constant angular velocity driven by white angular acceleration; the error
  state is the small rotation in the body frame;
- position: a linear Kalman filter of the relative orbital elements at the sequence's epoch
  (``a`` times D'Amico's ROE, metres), whose measurement is the servicer's position in RTN,
  mapped by the linear model of ``stages/common/orbits.py`` (the dynamics are in the map);
  a random walk lets the elements move.

Each measurement passes an innovation gate (the squared Mahalanobis distance under the
chi-square quantile of ``gate_probability``) or is not used. The attitude filter starts
from three measurements in a row that one body rate explains, and restarts so after
``reset_after`` rejections in a row (a filter that locked onto a wrong estimate recovers);
until it starts, a frame's own rotation stands for it. Units: metres, seconds, radians.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stages.common import geometry as g
from stages.common.orbits import Elements


@dataclass(frozen=True)
class TrackingNoise:
    """What the filters assume (rad, fractions of the range, rad/s^2, m/s^0.5)."""

    rotation_sigma_rad: float
    lateral_sigma: float  # across the boresight, times the range
    depth_sigma: float  # along the boresight, times the range
    angular_acceleration_sigma: float
    roe_walk_m_per_sqrt_s: float
    gate_probability: float = 0.999
    reset_after: int = 3


@dataclass(frozen=True)
class Measurement:
    """One frame: its time (s since the epoch), the measured ``cam_from_target`` (None when the
    model gave no pose; translation full scale, m), the servicer's ``eci_from_cam`` (3, 3), and
    the chief's ``rtn_from_eci`` (3, 3) and mean argument of latitude (rad)."""

    time_s: float
    cam_from_target: np.ndarray | None
    eci_from_cam: np.ndarray
    rtn_from_eci: np.ndarray
    latitude_rad: float


@dataclass(frozen=True)
class TrackedFrame:
    cam_from_target: np.ndarray  # (4, 4) the filters' estimate after this frame
    rotation_used: bool
    position_used: bool


def roe_map(chief: Elements, time_s: float, latitude_rad: float) -> np.ndarray:
    """(3, 6): the servicer's RTN position from ``a`` times the ROE at the epoch (orbits.py)."""
    cos_u, sin_u = np.cos(latitude_rad), np.sin(latitude_rad)
    drift = -1.5 * chief.mean_motion_rad_s * time_s
    return np.array([[1.0, 0, -cos_u, -sin_u, 0, 0],
                     [drift, 1.0, 2 * sin_u, -2 * cos_u, 0, 0],
                     [0, 0, 0, 0, sin_u, -cos_u]])


class AttitudeFilter:
    """The multiplicative EKF of ``eci_from_target`` (module docstring).

    It starts (and, after ``reset_after`` rejections in a row, restarts) only from three
    measurements in a row that a constant body rate explains within the gate: one flipped or
    wild estimate can neither start it nor pull it away. Until then it has no estimate."""

    def __init__(self, noise: TrackingNoise) -> None:
        from scipy.stats import chi2
        self.noise, self.q, self.omega, self.time = noise, None, np.zeros(3), 0.0
        self.covariance = np.zeros((6, 6))
        self.rejections = 0
        self.gate = chi2.ppf(noise.gate_probability, 3)
        self.recent: list[tuple[float, np.ndarray]] = []  # (time, q) since the filter last took one

    def _rate(self, first: tuple[float, np.ndarray], second: tuple[float, np.ndarray]) -> np.ndarray:
        """The constant body rate (3,) rad/s that turns one measurement into the other."""
        return g.quat_to_rotvec(g.quat_multiply(g.quat_conjugate(first[1]), second[1])) / (second[0] - first[0])

    def _try_start(self) -> bool:
        """Start from the last three measurements when a constant rate explains them."""
        if len(self.recent) < 3:
            return False
        (t1, q1), (t2, q2), (t3, q3) = self.recent[-3:]
        if not (t1 < t2 < t3):
            return False
        predicted = g.quat_multiply(q2, g.rotvec_to_quat(self._rate((t1, q1), (t2, q2)) * (t3 - t2)))
        miss = g.quat_to_rotvec(g.quat_multiply(g.quat_conjugate(predicted), q3))
        sigma = self.noise.rotation_sigma_rad
        spread = 1 + 2 * ((t3 - t2) / (t2 - t1)) ** 2 + 1  # the noise of q1, q2 carried to t3, and q3's own
        if miss @ miss > self.gate * spread * sigma ** 2:
            return False
        self.q, self.omega, self.time = g.quat_normalize(q3), self._rate((t1, q1), (t3, q3)), t3
        self.covariance = np.diag([sigma ** 2] * 3 + [2 * (sigma / (t3 - t1)) ** 2] * 3)
        self.rejections, self.recent = 0, []
        return True

    def predict(self, time_s: float) -> None:
        dt = time_s - self.time
        if self.q is None:
            self.time = time_s
            return
        if dt <= 0:
            return
        self.q = g.quat_normalize(g.quat_multiply(self.q, g.rotvec_to_quat(self.omega * dt)))
        transition = np.eye(6)
        transition[:3, :3] = g.rotvec_to_matrix(-self.omega * dt)
        transition[:3, 3:] = np.eye(3) * dt
        s2 = self.noise.angular_acceleration_sigma ** 2
        noise = np.kron(np.array([[dt ** 3 / 3, dt ** 2 / 2], [dt ** 2 / 2, dt]]) * s2, np.eye(3))
        self.covariance = transition @ self.covariance @ transition.T + noise
        self.time = time_s

    def update(self, q_measured: np.ndarray) -> bool:
        """Fold in a measured ``eci_from_target`` quaternion; whether the filter took it."""
        self.recent = [*self.recent[-2:], (self.time, g.quat_normalize(q_measured))]
        if self.q is None:
            return self._try_start()
        error = g.quat_multiply(g.quat_conjugate(self.q), q_measured)
        innovation = g.quat_to_rotvec(g.quat_normalize(error))
        observation = np.hstack([np.eye(3), np.zeros((3, 3))])
        innovation_cov = observation @ self.covariance @ observation.T + np.eye(3) * self.noise.rotation_sigma_rad ** 2
        if innovation @ np.linalg.solve(innovation_cov, innovation) > self.gate:
            self.rejections += 1
            return self.rejections >= self.noise.reset_after and self._try_start()
        gain = self.covariance @ observation.T @ np.linalg.inv(innovation_cov)
        correction = gain @ innovation
        self.q = g.quat_normalize(g.quat_multiply(self.q, g.rotvec_to_quat(correction[:3])))
        self.omega = self.omega + correction[3:]
        self.covariance = (np.eye(6) - gain @ observation) @ self.covariance
        self.rejections, self.recent = 0, []
        return True


class PositionFilter:
    """The linear Kalman filter of ``a`` times the ROE at the epoch (module docstring)."""

    def __init__(self, chief: Elements, noise: TrackingNoise, prior_range_m: float) -> None:
        from scipy.stats import chi2
        self.chief, self.noise, self.time, self.prior_range_m = chief, noise, 0.0, prior_range_m
        self.state, self.covariance = np.zeros(6), np.eye(6) * (10.0 * prior_range_m) ** 2
        self.gate = chi2.ppf(noise.gate_probability, 3)
        self.rejected: list[tuple[float, np.ndarray, np.ndarray, float]] = []  # in a row, as (time, rtn, cov, u)

    def predict(self, time_s: float) -> None:
        dt = time_s - self.time
        if dt > 0:
            self.covariance = self.covariance + np.eye(6) * self.noise.roe_walk_m_per_sqrt_s ** 2 * dt
            self.time = time_s

    def rtn(self, time_s: float, latitude_rad: float) -> np.ndarray:
        return roe_map(self.chief, time_s, latitude_rad) @ self.state

    def _fold(self, time_s: float, rtn_measured: np.ndarray, rtn_covariance: np.ndarray, latitude_rad: float,
              gated: bool) -> bool:
        observation = roe_map(self.chief, time_s, latitude_rad)
        innovation = rtn_measured - observation @ self.state
        innovation_cov = observation @ self.covariance @ observation.T + rtn_covariance
        if gated and innovation @ np.linalg.solve(innovation_cov, innovation) > self.gate:
            return False
        gain = self.covariance @ observation.T @ np.linalg.inv(innovation_cov)
        self.state = self.state + gain @ innovation
        self.covariance = (np.eye(6) - gain @ observation) @ self.covariance
        return True

    def update(self, rtn_measured: np.ndarray, rtn_covariance: np.ndarray, latitude_rad: float) -> bool:
        """Fold in a measured RTN position; whether it passed the gate. ``reset_after``
        rejections in a row start the filter again from its prior and those measurements."""
        if self._fold(self.time, rtn_measured, rtn_covariance, latitude_rad, gated=True):
            self.rejected = []
            return True
        self.rejected.append((self.time, rtn_measured, rtn_covariance, latitude_rad))
        if len(self.rejected) < self.noise.reset_after:
            return False
        self.state, self.covariance = np.zeros(6), np.eye(6) * (10.0 * self.prior_range_m) ** 2
        for time_s, rtn, covariance, latitude in self.rejected:
            self._fold(time_s, rtn, covariance, latitude, gated=False)
        self.rejected = []
        return True


def track(measurements: list[Measurement], chief: Elements, centre_of_mass_m: np.ndarray, noise: TrackingNoise
          ) -> list[TrackedFrame]:
    """The filtered ``cam_from_target`` after each frame (in time order), and whether each
    frame's measurement passed the gates."""
    ranges = [np.linalg.norm(m.cam_from_target[:3, 3]) for m in measurements if m.cam_from_target is not None]
    attitude = AttitudeFilter(noise)
    position = PositionFilter(chief, noise, float(np.median(ranges)) if ranges else 10.0)
    out, com = [], np.asarray(centre_of_mass_m, float)
    for m in measurements:
        attitude.predict(m.time_s)
        position.predict(m.time_s)
        rotation_used = position_used = False
        if m.cam_from_target is not None:
            eci_from_target = m.eci_from_cam @ m.cam_from_target[:3, :3]
            rotation_used = attitude.update(g.matrix_to_quat(eci_from_target))
            centre_cam = m.cam_from_target[:3, 3] + m.cam_from_target[:3, :3] @ com
            rtn_from_cam = m.rtn_from_eci @ m.eci_from_cam
            distance = float(np.linalg.norm(centre_cam))
            sigma_cam = np.diag([noise.lateral_sigma, noise.lateral_sigma, noise.depth_sigma]) ** 2 * distance ** 2
            position_used = position.update(-rtn_from_cam @ centre_cam, rtn_from_cam @ sigma_cam @ rtn_from_cam.T,
                                            m.latitude_rad)
        if attitude.q is not None:
            eci_from_target = g.quat_to_matrix(attitude.q)
        elif m.cam_from_target is not None:  # until the filter starts, the frame's own estimate
            eci_from_target = m.eci_from_cam @ m.cam_from_target[:3, :3]
        else:
            out.append(TrackedFrame(np.full((4, 4), np.nan), False, False))
            continue
        cam_from_eci = m.eci_from_cam.T
        centre_cam = -cam_from_eci @ m.rtn_from_eci.T @ position.rtn(m.time_s, m.latitude_rad)
        rotation = cam_from_eci @ eci_from_target
        out.append(TrackedFrame(g.make_transform(rotation, centre_cam - rotation @ com), rotation_used, position_used))
    return out
