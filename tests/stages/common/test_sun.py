"""The sun's direction from the epoch against the equinox and a solstice, and the shadow."""

import numpy as np
import pytest

from stages.common.orbits import EARTH_RADIUS_M
from stages.common.sun import in_shadow, parse_epoch, sun_eci


def test_the_sun_is_at_the_equinox_and_the_solstice_when_almanacs_put_it_there():
    """March equinox 2025-03-20 09:01 UTC; June solstice 2025-06-21 02:42 UTC (USNO)."""
    equinox = sun_eci(parse_epoch("2025-03-20T09:01:00Z"), [0.0])[0]
    assert np.degrees(np.arctan2(equinox[1], equinox[0])) == pytest.approx(0.0, abs=0.02)
    assert np.degrees(np.arcsin(equinox[2])) == pytest.approx(0.0, abs=0.02)
    solstice = sun_eci(parse_epoch("2025-06-21T02:42:00Z"), [0.0])[0]
    assert np.degrees(np.arcsin(solstice[2])) == pytest.approx(23.436, abs=0.02)
    assert np.degrees(np.arctan2(solstice[1], solstice[0])) == pytest.approx(90.0, abs=0.02)
    # a day later, about one degree further along the ecliptic
    later = sun_eci(parse_epoch("2025-03-20T09:01:00Z"), [86400.0])[0]
    assert np.degrees(np.arccos(later @ equinox)) == pytest.approx(0.99, abs=0.03)


def test_the_shadow_is_behind_the_earth_only():
    sun = np.array([[1.0, 0.0, 0.0]] * 4)
    altitude = EARTH_RADIUS_M + 700e3
    points = np.array([[-altitude, 0, 0], [altitude, 0, 0], [0, altitude, 0], [-altitude, EARTH_RADIUS_M * 1.01, 0]])
    assert in_shadow(points, sun).tolist() == [True, False, False, False]


def test_an_epoch_names_its_time_zone():
    assert parse_epoch("2026-03-20T06:00:00+02:00").hour == 4
    with pytest.raises(ValueError, match="UTC"):
        parse_epoch("2026-03-20T06:00:00")
