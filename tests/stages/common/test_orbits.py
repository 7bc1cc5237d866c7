"""Relative motion: exact two-body propagation, the ROE definition, and D'Amico's linear
model against two-body propagation of both orbits."""

import math

import numpy as np
import pytest

from stages.common.orbits import MU_EARTH, Elements, RoeModel, deputy_elements, relative_two_body, two_body


def random_chief(rng, e_max=0.01):
    return Elements(float(rng.uniform(6.8e6, 7.5e6)), float(rng.uniform(0.0, e_max)),
                    float(rng.uniform(0.3, 2.8)), *(float(v) for v in rng.uniform(0, 2 * np.pi, 3)))


def roe_of(chief, deputy):
    """The ROE definition (orbits.py's docstring), written out independently."""
    u_c, u_d = chief.argp_rad + chief.mean_anomaly_rad, deputy.argp_rad + deputy.mean_anomaly_rad
    d_raan = deputy.raan_rad - chief.raan_rad
    return np.array([(deputy.a_m - chief.a_m) / chief.a_m,
                     (u_d - u_c) + d_raan * math.cos(chief.i_rad),
                     deputy.e * math.cos(deputy.argp_rad) - chief.e * math.cos(chief.argp_rad),
                     deputy.e * math.sin(deputy.argp_rad) - chief.e * math.sin(chief.argp_rad),
                     deputy.i_rad - chief.i_rad, d_raan * math.sin(chief.i_rad)])


@pytest.mark.parametrize("seed", range(5))
def test_two_body_keeps_energy_and_momentum_and_closes_its_orbit(seed):
    chief = random_chief(np.random.default_rng(seed), e_max=0.3)
    period = 2 * np.pi / chief.mean_motion_rad_s
    times = np.linspace(0.0, period, 97)
    r, v = two_body(chief, times)
    energy = 0.5 * np.sum(v * v, axis=1) - MU_EARTH / np.linalg.norm(r, axis=1)
    np.testing.assert_allclose(energy, -MU_EARTH / (2 * chief.a_m), rtol=1e-12)
    momentum = np.cross(r, v)
    assert np.linalg.norm(momentum - momentum[0], axis=1).max() < 1e-12 * np.linalg.norm(momentum[0])
    np.testing.assert_allclose(r[-1], r[0], atol=1e-6)
    # the velocity is the derivative of the position
    step = 1e-3
    ahead, _ = two_body(chief, times[:5] + step)
    behind, _ = two_body(chief, times[:5] - step)
    np.testing.assert_allclose((ahead - behind) / (2 * step), v[:5], rtol=1e-7, atol=1e-6)


@pytest.mark.parametrize("seed", range(5))
def test_the_deputys_elements_invert_the_roe_definition(seed):
    rng = np.random.default_rng(seed)
    chief = random_chief(rng)
    roe = rng.normal(0.0, 50.0, 6) / chief.a_m
    np.testing.assert_allclose(roe_of(chief, deputy_elements(chief, roe)), roe, atol=1e-15)


@pytest.mark.parametrize("seed", range(6))
def test_the_linear_model_follows_two_body_motion_to_first_order(seed):
    """Over an orbit its error is second order in the separation on a circular chief, and
    about e times the separation on an eccentric one (its near-circular mapping)."""
    rng = np.random.default_rng(100 + seed)
    circular = random_chief(rng, e_max=0.0)
    roe = rng.normal(0.0, 20.0, 6) / circular.a_m
    times = np.linspace(0.0, 2 * np.pi / circular.mean_motion_rad_s, 120)
    reference = relative_two_body(circular, roe, times)
    separation = np.linalg.norm(reference, axis=1).max()
    error = np.linalg.norm(RoeModel(circular, roe).rtn_m(times) - reference, axis=1).max()
    assert error < 10 * separation ** 2 / circular.a_m + 1e-6
    eccentric = Elements(circular.a_m, 0.002, circular.i_rad, circular.raan_rad, circular.argp_rad,
                         circular.mean_anomaly_rad)
    reference = relative_two_body(eccentric, roe, times)
    error = np.linalg.norm(RoeModel(eccentric, roe).rtn_m(times) - reference, axis=1).max()
    assert error < 3 * eccentric.e * np.linalg.norm(reference, axis=1).max()


def test_a_lower_orbit_drifts_ahead_by_three_pi_da_per_orbit():
    chief = Elements(7.0e6, 0.0, 1.0, 0.0, 0.0, 0.0)
    period = 2 * np.pi / chief.mean_motion_rad_s
    model = RoeModel(chief, np.array([-1.0, 0, 0, 0, 0, 0]) / chief.a_m)
    along = model.rtn_m(np.array([0.0, period]))[:, 1]
    assert along[1] - along[0] == pytest.approx(3 * np.pi, rel=1e-12)
    exact = relative_two_body(chief, model.roe, np.array([0.0, period]))[:, 1]
    assert exact[1] - exact[0] == pytest.approx(3 * np.pi, rel=1e-4)
