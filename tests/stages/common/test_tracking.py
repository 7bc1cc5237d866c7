"""The tracking baseline: on a propagated sequence seen through noisy per-frame poses with
flips, the filters beat the frames, the gate keeps the flips out, and a filter that started
on a flip recovers."""

from dataclasses import replace

import numpy as np
import pytest

from pipeline.config import load_config
from stages.common import geometry as g
from stages.common.orbits import rtn_from_eci, two_body
from stages.common.scores import score
from stages.common.tracking import Measurement, TrackingNoise, track
from stages.common.workspace_target import planned_target
from stages.plan.trajectory import chief_elements, mass_properties, preset_motion, propagate

NOISE = TrackingNoise(np.radians(3.0), 0.005, 0.03, 3e-4, 1e-3)
FRAMES = 120


@pytest.fixture(scope="module")
def scene():
    config = load_config("default")
    config = config.replace(trajectory=replace(config.trajectory, frames=FRAMES))
    target = planned_target(config)
    masses, _ = mass_properties(config, target)
    return config, masses, target


def sequence(scene, preset, seed, flip_rate=0.1, first_flipped=False):
    """(measurements, true cam_from_target per frame, flipped per frame)."""
    config, masses, target = scene
    rng = np.random.default_rng(seed)
    roe_m, omega0 = preset_motion(config, target, preset, masses)
    frames = propagate(config, roe_m, omega0, g.random_quats(rng, 1)[0], np.zeros((FRAMES, 2)), masses)
    chief = chief_elements(config)
    position, velocity = two_body(chief, frames.times_s)
    rtn_from = rtn_from_eci(position, velocity)
    latitude = chief.mean_latitude_rad(frames.times_s)
    measurements, flipped = [], []
    for k, true in enumerate(frames.cam_from_target_m):
        flip = rng.uniform() < flip_rate or (first_flipped and k == 0)
        turn = np.array([0, 0, np.pi]) if flip else rng.normal(0.0, np.radians(3.0), 3)
        rotation = true[:3, :3] @ g.rotvec_to_matrix(turn)
        translation = true[:3, 3] + rng.normal(0, 1, 3) * [0.005, 0.005, 0.03] * np.linalg.norm(true[:3, 3])
        measurements.append(Measurement(float(frames.times_s[k]), g.make_transform(rotation, translation),
                                        g.quat_to_matrix(frames.eci_from_cam_q[k]), rtn_from[k], float(latitude[k])))
        flipped.append(flip)
    return measurements, frames.cam_from_target_m, np.array(flipped), chief, masses.centre_of_mass_m


def scores(poses, truth):
    return np.array([float(score(g.matrix_to_quat(p[:3, :3]), p[:3, 3], g.matrix_to_quat(t[:3, :3]),
                                 t[:3, 3])["score_speed"]) for p, t in zip(poses, truth, strict=True)])


@pytest.mark.parametrize("preset", ["vbar_hold_spin", "approach_tumble"])
def test_the_filter_beats_the_frames_and_gates_out_the_flips(scene, preset):
    measurements, truth, flipped, chief, com = sequence(scene, preset, seed=3)
    tracked = track(measurements, chief, com, NOISE)
    per_frame = scores([m.cam_from_target for m in measurements], truth)
    filtered = scores([t.cam_from_target for t in tracked], truth)
    assert filtered[20:].mean() < per_frame[20:].mean() / 3  # after it settles
    used = np.array([t.rotation_used for t in tracked])
    assert not np.any(used[1:] & flipped[1:])  # no flip folded in
    assert used[~flipped].mean() > 0.9


def test_a_filter_that_starts_on_a_flip_recovers(scene):
    measurements, truth, flipped, chief, com = sequence(scene, "vbar_hold_spin", seed=5, flip_rate=0.0,
                                                        first_flipped=True)
    tracked = track(measurements, chief, com, NOISE)
    errors = [g.angular_distance(t.cam_from_target[:3, :3], true[:3, :3]) for t, true in zip(tracked, truth,
                                                                                               strict=True)]
    assert errors[0] > 3.0  # it believed the flip
    assert np.mean(errors[10:]) < np.radians(3.0) and max(errors[10:]) < np.radians(8.0)  # the frames' own noise


def test_no_measurement_gives_no_estimate_until_one_comes(scene):
    measurements, _, _, chief, com = sequence(scene, "vbar_hold_spin", seed=1, flip_rate=0.0)
    blind = [replace(m, cam_from_target=None) if k < 3 else m for k, m in enumerate(measurements[:6])]
    tracked = track(blind, chief, com, NOISE)
    assert all(np.isnan(t.cam_from_target).all() for t in tracked[:3])
    assert all(np.isfinite(t.cam_from_target).all() for t in tracked[3:])
