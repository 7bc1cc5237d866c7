"""Every calibrated offset with its covariance, and a direction the poses leave weak named
(issue 57, part 3): a hand-eye set that turns about one axis cannot fix the offsets'
translation along it (Tsai and Lenz 1989)."""

import numpy as np
import pytest

from stages.calibrate.offset_uncertainty import offsets_covariance, uncertainty
from stages.common import geometry as g
from stages.common import rwhe


def _data(rng: np.random.Generator, one_axis: bool, count: int = 15) -> tuple[np.ndarray, np.ndarray, rwhe.Solution]:
    z = g.make_transform(g.rotvec_to_matrix([0.2, -0.1, 0.3]), [0.05, -0.02, 0.1])
    x = g.make_transform(g.rotvec_to_matrix([0.1, 0.4, -0.2]), [0.3, 0.1, -0.05])
    if one_axis:
        rotations = g.rotvec_to_matrix(np.outer(rng.uniform(-1.0, 1.0, count), [0.0, 0.0, 1.0]))
    else:
        rotations = g.rotvec_to_matrix(rng.normal(0.0, 0.6, (count, 3)))
    b = g.make_transform(rotations, rng.normal(0.0, 0.3, (count, 3)))
    noise = rwhe.transform_from_vector(np.concatenate([rng.normal(0, 2e-4, (count, 3)),
                                                       rng.normal(0, 2e-4, (count, 3))], axis=1))
    return z @ b @ g.invert(x) @ noise, b, rwhe.Solution(z, {"fixed": x})


@pytest.mark.parametrize("seed", [1, 2])
def test_a_set_that_turns_about_one_axis_is_named_weak_along_it(seed):
    a, b, solution = _data(np.random.default_rng(seed), one_axis=True)
    covariance = offsets_covariance(a, b, ["fixed"] * len(a), solution, None)
    record = uncertainty(covariance, ["fixed"], "cam_from_camee", "target_from_targetee", b)
    assert any(w.startswith("cam_from_camee") and "turn about one axis (z" in w for w in record.weak), record.weak
    assert any(w.startswith("target_from_targetee[fixed] z") for w in record.weak), record.weak
    assert max(record.target_from_offset_sigma_by_fixture["fixed"][3:]) > 0.01  # metres: not determined


def test_a_well_spread_set_is_determined_and_its_sigma_is_honest():
    rng = np.random.default_rng(3)
    z_errors = []
    sigmas = []
    for _ in range(40):
        a, b, truth = _data(rng, one_axis=False, count=20)
        fixtures = ["fixed"] * len(a)
        solved = rwhe.frobenius(a, b, fixtures, rwhe.closed_form(a, b, fixtures))
        covariance = offsets_covariance(a, b, fixtures, solved, None)
        record = uncertainty(covariance, ["fixed"], "cam_from_camee", "target_from_targetee", b)
        assert record.weak == ()
        z_errors.append(solved.z[:3, 3] - truth.z[:3, 3])
        sigmas.append(record.cam_from_offset_sigma[3:])
    ratio = np.array(z_errors) / np.array(sigmas)  # the translation's error in units of its sigma
    assert 0.7 < np.sqrt(np.mean(ratio**2)) < 1.4
