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
    record = uncertainty(covariance, solution, "cam_from_camee", "target_from_targetee", b)
    # b turns about its z on both sides; seen from the offsets' own frames, about R z
    along_z = {"camera": solution.z[:3, :3] @ [0, 0, 1], "target": solution.x["fixed"][:3, :3] @ [0, 0, 1]}
    camera = [w for w in record.weak if w.startswith("cam_from_camee") and "rotation about" not in w]
    target = [w for w in record.weak if w.startswith("target_from_targetee[fixed]") and "rotation about" not in w]
    assert camera and target, record.weak
    for sentence, axis in ((camera[0], along_z["camera"]), (target[0], along_z["target"])):
        shown = sentence.split("one axis (")[1].rsplit(" of ", 1)[0]
        assert abs(_vector(shown) @ axis) > 0.9, sentence  # the axis, named in the offset's frame
        weak = sentence.split(":")[0].rsplit(" ", 1)[0].split(" ", 1)[1]
        weak = weak.rsplit(" +-", 1)[0] if " +-" in weak else weak
        assert abs(_vector(weak) @ axis) > 0.9, sentence  # the weak translation lies along it
    assert max(record.target_from_offset_sigma_by_fixture["fixed"][3:]) > 0.01  # metres: not determined


def _vector(named: str) -> np.ndarray:
    """An axis as a sentence names it: "x", "y", "z" (within 25.8 deg) or "(+0.12, -0.99, +0.05)"."""
    if named in ("x", "y", "z"):
        return np.eye(3)["xyz".index(named)]
    vector = np.array([float(v) for v in named.strip("()").split(", ")])
    return vector / np.linalg.norm(vector)


def test_a_well_spread_set_is_determined_and_its_sigma_is_honest():
    rng = np.random.default_rng(3)
    z_errors = []
    sigmas = []
    for _ in range(40):
        a, b, truth = _data(rng, one_axis=False, count=20)
        fixtures = ["fixed"] * len(a)
        solved = rwhe.frobenius(a, b, fixtures, rwhe.closed_form(a, b, fixtures))
        covariance = offsets_covariance(a, b, fixtures, solved, None)
        record = uncertainty(covariance, solved, "cam_from_camee", "target_from_targetee", b)
        assert record.weak == ()
        z_errors.append(solved.z[:3, 3] - truth.z[:3, 3])
        sigmas.append(record.cam_from_offset_sigma[3:])
    ratio = np.array(z_errors) / np.array(sigmas)  # the translation's error in units of its sigma
    assert 0.7 < np.sqrt(np.mean(ratio**2)) < 1.4
