"""Symmetries of a target that make its keypoints ambiguous: found on the mesh, none on
Tango, and said by `speedplus target`."""

import numpy as np

from stages.common import geometry as g
from stages.common.symmetry import ambiguities, symmetries
from stages.common.target import load_target
from stages.common.targets import builtin_folder
from tests.conftest import speedplus
from tests.target_folders import BOULDER_KEYPOINTS, boulder, cubesat


def test_tango_has_no_symmetry_its_antennas_break_every_turn():
    target = load_target(builtin_folder("tango"))
    assert symmetries(target) == [] and ambiguities(target) == []


def test_a_symmetric_cubesat_swaps_its_chosen_keypoints(tmp_path):
    """Two wings either side of the body: a half turn about x maps it onto itself, and the
    hull's farthest corners come in pairs that it swaps."""
    target = load_target(cubesat(tmp_path / "c"))
    found = symmetries(target)
    assert [name for name, _ in found] == ["half turn about x through the body centre"]
    vertices = np.concatenate([p.vertices for p in target.parts.values()])
    np.testing.assert_allclose(np.sort(g.apply(found[0][1], vertices), axis=0), np.sort(vertices, axis=0), atol=1e-6)
    [ambiguity] = ambiguities(target)
    assert len(ambiguity.swapped) >= 4
    for i, j in ambiguity.swapped:  # each pair really is exchanged
        np.testing.assert_allclose(g.apply(found[0][1], target.keypoints_m[[i]])[0], target.keypoints_m[j], atol=1e-6)


def test_an_ellipsoid_has_three_half_turns_and_the_command_says_so(tmp_path):
    folder = boulder(tmp_path / "b")
    target = load_target(folder)
    assert sorted(name.split(" ")[3] for name, _ in symmetries(target)) == ["x", "y", "z"]
    # the declared keypoints: (0, 1) and (3, 4) are mirror pairs across the y half turn
    by_name = {a.symmetry.split(" ")[3]: a for a in ambiguities(target)}
    assert by_name["y"].swapped == ((0, 1), (3, 4)) and len(BOULDER_KEYPOINTS) == 5
    said = " ".join(speedplus("target", str(folder)).stdout.split())
    assert "half turn about y" in said and "no model of the images can tell them apart" in said.replace("│ ", "")
