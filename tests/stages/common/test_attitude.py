"""Torque-free attitude: the inertia of a shell, what a body's inertia can be, and Euler's
equations integrated without losing angular momentum."""

from types import SimpleNamespace

import numpy as np
import pytest
import trimesh

from stages.common import geometry as g
from stages.common.attitude import (
    MassProperties,
    angular_momentum_eci,
    shell_mass_properties,
    torque_free,
)


def box_target(extents, centre=(0.0, 0.0, 0.0)):
    mesh = trimesh.creation.box(extents=extents)
    mesh.apply_translation(centre)
    part = SimpleNamespace(name="body", vertices=np.asarray(mesh.vertices), faces=np.asarray(mesh.faces))
    return SimpleNamespace(name="box", parts={"body": part})


def test_a_cube_shells_inertia_is_five_eighteenths_m_s_squared_about_its_centre():
    masses = shell_mass_properties(box_target((2.0, 2.0, 2.0), centre=(0.3, -0.2, 1.0)), mass_kg=6.0)
    np.testing.assert_allclose(masses.centre_of_mass_m, [0.3, -0.2, 1.0], atol=1e-12)
    np.testing.assert_allclose(masses.inertia_kgm2, 5 / 18 * 6.0 * 4.0 * np.eye(3), atol=1e-12)


def test_a_long_box_spins_stably_about_its_major_axis():
    masses = shell_mass_properties(box_target((1.0, 2.0, 4.0)), mass_kg=10.0)
    moments, axes = masses.principal_axes()
    assert moments[0] < moments[1] < moments[2]
    assert abs(axes[:, 0] @ [0, 0, 1]) == pytest.approx(1.0)  # the long axis has the least inertia
    assert np.linalg.det(axes) == pytest.approx(1.0)


@pytest.mark.parametrize(("inertia", "why"), [([1, 1, 3, 0, 0, 0], "not a rigid body's"),
                                              ([1, 2, -1, 0, 0, 0], "not a rigid body's"),
                                              ([1, 2], "expected \\(Ixx")])
def test_a_declared_body_that_cannot_exist_is_named(inertia, why):
    from core.config import ConfigError
    from pipeline.config import load_config

    load_config("smoke", overrides=["plan.mode=trajectory", "trajectory.inertia_kgm2=[1, 2, 2.5, 0.1, 0, 0]"])
    with pytest.raises(ConfigError, match=rf"trajectory.inertia_kgm2: .*{why}"):
        load_config("smoke", overrides=["plan.mode=trajectory", f"trajectory.inertia_kgm2={inertia}"])


@pytest.mark.parametrize("seed", range(4))
def test_angular_momentum_and_energy_are_conserved_to_1e_9(seed):
    rng = np.random.default_rng(seed)
    moments = np.sort(rng.uniform(1.0, 10.0, 3))
    moments[2] = min(moments[2], moments[0] + moments[1])
    axes = g.quat_to_matrix(g.random_quats(rng, 1)[0])
    inertia = axes @ np.diag(moments) @ axes.T
    omega0 = rng.normal(0.0, np.radians(3.0), 3)
    times = np.arange(121) * 5.0  # ten minutes at SHIRT's 5 s
    quats, omegas = torque_free(inertia, g.random_quats(rng, 1)[0], omega0, times)
    momentum = angular_momentum_eci(inertia, quats, omegas)
    assert np.max(np.linalg.norm(momentum - momentum[0], axis=1)) < 1e-9 * np.linalg.norm(momentum[0])
    energy = 0.5 * np.einsum("ni,ij,nj->n", omegas, inertia, omegas)
    np.testing.assert_allclose(energy, energy[0], rtol=1e-9)
    # the body really turns: a tumbling body's attitude leaves its start
    assert g.quat_angular_distance(quats[0], quats[-1]) > 0.1


def test_a_spin_about_a_principal_axis_is_a_steady_rotation():
    inertia = np.diag([2.0, 3.0, 4.0])
    rate = np.radians(2.0)
    quats, omegas = torque_free(inertia, np.array([1.0, 0, 0, 0]), [0.0, 0.0, rate], np.arange(10) * 5.0)
    np.testing.assert_allclose(omegas, np.broadcast_to([0, 0, rate], omegas.shape), atol=1e-15)
    expected = g.rotvec_to_quat(np.outer(np.arange(10) * 5.0 * rate, [0, 0, 1]))
    np.testing.assert_allclose(g.quat_angular_distance(quats, expected), 0.0, atol=1e-11)


def test_mass_properties_name_their_axes_right_handed():
    masses = MassProperties(1.0, np.zeros(3), np.diag([3.0, 1.0, 2.0]))
    moments, axes = masses.principal_axes()
    np.testing.assert_allclose(moments, [1.0, 2.0, 3.0])
    assert np.linalg.det(axes) == pytest.approx(1.0)
