"""plan.mode = trajectory end to end on the smoke profile: sequences whose columns recompose
the planned pose, whose motion an independent propagator reproduces, acquired in frame
order, exported in SHIRT's layout and read back by a loader written from its description."""

import json
import math
import shutil

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.io import loadmat

from manifests import Workspace, read_manifest
from manifests.sidecars import read_trajectories
from stages.common import geometry as g
from stages.common.orbits import Elements, relative_two_body, rtn_from_eci, two_body
from tests.conftest import speedplus

TRAJECTORY = ("--set", "plan.mode=trajectory")


@pytest.fixture(scope="module")
def sequences(tmp_path_factory):
    """A smoke trajectory workspace through render (two sequences of four frames)."""
    root = tmp_path_factory.mktemp("trajectory") / "w"
    result = speedplus("run", "--profile", "smoke", "--workspace", str(root), *TRAJECTORY, "--until", "render")
    assert result.returncode == 0, result.stderr
    return Workspace(root)


def dataset_rows(workspace):
    rows = read_manifest(workspace, "plan").to_pylist()
    return sorted((r for r in rows if r["session"] == "dataset"), key=lambda r: r["sample_id"])


def chief_of(sequence):
    return Elements(**sequence.chief)


def test_the_columns_recompose_the_planned_pose(sequences):
    """cam_from_target = cam_from_eci . eci_from_target, translated by the servicer's RTN
    offset and the centre of mass, at mock-up scale."""
    record = read_trajectories(sequences)
    scale = json.loads(sequences.session_path.read_text())["mockup_scale"]
    rows = dataset_rows(sequences)
    assert [r["sequence_id"] for r in rows] == [s.sequence_id for s in record.sequences for _ in range(s.frames)]
    for row in rows:
        sequence = record.sequence(row["sequence_id"])
        assert row["time_s"] == pytest.approx(row["frame"] * sequence.cam_step_s)
        r, v = two_body(chief_of(sequence), [row["time_s"]])
        rtn_from = rtn_from_eci(r, v)[0]
        eci_from_cam = g.quat_to_matrix(row["eci_from_cam_q"])
        eci_from_target = g.quat_to_matrix(row["eci_from_target_q"])
        origin = -rtn_from.T @ row["rtn_servicer_m"] - eci_from_target @ np.asarray(sequence.centre_of_mass_m)
        expected = g.make_transform(eci_from_cam.T @ eci_from_target, scale * (eci_from_cam.T @ origin))
        np.testing.assert_allclose(g.transform_from_qt(row["cam_from_target_q"], row["cam_from_target_t"]), expected,
                                   atol=1e-9)
        assert abs(np.linalg.norm(row["sun_eci"]) - 1) < 1e-12 and isinstance(row["in_eclipse"], bool)
        assert 0 <= row["light_from_sun_rad"] <= math.pi


def test_an_independent_propagator_reproduces_the_frames(sequences):
    """Relative motion against both orbits propagated exactly (the model's first-order error:
    about e times the range); attitude against a rotation-matrix integration of Euler's
    equations with another integrator."""
    record = read_trajectories(sequences)
    rows = dataset_rows(sequences)
    for sequence in record.sequences:
        mine = [r for r in rows if r["sequence_id"] == sequence.sequence_id]
        times = np.array([r["time_s"] for r in mine])
        rtn = np.array([r["rtn_servicer_m"] for r in mine])
        exact = relative_two_body(chief_of(sequence), np.array(sequence.roe), times)
        assert np.abs(rtn - exact).max() < 2 * sequence.chief["e"] * np.linalg.norm(exact, axis=1).max() + 1e-6
        inertia = np.array(sequence.inertia_kgm2)

        def derivative(_, state, inertia=inertia):
            rotation, omega = state[:9].reshape(3, 3), state[9:]
            skew = np.array([[0, -omega[2], omega[1]], [omega[2], 0, -omega[0]], [-omega[1], omega[0], 0]])
            omega_dot = np.linalg.solve(inertia, -np.cross(omega, inertia @ omega))
            return np.concatenate([(rotation @ skew).ravel(), omega_dot])

        start = np.concatenate([g.quat_to_matrix(sequence.eci_from_target_q0).ravel(), sequence.omega0_rad_s])
        solution = solve_ivp(derivative, (0, times[-1]), start, method="Radau", t_eval=times, rtol=1e-12, atol=1e-14)
        reference = solution.y[:9].T.reshape(-1, 3, 3)
        got = g.quat_to_matrix(np.array([r["eci_from_target_q"] for r in mine]))
        assert np.max(g.angular_distance(got, reference)) < 1e-7


def test_the_testbed_acquires_each_sequence_in_frame_order(sequences):
    captures = {r["sample_id"]: r for r in read_manifest(sequences, "captures").to_pylist()}
    rows = dataset_rows(sequences)
    times = [captures[r["sample_id"]]["capture_time_s"] for r in rows]
    assert all(b > a for a, b in zip(times, times[1:], strict=False))
    moves = [captures[r["sample_id"]]["move_s"] for r in rows]
    assert moves[0] is None and all(m is not None and m >= 0 for m in moves[1:])
    assert all(b - a >= m for a, b, m in zip(times[:-1], times[1:], moves[1:], strict=True))


def test_same_seed_same_plan_bytes(sequences, tmp_path):
    result = speedplus("plan", "--profile", "smoke", "--workspace", str(tmp_path / "again"), *TRAJECTORY)
    assert result.returncode == 0, result.stderr
    again = Workspace(tmp_path / "again")
    assert again.trajectories_path.read_bytes() == sequences.trajectories_path.read_bytes()
    mine = sorted(p.name for p in sequences.manifest_dir("plan").iterdir())
    assert mine == sorted(p.name for p in again.manifest_dir("plan").iterdir())
    for name in mine:
        assert (sequences.manifest_dir("plan") / name).read_bytes() == (again.manifest_dir("plan") / name).read_bytes()


@pytest.mark.parametrize(("override", "named"), [
    ("trajectory.presets=[\"vbar_hold\"]", "trajectory.presets"),
    ("trajectory.inertia_kgm2=[1, 1, 3, 0, 0, 0]", "trajectory.inertia_kgm2"),
    ("trajectory.chief_a_m=7078", "trajectory.chief_a_m"),
    ("trajectory.epoch_utc=\"2026-03-20 06:00\"", "trajectory.epoch_utc"),
    ("trajectory.chief_a_m=nan", "trajectory.chief_a_m: expected a finite number"),
    ("evaluate.tracking_gate_probability=1.5", "evaluate.tracking_gate_probability"),
])
def test_a_bad_trajectory_configuration_is_refused_naming_the_key(tmp_path, override, named):
    root = tmp_path / "w"
    result = speedplus("plan", "--profile", "smoke", "--workspace", str(root), *TRAJECTORY, "--set", override)
    assert result.returncode == 1 and named in result.stderr and "Traceback" not in result.stderr
    assert not (root / "manifests" / "plan").exists() and not (root / "trajectories.json").exists()


def test_a_sequence_the_room_cannot_hold_is_refused_whole(tmp_path):
    """A custom relative orbit 60 m behind the target: every frame out of the testbed's
    reach; refused with the count, nothing written."""
    root = tmp_path / "w"
    result = speedplus("plan", "--profile", "smoke", "--workspace", str(root), *TRAJECTORY,
                       "--set", "trajectory.presets=[\"custom\"]", "--set", "trajectory.roe_m=[0, -60, 0, 1, 0, 1]")
    assert result.returncode == 1, result.stdout
    assert "sequence custom: 4 frame(s)" in result.stderr and "refused, not thinned" in result.stderr
    assert not (root / "manifests" / "plan").exists() and not (root / "trajectories.json").exists()


def shirt_loader(root, sequence):
    """A loader written from SHIRT's description: metadata.json (cam_step, num_images), a json
    per domain of {filename, q_vbs2tango_true, r_Vo2To_vbs_true}, images under <domain>/images."""
    metadata = json.loads((root / sequence / "metadata.json").read_text())
    domains = {}
    for path in sorted((root / sequence).glob("*.json")):
        if path.name != "metadata.json":
            domains[path.stem] = json.loads(path.read_text())
    return metadata, domains


def test_the_shirt_export_reads_back_frame_by_frame(sequences, tmp_path):
    out = tmp_path / "shirt"
    result = speedplus("export", "--workspace", str(sequences.root), "--format", "shirt", "--out", str(out))
    assert result.returncode == 0, result.stderr
    record = read_trajectories(sequences)
    labels = {r["sample_id"]: r for r in read_manifest(sequences, "labels").to_pylist()}
    rows = dataset_rows(sequences)
    points = loadmat(str(out / "tangoPoints.mat"))["tango3Dpoints"].T
    for sequence in record.sequences:
        metadata, domains = shirt_loader(out, sequence.sequence_id)
        assert metadata["cam_step"] == sequence.cam_step_s and metadata["num_images"] == sequence.frames
        assert metadata["roe_m"] == list(sequence.roe_m) and metadata["chief"] == sequence.chief
        assert set(domains) <= {"synthetic", "lightbox", "sunlamp"} and "synthetic" in domains
        frames = {r["frame"]: r for r in rows if r["sequence_id"] == sequence.sequence_id}
        testbed = sorted(e["frame"] for name, entries in domains.items() if name != "synthetic" for e in entries)
        assert testbed == sorted(frames)  # every frame under the light it was taken in
        for name, entries in domains.items():
            assert [e["frame"] for e in entries] == sorted(e["frame"] for e in entries)
            for entry in entries:
                row = frames[entry["frame"]]
                assert entry["time_s"] == row["time_s"] and (name == "synthetic" or name == row["light"])
                assert (out / sequence.sequence_id / name / "images" / entry["filename"]).is_file()
                label = labels[row["sample_id"]]
                rotation = g.quat_to_matrix(entry["q_vbs2tango_true"])
                camera = points @ rotation.T + entry["r_Vo2To_vbs_true"]
                pixels, _ = cv2_project(camera, metadata["camera"])
                np.testing.assert_allclose(pixels, label["keypoints_px"], atol=1e-4)


def cv2_project(points_cam, camera):
    import cv2

    pixels, jacobian = cv2.projectPoints(points_cam, np.zeros(3), np.zeros(3), np.array(camera["cameraMatrix"]),
                                         np.array(camera["distCoeffs"]))
    return pixels.reshape(-1, 2), jacobian


def test_bop_makes_a_scene_of_each_sequence_with_frames_as_image_ids(sequences, tmp_path):
    out = tmp_path / "bop"
    result = speedplus("export", "--workspace", str(sequences.root), "--format", "bop", "--out", str(out))
    assert result.returncode == 0, result.stderr
    record = read_trajectories(sequences)
    for scene, sequence in enumerate(record.sequences, start=1):
        for split in ("test", "test_twin"):
            gt = json.loads((out / split / f"{scene:06d}" / "scene_gt.json").read_text())
            assert sorted(int(k) for k in gt) == list(range(sequence.frames))


def test_the_shirt_format_needs_sequences(tmp_path):
    root = tmp_path / "w"
    shutil.rmtree(root, ignore_errors=True)
    result = speedplus("plan", "--profile", "smoke", "--workspace", str(root), "--set", "export.format=shirt")
    assert result.returncode == 1 and "export.format" in result.stderr


def test_evaluate_tracks_every_sequence_and_the_report_plots_it(sequences, tmp_path):
    root = tmp_path / "w"
    shutil.copytree(sequences.root, root)
    workspace = Workspace(root)
    # one model on its own crop is enough to see the filter fed per frame (and keeps the test short)
    result = speedplus("run", "--workspace", str(root), "--set", "evaluate.models=[\"models/reference.onnx\"]",
                       "--set", "evaluate.self_crop=false")
    assert result.returncode == 0, result.stderr
    assert "Tracking: reference, mean SPEED score" in result.stdout
    predictions = read_manifest(workspace, "predictions").to_pylist()
    tracked = read_manifest(workspace, "tracks").to_pylist()
    assert len(tracked) == len(predictions)  # every image of these workspaces is a frame of a sequence
    by_id = {p["prediction_id"]: p for p in predictions}
    for row in tracked:
        domain = "synthetic" if row["domain"] == "synthetic" else None
        matches = [p for key, p in by_id.items() if key.startswith(f"{row['model']}:{row['crop']}:")
                   and p["sample_id"] == row["sample_id"] and (p["domain"] == "synthetic") == (domain == "synthetic")]
        assert len(matches) == 1 and matches[0]["score_speed"] == row["frame_score_speed"]
        assert row["measured"] == matches[0]["pose_found"]
    report = (root / "report" / "index.html").read_text()
    assert "Tracking: per frame against a navigation filter" in report
    assert (root / "report" / "figures" / "tracking.png").is_file()


def test_a_twin_shows_the_earth_where_the_orbit_puts_it_in_view(sequences, tmp_path):
    """Held on the v-bar the camera looks along the track, 27 degrees above the 700 km
    horizon: no Earth (the twins rendered say so). From 8 m above the target (a custom
    sequence) it looks down: the renderer's Earth fills the background around the target."""
    from pipeline.config import load_config
    from stages.common.lens import LensCamera
    from stages.common.workspace_target import workspace_target
    from stages.render.jobs import RenderJob, orbital_earth
    from stages.render.worker import RenderWorker

    assert not any(read_manifest(sequences, "renders").column("earth").to_pylist())
    root = tmp_path / "w"
    result = speedplus("plan", "--profile", "smoke", "--workspace", str(root), *TRAJECTORY,
                       "--set", "trajectory.presets=[\"custom\"]", "--set", "trajectory.roe_m=[8, 0, 0, 0, 0, 0]")
    assert result.returncode == 0, result.stderr
    workspace = Workspace(root)
    config = load_config(None, workspace.config_path)
    sequences_by_id = {s.sequence_id: s for s in read_trajectories(workspace).sequences}
    c = config.camera
    camera = LensCamera(c.camera_matrix(), c.dist_coeffs(), c.width_px, c.height_px)
    worker = RenderWorker(camera, workspace_target(config, workspace), spp=4, max_depth=2, threads=1,
                          with_ground_truth=False)
    scale = workspace_target(config, workspace).mockup_scale
    for row in dataset_rows(workspace)[:2]:
        earth = orbital_earth(row, sequences_by_id)
        job = RenderJob(row["sample_id"], "twin", tuple(row["cam_from_target_q"]),
                        tuple(np.asarray(row["cam_from_target_t"]) / scale), (0.0, 0.0, -1.0), 3.0, True, 1, **earth)
        radiance, seen = worker.radiance(job)
        assert seen and (radiance.sum(axis=2) > 0).mean() > 0.9  # a lit planet all around the target
        assert np.dot(earth["earth_centre_cam_m"], [0, 0, 1]) > 0.99 * np.linalg.norm(earth["earth_centre_cam_m"])


def test_a_strangers_target_gets_sequences_of_its_own_size_and_inertia(tmp_path):
    """The CubeSat of tests/target_folders.py (three parts, mm): its sequences sit in its own
    range (SPEED+'s in diameters), its inertia is its mesh's, and the whole plan is placed."""
    from pipeline.config import load_config
    from stages.common.workspace_target import planned_target
    from tests.target_folders import cubesat

    folder = cubesat(tmp_path / "cubesat", mass_kg=4.0)
    root = tmp_path / "w"
    result = speedplus("plan", "--profile", "smoke", "--workspace", str(root), *TRAJECTORY, "--set",
                       f"target.path={folder}", "--set", "plan.dataset_range_m=[0, 1e9]", "--set",
                       "plan.dataset_range_diameters=[4.75, 6.94]", "--set", "trajectory.frames=12")
    assert result.returncode == 0, result.stderr
    workspace = Workspace(root)
    record = read_trajectories(workspace)
    diameter = planned_target(load_config(None, workspace.config_path)).diameter_m
    hold = record.sequence("vbar_hold_spin")
    moments = np.linalg.eigvalsh(np.array(hold.inertia_kgm2))  # a body's: positive, the triangle inequality
    assert hold.inertia_source == "mesh shell" and moments[0] > 0 and moments[2] <= moments[0] + moments[1]
    rows = dataset_rows(workspace)
    assert len(rows) == 24 and all(r["reachable"] for r in rows)
    ranges = [np.linalg.norm(r["rtn_servicer_m"]) for r in rows if r["sequence_id"] == "vbar_hold_spin"]
    # held at the middle of 4.75-6.94 diameters, as Tango's at the middle of 6.5-9.5 m
    assert -hold.roe_m[1] == pytest.approx((4.75 + 6.94) / 2 * diameter)
    assert abs(np.mean(ranges) - -hold.roe_m[1]) < 0.1 * -hold.roe_m[1]


def test_a_sequence_id_that_would_leave_the_export_is_refused(sequences, tmp_path):
    """W/trajectories.json names the export's folders: a hand-edited id with a path in it is
    an error naming the file and key."""
    from manifests.sidecars import SidecarError

    copy = Workspace(tmp_path / "w")
    copy.root.mkdir()
    data = json.loads(sequences.trajectories_path.read_text())
    data["sequences"][0]["sequence_id"] = "../outside"
    copy.trajectories_path.write_text(json.dumps(data))
    with pytest.raises(SidecarError, match=r"trajectories.json: key sequences.0.sequence_id: expected a name"):
        read_trajectories(copy)
