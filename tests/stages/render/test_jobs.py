"""Render jobs: label validation, the training-set sampler, light alignment."""

import numpy as np
import pytest
from scipy import stats

from pipeline.config import load_config
from stages.common import geometry as g
from stages.common import tango
from stages.common.cameras import train_camera
from stages.render.jobs import image_seed, light_position, train_jobs, unrenderable_reason


@pytest.mark.parametrize(("q", "t", "expected"), [
    ((1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 8.0), None),
    ((1.0, 0.01, 0.0, 0.0), (0.0, 0.0, 8.0), "not unit"),
    ((np.nan, 0.0, 0.0, 1.0), (0.0, 0.0, 8.0), "4 finite"),
    ((1.0, 0.0, 0.0, 0.0), (0.0, np.inf, 8.0), "3 finite"),
    ((1.0, 0.0, 0.0, 0.0), (0.0, 0.0, -8.0), "behind the camera"),
    ((1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.5), "too close"),
])
def test_unrenderable_reasons(q, t, expected):
    reason = unrenderable_reason(q, t, 0.7377)
    assert (reason is None) if expected is None else (expected in reason)


def test_image_seeds_are_stable_and_distinct():
    assert image_seed(7, "twin", "img000001") == image_seed(7, "twin", "img000001")
    seeds = {image_seed(7, s, f"img{i:06d}") for s in ("twin", "train") for i in range(500)}
    assert len(seeds) == 1000 and all(0 <= s < 2**32 for s in seeds)


def test_training_set_is_deterministic_for_a_seed():
    config = load_config("smoke", None, ["render.train_count=50"])
    assert train_jobs(config) == train_jobs(config)
    other = train_jobs(load_config("smoke", None, ["render.train_count=50", "render.seed=8"]))
    assert [j.q_vbs2tango_true for j in other] != [j.q_vbs2tango_true for j in train_jobs(config)]


def test_training_poses_follow_the_specified_distributions():
    config = load_config("default", None, ["render.train_count=2000"])
    jobs = train_jobs(config)
    quats = np.array([j.q_vbs2tango_true for j in jobs])
    # uniform on SO(3): the rotation angle has density (1 - cos x) / pi on [0, pi]
    angles = g.quat_angular_distance(quats, np.array([1.0, 0.0, 0.0, 0.0]))
    assert stats.kstest(angles, lambda x: (x - np.sin(x)) / np.pi).pvalue > 0.01
    camera = train_camera(config)
    from stages.render.jobs import SPEEDPLUS_TRAIN_DISTANCE_M

    low, high = SPEEDPLUS_TRAIN_DISTANCE_M  # the default: SPEED+'s, Tango's own apparent size
    lights_facing = 0
    for job in jobs:
        centre = job.cam_from_target()[:3, :3] @ tango.BODY_CENTRE_M + np.asarray(job.r_Vo2To_vbs_true)
        assert low - 1e-9 <= np.linalg.norm(centre) <= high + 1e-9
        u, v = g.project_points(centre[None], camera.camera_matrix, np.zeros(5))[0]
        assert 0 <= u <= camera.width - 1 and 0 <= v <= camera.height - 1
        assert unrenderable_reason(job.q_vbs2tango_true, job.r_Vo2To_vbs_true, 0.7377) is None
        lights_facing += np.dot(job.light_dir_cam, -centre) >= 0
    assert lights_facing == len(jobs)
    earth = np.mean([j.earth for j in jobs])
    assert abs(earth - config.render.train_earth_fraction) < 0.05


def test_train_camera_scales_the_intrinsics():
    config = load_config("default", None, ["render.train_resolution_scale=0.5"])
    camera = train_camera(config)
    full = config.camera.camera_matrix()
    assert (camera.width, camera.height) == (480, 300)
    assert camera.camera_matrix[0, 0] == pytest.approx(full[0, 0] / 2)
    # the image centre stays the image centre
    assert camera.camera_matrix[0, 2] + 0.5 == pytest.approx((full[0, 2] + 0.5) / 2)


def test_light_positions_of_the_testbed():
    config = load_config("default")
    np.testing.assert_allclose(light_position(config, "sunlamp", []), config.testbed.sun_lamp_position_m)
    centres = np.asarray(config.testbed.light_box_centres_m)
    np.testing.assert_allclose(light_position(config, "lightbox", [1, 3]), centres[[1, 3]].mean(axis=0))
