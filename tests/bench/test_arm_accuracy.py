"""An arm's absolute accuracy is what is left after registering both ends (bench/arm_accuracy.py)."""

import numpy as np

from bench.arm_accuracy import registered_errors
from stages.common import geometry as g


def _poses(rng: np.random.Generator, count: int) -> np.ndarray:
    return np.stack([g.make_transform(g.rotvec_to_matrix(rng.normal(0, 1.0, 3)), rng.uniform(-1.5, 1.5, 3))
                     for _ in range(count)])


def test_a_constant_base_and_tool_offset_is_no_error_and_a_flange_error_is_kept():
    rng = np.random.default_rng(5)
    model = _poses(rng, 40)
    base = g.make_transform(g.rotvec_to_matrix([0.02, -0.01, 0.3]), [0.2, -0.1, 0.05])
    tool = g.make_transform(g.rotvec_to_matrix([0.1, 0.0, -0.05]), [0.0, 0.01, 0.12])
    true = base @ model @ tool
    position, rotation = registered_errors(model, true)
    assert position.max() < 1e-9 and rotation.max() < 1e-9
    # a 0.5 mm error at each pose, in a random direction, is what the test reports
    noise = rng.normal(0.0, 1.0, (40, 3))
    noise *= 0.5e-3 / np.linalg.norm(noise, axis=1, keepdims=True)
    moved = true.copy()
    moved[:, :3, 3] += noise
    position, _ = registered_errors(model, moved)
    assert 0.35e-3 < position.mean() < 0.5e-3  # the registration takes only what is common to every pose
