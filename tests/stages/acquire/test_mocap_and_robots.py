"""Virtual testbed error models, without rendering: robot telemetry and motion capture."""

import numpy as np
import pytest

from pipeline.config import load_config
from stages.acquire.virtual import VirtualTestbed, mocap, robots
from stages.acquire.virtual.truth import draw_truth
from stages.common import geometry as g
from stages.common.markers import main_body_hull, markers
from stages.common.workspace_target import planned_target
from stages.plan.stage import plan_sample, planned_samples


@pytest.fixture(scope="module")
def default_config():
    return load_config("default")


@pytest.fixture(scope="module")
def plan_rows(default_config):
    return [plan_sample(default_config, *item) for item in planned_samples(default_config)]


def test_truth_is_reproducible_and_differs_from_nominal(default_config):
    a, b = draw_truth(default_config), draw_truth(default_config)
    np.testing.assert_array_equal(a.camee_from_cam, b.camee_from_cam)
    nominal = np.asarray(default_config.testbed.camee_from_cam_t_m)
    assert 1e-4 < np.linalg.norm(a.camee_from_cam[:3, 3] - nominal) < 0.02


def test_telemetry_errors_have_the_configured_magnitude(default_config, plan_rows):
    """With perfect knowledge of the fixtures, the robots alone leave mm-level, pose-dependent
    errors: not zero, not wild."""
    truth = draw_truth(default_config)
    flange_errors, relative_errors, angles = [], [], []
    for row in plan_rows[::2]:
        state = robots.move(default_config, truth, row, np.random.default_rng(0))
        flange_errors.append(np.linalg.norm(state.world_from_targetee[:3, 3] - state.kuka_world_from_targetee[:3, 3]))
        flange_errors.append(np.linalg.norm(state.world_from_camee[:3, 3] - state.kuka_world_from_camee[:3, 3]))
        if row["session"] == "calibration":
            kuka = (g.invert(state.kuka_world_from_camee @ truth.camee_from_cam) @ state.kuka_world_from_targetee
                    @ g.invert(truth.target_from_targetee[row["mount"]]))
            true = g.invert(state.world_from_cam) @ state.world_from_target
            relative_errors.append(np.linalg.norm(kuka[:3, 3] - true[:3, 3]))
            angles.append(g.angular_distance(kuka[:3, :3], true[:3, :3]))
    flange_errors = np.array(flange_errors) * 1000
    assert 0.3 < np.median(flange_errors) < 3.0 and flange_errors.max() < 5.0  # mm, "about 1-3 mm"
    assert flange_errors.std() > 0.05  # pose-dependent, not a constant offset
    assert 0.3 < np.median(relative_errors) * 1000 < 5.0
    assert np.radians(0.02) < np.median(angles) < np.radians(1.0)


def test_fixture_sag_is_tenths_of_a_degree(default_config, plan_rows):
    truth = draw_truth(default_config)
    sags = [robots.move(default_config, truth, row, np.random.default_rng(0)).sag_rad for row in plan_rows]
    assert np.radians(0.1) < np.max(sags) < np.radians(0.9)
    assert np.std(sags) > 0  # depends on the orientation of the model


def observe_all(config, rows, link_segments=None):
    testbed = VirtualTestbed.__new__(VirtualTestbed)  # the error models only, no renderer
    VirtualTestbed.__init__(testbed, config, workspace=None)
    out = []
    for row in rows:
        rng = np.random.default_rng(1)
        state = robots.move(config, testbed.truth, row, rng)
        segments = testbed._link_segments(state) if link_segments is None else link_segments
        out.append(mocap.observe(config, rng, testbed.target_markers_rb,
                                 state.world_from_target @ testbed.truth.target_from_targetrb,
                                 testbed.truth.vicon_world_from_world, segments, state.world_from_target,
                                 testbed.body))
    return out


def test_arms_occlude_markers(default_config, plan_rows):
    rows = [r for r in plan_rows if r["session"] == "dataset"]
    with_arms = observe_all(default_config, rows)
    far_away = np.array([[[100.0, 100, 100], [101.0, 100, 100]]])
    without_arms = observe_all(default_config, rows, far_away)
    occluded = [a.markers < b.markers for a, b in zip(with_arms, without_arms, strict=True)]
    assert any(occluded)  # the arms hide markers
    assert any(o.vicon_world_from_rb is None for o in with_arms)  # and some bodies become untracked
    assert all(o.vicon_world_from_rb is not None or o.markers < mocap.MIN_MARKERS for o in with_arms)


def test_ghost_rate_is_respected_and_ghosts_bias_the_pose():
    config = load_config("default", overrides=["virtual.vicon_ghost_rate=0.2"])
    rng = np.random.default_rng(5)
    target = planned_target(config)
    markers_rb = markers(target).centres_m
    world_from_rb = g.make_transform(np.eye(3), [1.5, 1.5, 1.2])
    nowhere = np.array([[[100.0, 100, 100], [101.0, 100, 100]]])
    observations = [mocap.observe(config, rng, markers_rb, world_from_rb, np.eye(4), nowhere, world_from_rb,
                                  main_body_hull(target)) for _ in range(1000)]
    rate = np.mean([o.ghost for o in observations])
    assert abs(rate - 0.2) < 3 * np.sqrt(0.2 * 0.8 / 1000)
    error = {flag: np.median([np.linalg.norm(o.vicon_world_from_rb[:3, 3] - world_from_rb[:3, 3])
                              for o in observations if o.ghost == flag]) for flag in (True, False)}
    assert error[True] > 3 * error[False]


def test_kabsch_recovers_a_rigid_motion():
    rng = np.random.default_rng(2)
    model = rng.normal(size=(6, 3))
    truth = g.transform_from_qt(g.random_quats(rng, 1)[0], rng.normal(size=3))
    np.testing.assert_allclose(mocap.kabsch(model, g.apply(truth, model)), truth, atol=1e-12)
