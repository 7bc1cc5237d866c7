"""The synthetic target renderer (the built-in Tango) against the geometry core: same
camera, same pixels."""

import numpy as np
import pytest

from pipeline.config import load_config
from stages.acquire.virtual.sensor import lens_camera
from stages.common import geometry as g
from stages.common import tango
from stages.common.tango_mesh import tango_parts
from stages.common.workspace_target import planned_target
from stages.render.jobs import RenderJob
from stages.render.scene import TargetRenderer, ray_traced_mask
from stages.render.worker import mask_bbox


@pytest.fixture(scope="module")
def renderer():
    camera = lens_camera(load_config("default").camera)  # 960 x 600 with the SPEED+ lens distortion
    return TargetRenderer(camera, planned_target(load_config("default")), spp=4, max_depth=2, threads=2)


def random_poses(seed, n):
    """cam_from_target (4, 4) full scale: random attitude, 6-10 m away, off-centre in the image."""
    rng = np.random.default_rng(seed)
    poses = []
    for q in g.random_quats(rng, n):
        centre = np.array([rng.uniform(-0.8, 0.8), rng.uniform(-0.5, 0.5), rng.uniform(6.0, 10.0)])
        poses.append(g.transform_from_qt(q, centre - g.quat_to_matrix(q) @ tango.BODY_CENTRE_M))
    return poses


def test_mask_box_is_the_projected_model_box(renderer):
    camera = renderer.lens.camera
    vertices = np.concatenate([part.vertices for part in tango_parts().values()])
    for cam_from_target in random_poses(3, 6):
        rgba = renderer.render(cam_from_target, np.array([0.0, 0.0, -1.0]), 3.0, seed=1)
        mask = rgba[..., 3] >= 0.5
        projected = g.project(cam_from_target, vertices, camera.camera_matrix, camera.dist)
        expected = np.concatenate([projected.min(axis=0), projected.max(axis=0)])
        # a pixel centre is in the mask when at least half the pixel is covered: the mask's
        # extreme centres lie within about a pixel of the model's projected extremes
        assert np.abs(mask_bbox(mask) - expected).max() < 1.5, (mask_bbox(mask), expected)
        keypoints = g.project(cam_from_target, tango.KEYPOINTS_M, camera.camera_matrix, camera.dist)
        body = np.round(keypoints[:8]).astype(int)  # body corners (not the thin antenna tips)
        near = [mask[max(v - 1, 0):v + 2, max(u - 1, 0):u + 2].any() for u, v in body]
        assert all(near)


def test_coverage_mask_agrees_with_ray_casting_through_the_lens(renderer):
    for cam_from_target in random_poses(5, 3):
        mask = renderer.render(cam_from_target, np.array([0.0, 0.0, -1.0]), 3.0, seed=2)[..., 3] >= 0.5
        traced = ray_traced_mask(renderer, cam_from_target)
        assert (mask & traced).sum() / (mask | traced).sum() > 0.97


def test_light_direction_lights_the_faces_that_see_it(renderer):
    # the camera looks at the solar-panel face (+z of the body) straight on
    cam_from_target = g.make_transform(np.diag([1.0, -1.0, -1.0]), [0.0, 0.0, 8.0])
    towards_camera = renderer.render(cam_from_target, np.array([0.0, 0.0, -1.0]), 3.0, seed=3)
    from_behind = renderer.render(cam_from_target, np.array([0.0, 0.0, 1.0]), 3.0, seed=3)
    covered = towards_camera[..., 3] > 0.99
    assert towards_camera[covered, :3].mean() > 20 * max(from_behind[covered, :3].mean(), 1e-6)


def test_same_seed_same_pixels_other_seed_other_noise(renderer):
    cam_from_target = random_poses(7, 1)[0]
    light = np.array([0.3, -0.4, -0.866])
    a = renderer.render(cam_from_target, light, 3.0, seed=11)
    renderer.render(random_poses(8, 1)[0], -light, 5.0, seed=12)  # another image in between
    b = renderer.render(cam_from_target, light, 3.0, seed=11)
    c = renderer.render(cam_from_target, light, 3.0, seed=13)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)


def test_job_pose_round_trip():
    rng = np.random.default_rng(0)
    q = g.random_quats(rng, 1)[0]
    job = RenderJob("x", "twin", tuple(q), (0.1, 0.2, 7.0), (0.0, 0.0, -1.0), 3.0, False, 1)
    np.testing.assert_allclose(g.transform_to_qt(job.cam_from_target())[0], q, atol=1e-12)
    assert job.image_path == "renders/twins/x.png" and job.mask_path == "renders/twins/masks/x.png"


def test_a_target_outside_the_image_is_rejected_not_written(tmp_path):
    from stages.render.worker import RenderWorker

    worker = RenderWorker(lens_camera(load_config("smoke").camera), planned_target(load_config("smoke")), 4, 2, 2)
    job = RenderJob("img000001", "twin", (1.0, 0.0, 0.0, 0.0), (40.0, 0.0, 8.0), (0.0, 0.0, -1.0), 3.0, False, 1)
    outside = worker.render(job)
    assert outside.value == {"sample_id": "img000001", "rejected": "the target covers no pixel of the image"}
    assert outside.files == {}
    inside = worker.render(RenderJob("img000002", "twin", (1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 8.0), (0.0, 0.0, -1.0),
                                     3.0, False, 1))
    row = inside.value
    assert {row["image_path"], row["mask_path"], row["ground_truth_path"]} == set(inside.files)
    assert row["bbox_px"][2] > row["bbox_px"][0]
