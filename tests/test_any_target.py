"""Strangers' targets through every stage on the smoke profile, as a lab would run them
(docs/user-guide.md, "Your own target"): a CubeSat as a GLB of named parts in millimetres with no
keypoints, and a boulder as one STL in metres with its own keypoints and view names.
Each is planned, acquired on the virtual testbed, calibrated, fused, labelled, rendered,
given a reference model of its own, scored, reported and exported, and the products are
read back with the consumers' own rules."""

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.io import loadmat

from bench.overlap import twin_overlap
from manifests import Workspace, read_manifest
from manifests.sidecars import read_markers
from pipeline.config import load_config
from stages.common import geometry as g
from stages.common import ground_truth
from stages.common.image_io import read_image
from stages.common.markers import markers
from stages.common.target import load_target
from tests.conftest import speedplus
from tests.stages.export.test_bop import load_ply, project
from tests.target_folders import boulder, cubesat

#: SPEED+'s 6.5-9.5 m of Tango (1.37 m across) in target diameters: any size, the same pictures;
#: 24 calibration captures (smoke: 16), enough for the arms' calibration to carry to 3-4 m
# no distance override: a target folder plans at SPEED+'s apparent size alone (issue 42)
IN_DIAMETERS = ("--set", "plan.n_calibration=24")
TINY_MODEL = ("--set", "reference.images=40", "--set", "reference.variants=[\"plain\"]", "--set",
              "reference.max_steps=20", "--set", "reference.input_width=64", "--set", "reference.input_height=64",
              "--set", "reference.width=4", "--set", "reference.batch_size=8")


def chain(name: str, root: Path) -> tuple[Path, dict]:
    """The whole chain for one target, as a lab runs it: the folder and each command's result."""
    # a lab's mock-up of the CubeSat, 4 kg: a flight 6U's 9 kg, held 17 cm from its centre of
    # mass, tilts TRON's fixture by 0.9-1.3 deg, which 12 smoke captures a fixture leave at
    # 1.6 deg on the robots' label (measured); the boulder is a hollow 3 kg replica likewise
    folder = cubesat(root / "lab" / name, mass_kg=4.0) if name == "cubesat" else boulder(root / "lab" / name)
    ws = root / "w"
    steps = {"until render": speedplus("run", "--profile", "smoke", "--workspace", str(ws), "--target", str(folder),
                                       *IN_DIAMETERS, "--until", "render")}
    if name == "cubesat":  # before it has a model: the run stops at evaluate, saying why
        steps["run without a model"] = speedplus("run", "--workspace", str(ws))
    steps.update({"train": speedplus("train-reference", "--workspace", str(ws), "--out", str(root / "models"),
                                     *TINY_MODEL),
                  # evaluate.models left empty: the model train-reference made in W/models/ is scored
                  "evaluate and report": speedplus("run", "--workspace", str(ws)),
                  "speedplus": speedplus("export", "--workspace", str(ws), "--format", "speedplus", "--out",
                                         str(root / "speedplus")),
                  "bop": speedplus("export", "--workspace", str(ws), "--format", "bop", "--out", str(root / "bop"))})
    return folder, steps


@pytest.fixture(scope="module", params=["cubesat", "boulder"])
def made(request, tmp_path_factory):
    """One target's chain: the target, its workspace, its root folder and the results."""
    root = tmp_path_factory.mktemp(request.param)
    folder, steps = chain(request.param, root)
    for name, result in steps.items():
        assert (result.returncode == 0) == (name != "run without a model"), (name, result.stderr[-2000:])
    return load_target(folder), Workspace(root / "w"), root, steps


def test_labels_carry_the_targets_keypoints_and_views(made):
    target, ws, _, _ = made
    labels = read_manifest(ws, "labels").to_pylist()
    assert len(labels) == 8 and {row["view"] for row in labels} == set(target.view_names)
    assert all(len(row["keypoints_px"]) == len(target.keypoints_m) for row in labels)


def test_the_labels_keypoints_land_on_the_twin_where_they_are_visible(made):
    target, ws, _, _ = made
    renders = {row["sample_id"]: row for row in read_manifest(ws, "renders").to_pylist()}
    checked = 0
    for label in read_manifest(ws, "labels").to_pylist():
        twin = ground_truth.read(ws.resolve(renders[label["sample_id"]]["ground_truth_path"]), ("Z", "part"))
        cam_from_target = g.transform_from_qt(label["q_vbs2tango_true"], label["r_Vo2To_vbs_true"])
        depth = g.apply(cam_from_target, target.keypoints_m)[:, 2]
        for (u, v), z in zip(np.asarray(label["keypoints_px"]), depth, strict=True):
            column, row = int(round(u)), int(round(v))
            nearest = twin.channels["Z"][row, column]
            if nearest < z - 0.02 * target.diameter_m:
                continue  # the body hides it (NaN: just off the silhouette's rim, where it must touch it)
            # 2 px: a corner of a wing thinner than a pixel, seen edge-on, can miss the pixel centres next to it
            window = (slice(max(row - 2, 0), row + 3), slice(max(column - 2, 0), column + 3))
            assert (twin.channels["part"][window] > 0).any(), (label["sample_id"], u, v)
            checked += 1
    keypoints = len(target.keypoints_m) * len(read_manifest(ws, "labels"))
    assert checked >= 0.4 * keypoints, (checked, keypoints)  # about half of a body's points face the camera


def test_twins_overlap_the_mockup_in_the_testbed_captures(made):
    """At the true pose the twin (through the calibrated lens) covers the capture's
    silhouette (through the true one) but for its rim pixels; at the label, the labels'
    errors show: a few mm at 3-4 m, more for a robots-only label (motion capture rejected)
    on a smoke facility whose dataset poses the arms' calibration reaches from 24 captures.
    A short session fuses with the calibration's weights (``stages/fuse/short_session.py``):
    where motion capture erred 11.8 mm and 1.0 deg within the rejection test, the CubeSat's
    img000002 fell to 0.91 (the robots alone: 5.6 mm, 0.6 deg), while the labels' mean E_T
    is 3.3 mm against the robots' 4.3; fused or not, no label falls below 0.9."""
    _, ws, _, _ = made
    rows = twin_overlap(load_config(None, ws.config_path), ws)
    assert min(r["iou_truth"] for r in rows) > 0.96  # one set of conventions, whatever the target
    labels = sorted(r["iou_label"] for r in rows)
    assert labels[0] > 0.9 and np.median(labels) > 0.95, rows


def test_the_markers_are_chosen_on_its_parts_and_recorded(made):
    from stages.acquire.virtual.mocap import planned_sight
    from stages.common.markers import occluders

    target, ws, _, _ = made
    recorded = read_markers(ws)
    # chosen for the room's cameras at the plan's poses (issue 57)
    sight = planned_sight(load_config(None, ws.config_path), target, read_manifest(ws, "plan").to_pylist(),
                          occluders(target))
    placed = markers(target, sight)
    assert recorded.source == "chosen" and recorded.parts == placed.parts
    assert set(recorded.parts) <= set(target.parts)
    np.testing.assert_allclose(recorded.centres_m, placed.centres_m)
    captures = [row for row in read_manifest(ws, "captures").to_pylist() if row["session"] == "dataset"]
    tracked = [row for row in captures if row["vicon_targetrb_markers"] >= 3]
    assert len(tracked) / len(captures) > 0.8  # motion capture follows the mock-up by the markers chosen on it
    # and says which of them each fit used, and its residual, which fuse turns into its sigma
    assert all(len(row["vicon_targetrb_used"]) == row["vicon_targetrb_markers"] for row in tracked)
    assert all(0 < row["vicon_targetrb_residual_m"] < 0.01 for row in tracked)


def test_its_labels_sigmas_cover_on_the_short_session(made):
    """Issue 43: a smoke session has too few two-source captures to measure the factor;
    the sigmas then carry that (``stages/fuse/short_session.py``): at least 85% of the 24
    true errors (8 labels, 3 axes) inside 1.96 sigma, and no axis with more than 2 of its 8
    outside. Honest sigmas fail this on about 3% of builds (4 or more of 24 outside at 5%
    each); 7 of 8 on every axis, as this asked before, fails on about 16% of them, and did on
    the CubeSat when the captures' noise changed (issue 60: 0, 1 and 2 outside in x, y, z)."""
    _, ws, _, _ = made
    truth = {r["sample_id"]: r for r in read_manifest(ws, "truth").to_pylist()}
    normalised = []
    for pose in read_manifest(ws, "poses").to_pylist():
        true = np.asarray(truth[pose["sample_id"]]["cam_from_target_t"])
        normalised.append((np.asarray(pose["cam_from_target_t"]) - true) / np.asarray(pose["sigma_t_m"]))
    outside = np.abs(np.array(normalised)) > 1.96  # (8, 3)
    assert outside.mean() <= 0.15 and outside.sum(axis=0).max() <= 2, outside.sum(axis=0)


def test_a_run_without_a_model_of_the_target_says_so_and_how_to_make_one(made):
    target, _, _, steps = made
    if "run without a model" not in steps:
        pytest.skip("asked of the CubeSat only")
    said = " ".join(steps["run without a model"].stderr.split())
    assert f"this workspace's target is '{target.name}'" in said and "speedplus train-reference" in said
    assert "Traceback" not in said


def test_its_own_model_is_scored_on_its_views(made):
    target, ws, _, _ = made
    scores = read_manifest(ws, "scores").to_pylist()
    assert {row["view"] for row in scores} == {*target.view_names, "all"}
    assert {row["model"] for row in scores} == {"reference"}
    assert (ws.root / "report" / "index.html").is_file()


def test_its_report_opens_with_how_good_its_labels_are(made):
    """Issue 59, on a target of another shape: the report's first section counts its labels
    under the SPEED+ thresholds as the truth does, and gives its own model's domain gap."""
    from manifests.sidecars import read_session
    from stages.common.label_accuracy import label_accuracy

    _, ws, _, _ = made
    page = (ws.root / "report" / "index.html").read_text()
    first = page[page.index("How good the labels are</h2>"):page.index("What the figures mean</h2>")]
    accuracy = label_accuracy(read_manifest(ws, "truth").to_pylist(), read_manifest(ws, "labels").to_pylist(),
                              read_manifest(ws, "poses").to_pylist(), read_session(ws).mockup_scale)
    under, count, _, _ = accuracy.share()
    assert f"{under} of {count} labels" in first and "reference (oracle box): mean SPEED score" in first, first


def test_the_devkits_loader_reads_the_targets_keypoints(made):
    target, _, root, _ = made
    points = loadmat(str(root / "speedplus" / "tangoPoints.mat"))["tango3Dpoints"]
    np.testing.assert_allclose(points.T, target.keypoints_m)
    assert json.loads((root / "speedplus" / "keypoints.json").read_text())["target"] == target.name


def test_bops_reader_loads_the_model_and_its_masks_match_it(made):
    target, _, root, _ = made
    vertices, _, faces = load_ply(root / "bop" / "models" / "obj_000001.ply")
    info = json.loads((root / "bop" / "models" / "models_info.json").read_text())["1"]
    assert info["diameter"] == pytest.approx(target.diameter_m * 1000, rel=1e-6)
    np.testing.assert_allclose(vertices.min(axis=0), np.concatenate(
        [p.vertices for p in target.parts.values()]).min(axis=0) * 1000, atol=1e-3)
    scene = root / "bop" / "test" / "000001"
    camera = json.loads((scene / "scene_camera.json").read_text())
    for key, [gt] in json.loads((scene / "scene_gt.json").read_text()).items():
        pixels, _ = project(vertices[faces].mean(axis=1), camera[key]["cam_K"], gt["cam_R_m2c"], gt["cam_t_m2c"])
        mask = read_image(scene / "mask" / f"{int(key):06d}_000000.png", "gray") > 0
        inside = (pixels >= 0).all(axis=1) & (pixels[:, 0] < mask.shape[1] - 1) & (pixels[:, 1] < mask.shape[0] - 1)
        hits = mask[np.round(pixels[inside, 1]).astype(int), np.round(pixels[inside, 0]).astype(int)]
        assert hits.mean() > 0.8  # face centres fall on the silhouette (those at its rim may not)
