"""Target folders: the built-in Tango is the procedural model it replaces, a stranger's
object in another unit, frame and format loads with every derived quantity, and each
mistake a lab makes is refused naming the file and the key."""

import dataclasses
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from manifests.target import TARGET_FILE, TargetError, read_target_spec, write_target_spec
from pipeline.config import load_config
from stages.common import geometry as g
from stages.common import layout, tango
from stages.common.tango_mesh import tango_parts
from stages.common.target import CHOSEN_KEYPOINTS, derived_fixture, feature_edges, load_target
from stages.common.targets import builtin_folder, builtin_names, make_tango
from tests.target_folders import BOULDER_KEYPOINTS, boulder, cubesat


def test_the_builtin_tango_is_the_procedural_model():
    target = load_target(builtin_folder("tango"))
    assert builtin_names() == ("tango",)
    procedural = tango_parts()
    assert list(target.parts) == list(procedural)  # renderers add shapes in this order
    for name, part in procedural.items():
        np.testing.assert_allclose(target.parts[name].vertices, part.vertices, atol=3e-8)  # GLB holds float32
        np.testing.assert_array_equal(target.parts[name].faces, part.faces)
        np.testing.assert_allclose(target.parts[name].uv, part.uv, atol=3e-8)
    np.testing.assert_array_equal(target.keypoints_m, tango.KEYPOINTS_M)
    np.testing.assert_array_equal(target.centre_m, tango.BODY_CENTRE_M)
    assert not target.keypoints_chosen and target.mockup_scale == 0.5
    cameras = np.random.default_rng(0).normal(0, 2, (500, 3))
    for scale in (1.0, 0.5):
        expected = np.where(cameras[:, 2] > scale * tango.BODY_CENTRE_M[2], "solar_panel", "rear_panel")
        assert np.array_equal(target.view_of(cameras, scale), expected)  # the camera's side of the mid-plane


def test_the_builtin_folder_is_what_its_script_makes(tmp_path):
    make_tango.main(tmp_path)
    for name in (TARGET_FILE, make_tango.MESH):
        assert (tmp_path / name).read_bytes() == (builtin_folder("tango") / name).read_bytes(), name


def test_a_strangers_cubesat_in_mm_with_its_own_frame_and_no_keypoints(tmp_path):
    target = load_target(cubesat(tmp_path / "cubesat", looks={"body": make_tango.spec().looks["sides"]}))
    assert list(target.parts) == ["body", "wing_minus", "wing_plus"]
    vertices = np.concatenate([p.vertices for p in target.parts.values()])
    # mm became m, and the long (mesh x) axis is the body's z
    np.testing.assert_allclose(np.ptp(vertices, axis=0), [0.326, 0.228, 0.366], atol=1e-9)
    assert target.diameter_m == pytest.approx(np.linalg.norm(vertices[:, None] - vertices[None], axis=2).max())
    assert np.all(np.linalg.norm(vertices - target.centre_m, axis=1) <= target.radius_m + 1e-12)
    # chosen keypoints: distinct corners of the hull, spread out, recorded as chosen
    assert target.keypoints_chosen and len(target.keypoints_m) == CHOSEN_KEYPOINTS
    assert len({tuple(p) for p in np.round(target.keypoints_m, 9)}) == CHOSEN_KEYPOINTS
    pairwise = np.linalg.norm(target.keypoints_m[:, None] - target.keypoints_m[None], axis=2)
    assert pairwise[~np.eye(CHOSEN_KEYPOINTS, dtype=bool)].min() > 0.05
    assert target.view_names == ("plus_z", "minus_z")
    assert load_target(tmp_path / "cubesat").keypoints_m.tolist() == target.keypoints_m.tolist()  # deterministic


def test_an_stl_in_metres_with_declared_keypoints_and_views(tmp_path):
    target = load_target(boulder(tmp_path / "boulder"))
    assert list(target.parts) == ["boulder"] and not target.keypoints_chosen
    np.testing.assert_allclose(target.keypoints_m, BOULDER_KEYPOINTS)
    assert target.view_of(np.array([[2.0, 0, 0], [-2.0, 0, 0]])).tolist() == ["east", "west"]


def write(folder: Path, text: str, mesh: str = "boulder.stl") -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    if not (folder / mesh).exists() and mesh.endswith(".stl"):
        trimesh.creation.box((0.4, 0.3, 0.2)).export(folder / mesh)
    (folder / TARGET_FILE).write_text(text)
    return folder


GOOD = ('format_version = 1\nname = "box"\nmesh = "boulder.stl"\nlength_unit = "m"\n'
        '[mockup]\nscale = 1.0\nmass_kg = 3.0\n')


@pytest.mark.parametrize("text, expected", [
    ("colour = 3\n" + GOOD, "unknown key(s) colour"),
    (GOOD.replace("length_unit", "lenght_unit"), "unknown key(s) lenght_unit (did you mean length_unit?)"),
    (GOOD.replace("mass_kg", "mas_kg"), "unknown key(s) in mockup mas_kg (did you mean mass_kg?)"),
    (GOOD.replace('"box"', '"My Box"'), "key name"),
    (GOOD.replace("format_version = 1", "format_version = 2"), "key format_version"),
    (GOOD.replace("length_unit = \"m\"", "length_unit = \"inch\""), "key length_unit"),
    (GOOD.replace("scale = 1.0", "scale = 0"), "key mockup.scale"),
    (GOOD + "[keypoints]\npoints = [[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0]]\n", "key keypoints.points"),
    (GOOD + "[keypoints]\npoints = [[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0], [0, 0, 'a']]\n", "key keypoints.points.3"),
    (GOOD + "[keypoints]\npoints = [[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0], [0, 0, 5.0]]\n", "key keypoints.points.3"),
    (GOOD + '[views]\naxis = [0, 0, 0]\nnames = ["a", "b"]\n', "key views.axis"),
    (GOOD + '[views]\naxis = [0, 0, 1]\nnames = ["a", "a"]\n', "key views.names"),
    (GOOD + '[looks]\nboulder = "chrome"\n', "key looks.boulder"),
    (GOOD + '[looks]\nwing = "rock"\n', "key looks.wing"),
    (GOOD + "[frame]\nbody_from_mesh_q = [1, 1, 0, 0]\n", "key frame.body_from_mesh_q"),
    (GOOD.replace('"boulder.stl"', '"../boulder.stl"'), "key mesh"),
    (GOOD.replace('"boulder.stl"', '"/etc/passwd.stl"'), "key mesh"),
    (GOOD.replace('"boulder.stl"', '"missing.stl"'), "key mesh"),
    (GOOD.replace('"boulder.stl"', '"notes.txt"'), "key mesh"),
    (GOOD.replace("scale = 1.0", "scale = 1.0 ="), "not valid TOML (Expected newline or end of document after a "
                                                    "statement (at line 6, column 13))"),
])
def test_each_mistake_names_the_file_and_the_key(tmp_path, text, expected):
    folder = write(tmp_path / "t", text)
    with pytest.raises(TargetError) as error:
        load_target(folder)
    assert str(folder / TARGET_FILE) in str(error.value) and expected in str(error.value), str(error.value)


def test_a_mesh_in_mm_declared_in_metres_gives_both_sizes(tmp_path):
    folder = tmp_path / "t"
    folder.mkdir()
    trimesh.creation.box((400.0, 300.0, 200.0)).export(folder / "boulder.stl")  # mm
    write(folder, GOOD)
    with pytest.raises(TargetError, match=r"length_unit / mockup.scale: the mesh is 538.5 m across.*"
                                          r"length_unit = \"mm\" the mock-up would be 0.5385 m"):
        load_target(folder)


@pytest.mark.parametrize("mesh, content, expected", [
    ("broken.glb", b"glTF this is not", "not a mesh trimesh can read"),
    ("empty.obj", b"# nothing\nv 0 0 0\nv 1 0 0\n", "holds no triangles"),
    ("flat.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 3\nf 2 4 3\n", "flat or degenerate"),
    ("sliver.obj", b"v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n", "degenerate"),
])
def test_a_mesh_that_cannot_be_a_target_is_refused(tmp_path, mesh, content, expected):
    folder = tmp_path / "t"
    folder.mkdir()
    (folder / mesh).write_bytes(content)
    write(folder, GOOD.replace('"boulder.stl"', f'"{mesh}"'), mesh)
    with pytest.raises(TargetError, match=expected):
        load_target(folder)


def test_a_link_out_of_the_folder_is_refused(tmp_path):
    outside = tmp_path / "outside.stl"
    trimesh.creation.box((0.4, 0.3, 0.2)).export(outside)
    (tmp_path / "t").mkdir()
    os.symlink(outside, tmp_path / "t" / "link.stl")
    folder = write(tmp_path / "t", GOOD.replace('"boulder.stl"', '"link.stl"'), "link.stl")
    with pytest.raises(TargetError, match="key mesh: 'link.stl' leads out of"):
        load_target(folder)


def test_the_written_spec_reads_back(tmp_path):
    spec = make_tango.spec()
    (tmp_path / make_tango.MESH).write_bytes(b"")
    write_target_spec(tmp_path, spec)
    assert read_target_spec(tmp_path) == spec


def test_speedplus_target_checks_a_folder(tmp_path):
    def speedplus(*args):
        return subprocess.run([sys.executable, "-m", "pipeline.cli", *args], capture_output=True, text=True,
                              env={**os.environ, "COLUMNS": "200"}, timeout=120)

    good = speedplus("target", str(cubesat(tmp_path / "cubesat")))
    assert good.returncode == 0, good.stderr
    for said in ("cubesat6u", "11, chosen on the mesh", "0.5401 m full scale", "body, wing_minus, wing_plus",
                 "for the best fit over the whole target", "motion capture to expect"):
        assert said in good.stdout, good.stdout
    # the motion-capture accuracy to expect at the plan's range: a figure in mm, its parts named
    said = " ".join(good.stdout.split())
    expected = re.search(r"motion capture to expect │ ([\d.]+)-([\d.]+) mm \(3D RMS of the target's origin\) at "
                         r"([\d.]+)-([\d.]+) m", said)
    assert expected, said
    near, far, low, high = map(float, expected.groups())
    assert 0.1 < near < far < 50 and low < high
    assert "its markers' fit" in said and "the camera body's pointing" in said
    bad = speedplus("target", str(write(tmp_path / "bad", "colour = 3\n" + GOOD)))
    assert bad.returncode == 1 and "unknown key(s) colour" in bad.stderr and "Traceback" not in bad.stderr


def test_the_wireframe_is_the_meshs_creases_and_borders(tmp_path):
    """A box's 12 edges, not its faces' diagonals; Tango's body box and its antennas."""
    folder = tmp_path / "box"
    folder.mkdir()
    trimesh.creation.box((0.4, 0.3, 0.2)).export(folder / "boulder.stl")  # STL: every triangle its own vertices
    write(folder, GOOD)
    points, edges = feature_edges(load_target(folder))
    assert len(points) == 8 and len(edges) == 12
    lengths = sorted(round(float(np.linalg.norm(points[a] - points[b])), 6) for a, b in edges)
    assert lengths == [0.2] * 4 + [0.3] * 4 + [0.4] * 4

    points, edges = feature_edges(load_target(builtin_folder("tango")))
    drawn = {frozenset(map(tuple, np.round(points[[a, b]], 6))) for a, b in edges}
    body = np.round(tango.KEYPOINTS_M[:8], 6)
    box = [(i, (i + 1) % 4) for i in range(4)] + [(4 + i, 4 + (i + 1) % 4) for i in range(4)] + [(i, i + 4)
                                                                                              for i in range(4)]
    assert all(frozenset((tuple(body[a]), tuple(body[b]))) in drawn for a, b in box)
    tips = {tuple(p) for p in np.round(tango.KEYPOINTS_M[8:], 6)}
    assert tips <= {tuple(p) for p in np.round(points, 6)}  # each antenna drawn to its tip


@pytest.mark.parametrize("mesh, files, text", [
    ("model.gltf", {"model.gltf": '{"asset": {"version": "2.0"}, "buffers": [{"uri": "../secret.bin", '
                                  '"byteLength": 4}]}'}, "names '../secret.bin'"),
    ("model.obj", {"model.obj": "mtllib /etc/materials.mtl\nv 0 0 0\n"}, "names '/etc/materials.mtl'"),
    ("model.obj", {"model.obj": "mtllib m.mtl\nv 0 0 0\n", "m.mtl": "newmtl a\nmap_Kd ../../cat.png\n"},
     "names '../../cat.png'"),
])
def test_a_mesh_naming_files_outside_the_folder_is_refused(tmp_path, mesh, files, text):
    folder = tmp_path / "t"
    folder.mkdir()
    for name, content in files.items():
        (folder / name).write_text(content)
    write(folder, GOOD.replace('"boulder.stl"', f'"{mesh}"'), mesh)
    with pytest.raises(TargetError, match=text):
        load_target(folder)


def test_a_file_given_for_the_folder_is_an_error_not_a_crash(tmp_path):
    (tmp_path / "target.toml").write_text(GOOD)
    with pytest.raises(TargetError, match="cannot be read"):
        load_target(tmp_path / "target.toml")


def test_declared_keypoints_and_centre_are_in_the_body_frame_whatever_the_meshs_frame(tmp_path):
    """Only the mesh is moved by ``body_from_mesh``; keypoints and centre are written in the
    body frame (the labels'), in ``length_unit``."""
    points = [[0.0, 0.0, 183.0], [0.0, 0.0, -183.0], [163.0, 0.0, 0.0], [0.0, 114.0, 0.0]]
    target = load_target(cubesat(tmp_path / "cubesat", keypoints=points, centre=(0.0, 0.0, 10.0)))
    np.testing.assert_allclose(target.keypoints_m, np.asarray(points) / 1000)
    np.testing.assert_allclose(target.centre_m, [0.0, 0.0, 0.01])


def test_the_generic_mounts_put_tangos_board_and_fixture_where_tron_has_them():
    """Tango declares TRON's board and fixture; the rules for a target that declares none
    put them in the same places (the fixture level with the body centre, 0.4 mm above
    TRON's 8 cm on the mock-up)."""
    config = load_config("default")
    declared = load_target(builtin_folder("tango"))
    derived = dataclasses.replace(declared, board=None, fixture=derived_fixture(declared))
    np.testing.assert_allclose(layout.target_from_board(config.testbed, derived),
                               layout.target_from_board(config.testbed, declared), atol=1e-6)
    for mount in layout.MOUNT_NAMES:
        difference = (layout.target_from_targetee(derived, mount) - layout.target_from_targetee(declared, mount))
        np.testing.assert_allclose(difference[:3, :3], 0, atol=1e-12)
        np.testing.assert_allclose(difference[:3, 3], [0, 0, 0.000375], atol=1e-6)


def test_a_stranger_target_gets_a_board_on_its_top_and_a_fixture_off_its_body(tmp_path):
    config = load_config("default")
    target = load_target(boulder(tmp_path / "boulder"))  # 0.8 x 0.64 x 0.48 m, a full-size mock-up
    board = layout.target_from_board(config.testbed, target)
    centre = g.apply(board, layout.board_centre(config.testbed)[None])[0]
    np.testing.assert_allclose(centre, [0, 0, 0.24 + layout.BOARD_PLATE_M], atol=1e-6)  # on its top
    np.testing.assert_allclose(board[:3, 2], [0, 0, -1], atol=1e-12)  # z into the board, into the rock
    fixture = layout.target_from_targetee(target, "minus_x")
    np.testing.assert_allclose(fixture[:3, 3], [-0.4 - 0.12, 0, 0], atol=1e-6)
    np.testing.assert_allclose(fixture[:3, 2], [1, 0, 0], atol=1e-12)  # flange z along +x


def test_declared_symmetries_are_checked_on_the_mesh_and_reach_bops_models_info(tmp_path):
    from stages.export.bop import symmetries_mm

    folder = tmp_path / "box"
    folder.mkdir()
    trimesh.creation.box((400.0, 300.0, 200.0)).export(folder / "box.stl")  # mm, centred on the origin
    half_turn = [-1, 0, 0, 0, 0, -1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]  # about z: the box onto itself
    (folder / TARGET_FILE).write_text('format_version = 1\nname = "box"\nmesh = "box.stl"\nlength_unit = "mm"\n'
                                      f"[mockup]\nscale = 1.0\nmass_kg = 2.0\n[symmetries]\ndiscrete = [{half_turn}]\n"
                                      "continuous = [{ axis = [0, 0, 2], offset = [0, 0, 10] }]\n")
    info = symmetries_mm(load_target(folder))
    assert info["symmetries_discrete"] == [[float(v) for v in half_turn]]
    assert info["symmetries_continuous"] == [{"axis": [0.0, 0.0, 1.0], "offset": [0.0, 0.0, 10.0]}]
    quarter_turn = [0, -1, 0, 0, 1, 0, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]  # 400 x 300: not onto itself
    text = (folder / TARGET_FILE).read_text().replace(str(half_turn), str(quarter_turn))
    (folder / TARGET_FILE).write_text(text)
    with pytest.raises(TargetError, match=r"target.toml: key symmetries.discrete.0: moves a vertex"):
        load_target(folder)
    (folder / TARGET_FILE).write_text(text.replace(str(quarter_turn), str([2, 0, 0, 0] + half_turn[4:])))
    with pytest.raises(TargetError, match=r"key symmetries.discrete.0: expected a rigid transform"):
        load_target(folder)
    (folder / TARGET_FILE).write_text(text.split("[symmetries]")[0] + "[symmetries]\ndiscrete = 5\n")
    with pytest.raises(TargetError, match=r"key symmetries.discrete: expected a list"):
        load_target(folder)
