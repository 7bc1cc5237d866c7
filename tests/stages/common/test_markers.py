"""Motion-capture markers on a target's mock-up: chosen where a folder declares none, on
every part wide enough, for the best fit over the whole target (spread out, seen from a
whole half-space each, clear of the fixtures); declared ones kept, and the convex hulls
that hide them."""

import dataclasses

import numpy as np
import pytest
from scipy.spatial import ConvexHull

from manifests.sidecars import MarkersRecord
from manifests.sidecars.base import Fields, SidecarError
from manifests.target import TARGET_FILE, TargetError
from stages.common import layout
from stages.common.marker_fit import mean_point_variance
from stages.common.markers import (
    CHOSEN_MARKERS,
    FIXTURE_CLEARANCE,
    STAND_OFF_M,
    Hull,
    Sightlines,
    markers,
    occluders,
    seen_from_room,
    up_directions,
)
from stages.common.target import load_target, main_body_box, main_body_part
from stages.common.targets import builtin_folder
from tests.target_folders import boulder, cubesat


def test_a_segment_is_hidden_exactly_when_it_passes_through_the_hull():
    """Seeded: random hulls and segments against a dense walk along each segment."""
    rng = np.random.default_rng(7)
    for _ in range(5):
        hull = ConvexHull(rng.normal(size=(30, 3)))
        body = Hull(hull.equations[:, :3], hull.equations[:, 3])
        start, end = rng.uniform(-3, 3, (400, 3)), rng.uniform(-3, 3, (400, 3))
        walk = start[:, None] + np.linspace(0, 1, 2001)[None, :, None] * (end - start)[:, None]
        inside = np.all(walk @ body.normals.T + body.offsets < -1e-3, axis=-1).any(axis=1)
        outside = np.all(np.max(walk @ body.normals.T + body.offsets, axis=-1) > 1e-3, axis=1)
        hidden = body.hides(start, end)
        assert np.all(hidden[inside]) and not np.any(hidden[outside])
        assert inside.sum() > 50 and outside.sum() > 50


@pytest.mark.parametrize("make", [cubesat, boulder], ids=["cubesat", "boulder"])
def test_chosen_markers_stand_off_their_part_spread_out_and_seen_from_a_half_space(make, tmp_path):
    target = load_target(make(tmp_path / "t"))
    placed = markers(target)
    assert placed.chosen and len(placed.centres_m) == CHOSEN_MARKERS
    hulls = dict(zip(target.parts, occluders(target).hulls, strict=True))
    vertices = main_body_part(target).vertices * target.mockup_scale
    diameter = 2 * np.max(np.linalg.norm(vertices - vertices.mean(axis=0), axis=1))
    apart = np.linalg.norm(placed.centres_m[:, None] - placed.centres_m[None], axis=2)
    assert apart[~np.eye(len(apart), dtype=bool)].min() > 0.1 * diameter
    flanges = np.stack([layout.target_from_targetee(target, mount)[:3, 3] for mount in layout.MOUNT_NAMES])
    assert np.linalg.norm(placed.centres_m[:, None] - flanges[None], axis=2).min() > FIXTURE_CLEARANCE * diameter
    rng = np.random.default_rng(3)
    for centre, normal, part in zip(placed.centres_m, placed.normals, placed.parts, strict=True):
        body = hulls[part]
        # it stands STAND_OFF_M outside its own part's hull, off the face it is stuck on
        assert np.max(centre @ body.normals.T + body.offsets) == pytest.approx(STAND_OFF_M, abs=1e-3)
        directions = rng.normal(size=(500, 3))
        directions /= np.linalg.norm(directions, axis=1, keepdims=True)
        directions[directions @ normal < 0] *= -1  # the outward half-space
        assert not body.hides(centre + 1e-6 * directions, centre + 5.0 * directions).any()


def fit_over_attitudes(target, placed) -> float:
    """The mean over attitudes of the fit's position variance at the centre, per unit noise."""
    seen = seen_from_room(placed.normals, up_directions())
    return float(mean_point_variance(placed.centres_m[None], seen.T[None], target.centre_m * target.mockup_scale,
                                     unseen_m2=1e6)[0])


def test_a_bus_with_long_panels_gets_markers_on_its_panels_and_a_better_fit(tmp_path):
    """Issue 43's mock-up: a 0.32 m bus, panels 1 m tip to tip. On the bus alone the
    markers sit within 0.2 m of each other; chosen over the whole target, some go on the
    panels and the fit at the centre is better than the old rule's (the main body's
    hull, farthest points); an antenna whip takes none."""
    from bench.targets import bus_panels, cubesat3u

    target = load_target(bus_panels(tmp_path / "bus"))
    placed = markers(target)
    assert {"panel_minus", "panel_plus"} & set(placed.parts), placed.parts
    body = main_body_part(target)
    old = markers(dataclasses.replace(target, parts={body.name: body}))  # the main body's alone
    assert set(old.parts) == {"bus"}
    assert fit_over_attitudes(target, placed) < fit_over_attitudes(target, old)
    whips = markers(load_target(cubesat3u(tmp_path / "cubesat")))
    assert not any(part.startswith("whip") for part in whips.parts)


def test_declared_or_chosen_markers_are_what_acquire_records(tmp_path):
    record = MarkersRecord("chosen", ("bus", "panel"), ((0.0, 0.0, 0.1), (0.1, 0.0, 0.0), (0.0, 0.1, 0.0)),
                           ((0.0, 0.0, 1.0), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0)))
    data = record.to_json()
    with pytest.raises(SidecarError, match="key parts: expected one per marker"):
        MarkersRecord.from_fields(Fields(data, "markers.json", ""))
    data["parts"] = ["bus", "panel", "panel"]
    assert MarkersRecord.from_fields(Fields(data, "markers.json", "")).parts == ("bus", "panel", "panel")


def test_tangos_declared_markers_are_where_the_body_box_rule_put_them():
    """Tango declares the six markers the virtual testbed used before targets chose their
    own (fractions of the main body box's half extents), to a micrometre on the mock-up."""
    target = load_target(builtin_folder("tango"))
    placed = markers(target)
    low, high = (v * target.mockup_scale for v in main_body_box(target))
    rel = np.array([(0.9, 0.8, 1.02), (-0.9, 0.85, 1.02), (0.85, -0.9, 1.02), (1.03, 0.2, 0.5), (-1.03, -0.3, 0.3),
                    (0.2, 1.03, 0.2)])
    assert not placed.chosen
    np.testing.assert_allclose(placed.centres_m, (low + high) / 2 + rel * (high - low) / 2, atol=1e-6)
    # on the faces they were meant for: the top, +x, -x; the last on the body's slanted +y side
    np.testing.assert_allclose(placed.normals[:5], [[0, 0, 1]] * 3 + [[1, 0, 0], [-1, 0, 0]], atol=1e-9)
    assert placed.normals[5][1] > 0.9


def test_the_plus_x_fixture_holds_the_body_from_its_other_side(tmp_path):
    """The CubeSat's wings reach 226 mm to -x: the whole mesh's centre is not the body's,
    and the fixtures stand off the body's two faces alike."""
    target = load_target(cubesat(tmp_path / "c"))
    low, high = (v * target.mockup_scale for v in main_body_box(target))
    minus_x, plus_x = (layout.target_from_targetee(target, mount) for mount in layout.MOUNT_NAMES)
    assert minus_x[0, 3] == pytest.approx(low[0] - 0.12) and plus_x[0, 3] == pytest.approx(high[0] + 0.12)
    np.testing.assert_allclose(plus_x[:3, 2], [-1, 0, 0], atol=1e-12)  # its flange faces the body too


def test_declared_markers_are_checked(tmp_path):
    folder = boulder(tmp_path / "b")
    text = (folder / TARGET_FILE).read_text()
    for markers_toml, key in (("[[0.4, 0, 0], [0, 0.3, 0], [0, 0, 0.3]]", r"key mockup\.markers: expected a list of "
                                                                          "at least 4"),
                              ("[[0.4, 0, 0], [0, 0.3, 0], [0, 0, 0.3], [0, 0, 300]]", r"key mockup\.markers\.3: "
                                                                                       "300 m from the body centre")):
        (folder / TARGET_FILE).write_text(text.replace("[mockup]\n", f"[mockup]\nmarkers = {markers_toml}\n"))
        with pytest.raises(TargetError, match=key):
            load_target(folder)
    (folder / TARGET_FILE).write_text(text.replace("[mockup]\n", "[mockup]\nmarkers = [[0.41, 0, 0], [-0.41, 0, 0], "
                                                   "[0, 0.33, 0], [0, 0, 0.25]]\n"))
    target = load_target(folder)
    placed = markers(target)
    assert not placed.chosen
    np.testing.assert_allclose(placed.centres_m, [[0.41, 0, 0], [-0.41, 0, 0], [0, 0.33, 0], [0, 0, 0.25]])


def test_a_target_with_no_face_wide_enough_for_a_marker_is_an_error_naming_it(tmp_path):
    """A mock-up of thin rods only (a truss of three parts): no marker can be chosen; the
    error says to declare them, it is not a crash. (One mesh of rods is one part whose
    box is wide: the rule judges parts, not faces.)"""
    import trimesh

    from manifests.target import TargetSpec, write_target_spec

    folder = tmp_path / "truss"
    folder.mkdir()
    scene = trimesh.Scene()
    for index, turn in enumerate((np.eye(4), trimesh.transformations.rotation_matrix(np.pi / 2, (1, 0, 0)),
                                  trimesh.transformations.rotation_matrix(np.pi / 2, (0, 1, 0)))):
        scene.add_geometry(trimesh.creation.cylinder(radius=0.004, height=0.6, transform=turn),
                           geom_name=f"rod{index}", node_name=f"rod{index}")
    (folder / "truss.glb").write_bytes(scene.export(file_type="glb"))
    write_target_spec(folder, TargetSpec("truss", "truss.glb", "m", 1.0, 1.0))
    with pytest.raises(TargetError, match=r"target truss: no part is 20 mm wide.*declare \[mockup\] markers"):
        markers(load_target(folder))


def test_markers_are_chosen_where_the_rooms_cameras_see_them_at_the_planned_poses(tmp_path):
    """Issue 57: a 1:4 rocket body held one way, four cameras on one wall. Markers chosen
    for a ring of cameras over every attitude are seen there a few at a time; chosen for
    these cameras at these poses, three or more are placed at every pose, and more on
    average. ``Sightlines`` hides a marker behind the mock-up's own parts: one on the far
    side of the tank is placed by no camera."""
    from bench.targets import rocket
    from stages.common import geometry as g

    target = load_target(rocket(tmp_path / "rocket"))
    body = occluders(target)
    rng = np.random.default_rng(5)
    poses = np.stack([g.make_transform(g.rotvec_to_matrix(rng.normal(0.0, 0.3, 3)), [2.0, 1.5, 1.2])
                      for _ in range(12)])
    cameras = np.array([[x, 0.05, 2.6] for x in (0.5, 1.5, 2.5, 3.5)])
    lines = Sightlines(cameras, np.tile([2.0, 1.5, 1.2], (4, 1)), np.radians(70.0), 8.0, poses)
    ring, planned = markers(target), markers(target, lambda centres, normals: lines.seen(centres, body))
    seen_ring, seen_planned = lines.seen(ring.centres_m, body), lines.seen(planned.centres_m, body)
    assert seen_planned.sum(axis=0).min() >= 3
    assert seen_planned.sum() > seen_ring.sum()
    # a point just off the tank towards the cameras is placed; its mirror behind the tank is not
    centre = target.centre_m * target.mockup_scale
    for d, pose in enumerate(poses):
        towards = g.apply(g.invert(pose), cameras).mean(axis=0) - centre
        towards /= np.linalg.norm(towards)
        near, behind = lines.seen(centre + np.array([0.15, -0.15])[:, None] * towards, body)[:, d]
        assert near and not behind
