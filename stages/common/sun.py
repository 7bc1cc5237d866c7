"""The sun's direction from an epoch, and the Earth's shadow.

ECI here is the Earth-centred frame of the mean equator and equinox of date (x towards
the vernal equinox, z the celestial pole). The sun's ecliptic longitude follows the
Astronomical Almanac's low-precision formulae (section C, "Sun: low precision"): about
0.01 deg between 1950 and 2050. The equinox of date differs from J2000's by precession,
about 0.014 deg per year since 2000 (0.37 deg in 2026): a user comparing with J2000
(GCRF) ephemerides sees that as a rotation about the pole.

Eclipse: the cylindrical shadow of a spherical Earth (no penumbra); at 700 km that puts
the shadow's edge within about 10 s of the umbra's.
"""

from __future__ import annotations

from datetime import UTC, datetime

import numpy as np

from stages.common.orbits import EARTH_RADIUS_M

J2000 = datetime(2000, 1, 1, 12, 0, 0, tzinfo=UTC)


def parse_epoch(text: str) -> datetime:
    """A UTC epoch from ISO 8601 (``2026-03-20T12:00:00Z``); ValueError if it is not one."""
    epoch = datetime.fromisoformat(text.replace("Z", "+00:00"))
    if epoch.tzinfo is None:
        raise ValueError(f"{text!r} names no time zone; write it in UTC, e.g. 2026-03-20T12:00:00Z")
    return epoch.astimezone(UTC)


def sun_eci(epoch: datetime, times_s: np.ndarray) -> np.ndarray:
    """Unit vectors (N, 3) from the Earth's centre to the sun at ``times_s`` after ``epoch``."""
    days = (epoch - J2000).total_seconds() / 86400.0 + np.atleast_1d(np.asarray(times_s, float)) / 86400.0
    mean_longitude = np.radians(280.460 + 0.9856474 * days)
    mean_anomaly = np.radians(357.528 + 0.9856003 * days)
    longitude = mean_longitude + np.radians(1.915 * np.sin(mean_anomaly) + 0.020 * np.sin(2 * mean_anomaly))
    obliquity = np.radians(23.439 - 0.0000004 * days)
    return np.stack([np.cos(longitude), np.cos(obliquity) * np.sin(longitude),
                     np.sin(obliquity) * np.sin(longitude)], axis=-1)


def in_shadow(position_eci_m: np.ndarray, sun_direction: np.ndarray) -> np.ndarray:
    """Whether each position (N, 3) is in the Earth's cylindrical shadow (N,) bool."""
    along = np.einsum("ni,ni->n", position_eci_m, sun_direction)
    across = np.linalg.norm(position_eci_m - along[:, None] * sun_direction, axis=-1)
    return (along < 0) & (across < EARTH_RADIUS_M)
