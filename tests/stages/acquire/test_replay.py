"""Replay backends: a recorded session (written by a fixture) and Tabb's dataset."""

import csv
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from manifests import Workspace, read_manifest
from pipeline import registry, runner
from pipeline.config import load_config
from speedplus.errors import FileError, InputError
from stages.acquire.handeye import HandEyeReplay
from stages.acquire.replay import SessionReplay
from stages.acquire.tabb import tabb_dataset
from stages.common import geometry as g

TABB = Path(__file__).resolve().parents[4] / "shared" / "external" / "tabb_ds1"


def fake_png(path):
    import cv2

    cv2.imwrite(str(path), np.full((20, 32), 7, np.uint8))


def recorded_rows(n=6, seed=0):
    """What a lab would have recorded: flange poses in K, motion capture in V (some untracked)."""
    rng = np.random.default_rng(seed)
    rows = []
    for i in range(n):
        camee = g.transform_from_qt(g.random_quats(rng, 1)[0], [4.0 + i * 0.1, 1.5, 2.0])
        targetee = g.transform_from_qt(g.random_quats(rng, 1)[0], [1.2, 1.5, 1.0])
        camrb = None if i == 2 else g.transform_from_qt(g.random_quats(rng, 1)[0], [2.0, -1.0 + i * 0.01, 2.2])
        targetrb = g.transform_from_qt(g.random_quats(rng, 1)[0], [0.5, -2.0, 1.1])
        rows.append({"sample_id": f"cal{i:06d}" if i < 4 else f"img{i:06d}",
                     "session": "calibration" if i < 4 else "dataset", "rail": 2.5 + i,
                     "camee": camee, "targetee": targetee, "camrb": camrb, "targetrb": targetrb})
    return rows


def write_session(directory: Path, rows, length_unit="mm", untracked_as="zeros"):
    """The session format of docs/user-guide.md, as a lab's logger writes it."""
    directory.mkdir(parents=True)
    (directory / "images").mkdir()
    (directory / "session.toml").write_text(
        f'format_version = 1\nlength_unit = "{length_unit}"\nangle_unit = "deg"\neuler = "ZYX"\n'
        'sources = ["kuka", "vicon"]\n[camera]\nwidth = 32\nheight = 20\n')
    scale = 1000.0 if length_unit == "mm" else 1.0
    with open(directory / "robot.csv", "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["sample_id", "session", "rail"] + [f"{b}_{a}" for b in ("camee", "targetee")
                                                             for a in "xyzabc"])
        for row in rows:
            values = []
            for body in ("camee", "targetee"):
                xyzabc = g.transform_to_kuka(row[body])
                values += list(xyzabc[:3] / 1000.0 * scale) + list(xyzabc[3:])
            writer.writerow([row["sample_id"], row["session"], row["rail"] * scale] + [repr(float(v)) for v in values])
    with open(directory / "mocap.csv", "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["sample_id", "body", "x", "y", "z", "qw", "qx", "qy", "qz", "markers"])
        for row in rows:
            for body in ("camrb", "targetrb"):
                if row[body] is None:
                    blank = [0.0] * 7 if untracked_as == "zeros" else [float("nan")] * 7
                    writer.writerow([row["sample_id"], body, *blank, 2])
                else:
                    q, t = g.transform_to_qt(row[body])
                    writer.writerow([row["sample_id"], body, *(repr(float(v)) for v in t * scale),
                                     *(repr(float(v)) for v in q), 5])
    for row in rows:
        fake_png(directory / "images" / f"{row['sample_id']}.png")
    return directory


def acquire(source, tmp_path, fmt="session", name="w"):
    config = load_config("smoke", overrides=["acquire.backend=replay", f"acquire.format={fmt}",
                                             f"acquire.source='{source}'"])
    ws = Workspace(tmp_path / name)
    runner.run_stage(registry.stage("acquire"), config, ws)
    return ws


@pytest.mark.parametrize("length_unit, untracked_as", [("mm", "zeros"), ("m", "nan")])
def test_recorded_session_replays_to_the_expected_captures(tmp_path, length_unit, untracked_as):
    rows = recorded_rows()
    source = write_session(tmp_path / "session", rows, length_unit, untracked_as)
    ws = acquire(source, tmp_path)
    captures = {r["sample_id"]: r for r in read_manifest(ws, "captures").to_pylist()}
    assert set(captures) == {r["sample_id"] for r in rows}
    for row in rows:
        got = captures[row["sample_id"]]
        assert got["session"] == row["session"] and got["status"] == "ok"
        for column, body in (("kuka_world_from_camee", "camee"), ("kuka_world_from_targetee", "targetee"),
                             ("vicon_world_from_camrb", "camrb"), ("vicon_world_from_targetrb", "targetrb")):
            if row[body] is None:
                assert got[f"{column}_q"] is None and got[f"{column}_t"] is None
            else:
                np.testing.assert_allclose(g.transform_from_qt(got[f"{column}_q"], got[f"{column}_t"]),
                                           row[body], atol=1e-9)
        assert (ws.root / got["image_path"]).is_file()
    assert not (ws.root / "truth.json").exists()


def test_session_without_images_or_with_bad_rows_is_refused(tmp_path):
    rows = recorded_rows()
    source = write_session(tmp_path / "s1", rows)
    (source / "images" / "cal000001.png").unlink()
    with pytest.raises(FileError, match=r"robot.csv: sample cal000001: image images/cal000001.png \(or .*\) is "
                                          r"missing"):
        acquire(source, tmp_path)

    def edit(name, line, old, new, directory):
        path = directory / name
        lines = path.read_text().splitlines()
        assert old in lines[line - 1]
        lines[line - 1] = lines[line - 1].replace(old, new, 1)
        path.write_text("\n".join(lines) + "\n")

    cases = [
        ("robot.csv", 3, "cal000001", "cal000000", r"robot.csv: line 3 \(sample_id cal000000\): duplicate"),
        ("robot.csv", 4, ",4500.0,", ",nan,", r"robot.csv: line 4 \(sample_id cal000002\), rail: non-finite"),
        ("mocap.csv", 2, ",5", ",x", r"mocap.csv: line 2, column markers: expected a number"),
    ]
    for index, (name, line, old, new, message) in enumerate(cases):
        directory = write_session(tmp_path / f"case{index}", rows)
        edit(name, line, old, new, directory)
        with pytest.raises(FileError, match=message):
            acquire(directory, tmp_path, name=f"w{index}")


def test_wrong_units_and_rotations_are_refused(tmp_path):
    rows = recorded_rows()
    metres_declared_mm = write_session(tmp_path / "units", rows, "m")
    toml = metres_declared_mm / "session.toml"
    toml.write_text(toml.read_text().replace('length_unit = "m"', 'length_unit = "mm"'))
    with pytest.raises(FileError, match=r"robot.csv: camee position: every position lies within .* "
                                          r"implausible for mm.*in m\?"):
        acquire(metres_declared_mm, tmp_path)
    quaternion = write_session(tmp_path / "quat", rows)
    text = (quaternion / "mocap.csv").read_text().splitlines()
    parts = text[1].split(",")
    parts[5] = repr(float(parts[5]) * 1.5)
    text[1] = ",".join(parts)
    (quaternion / "mocap.csv").write_text("\n".join(text) + "\n")
    with pytest.raises(FileError, match=r"mocap.csv: line 2 .*quaternion norm"):
        acquire(quaternion, tmp_path, name="w2")


@pytest.fixture()
def tabb_copy(tmp_path):
    copy = tmp_path / "tabb"
    shutil.copytree(TABB, copy)
    return copy


def test_tabb_dataset_ingests_as_88_captures_in_metres(tmp_path):
    ws = acquire(TABB, tmp_path, fmt="tabb")
    table = read_manifest(ws, "captures")
    assert table.num_rows == 88
    translations = np.array(table.column("kuka_world_from_camee_t").to_pylist())
    assert np.all(np.linalg.norm(translations, axis=1) < 3.0)  # metres, not millimetres
    assert np.all(np.linalg.norm(translations, axis=1) > 0.3)
    assert table.column("vicon_world_from_camrb_q").null_count == 88
    session = (ws.root / "session.json").read_text()
    assert '"chessboard"' in session and "0.0285" in session


def TabbReplay(source, workspace):  # noqa: N802 - reads like the class it was
    return HandEyeReplay(tabb_dataset(source), workspace, "tabb")


def test_tabb_hand_poses_invert_the_recorded_matrices():
    replay = TabbReplay(TABB, Workspace("/nonexistent"))
    first = np.loadtxt(TABB / "robot_cali.txt", skiprows=1)[:4]  # hand_from_base, mm
    base_from_hand = replay.base_from_flange[0]
    # the file rounds to 6 digits; ingestion projects the rotation onto SO(3) before inverting
    np.testing.assert_allclose(base_from_hand[:3, :3].T, first[:3, :3], atol=1e-6)
    np.testing.assert_allclose(base_from_hand[:3, :3].T @ base_from_hand[:3, :3], np.eye(3), atol=1e-12)
    np.testing.assert_allclose(base_from_hand[:3, 3], -first[:3, :3].T @ first[:3, 3] / 1000.0, atol=1e-6)


def test_tabb_bad_inputs_name_the_file(tabb_copy, tmp_path):
    (tabb_copy / "images" / "image40.png").unlink()
    with pytest.raises(FileError, match="87 images match .* but robot_cali.txt holds 88 poses"):
        TabbReplay(tabb_copy, Workspace(tmp_path))
    fake_png(tabb_copy / "images" / "image40.png")
    robot = tabb_copy / "robot_cali.txt"
    original = robot.read_text()
    robot.write_text(original.replace("-0.178668", "-0.5", 1))
    with pytest.raises(FileError, match=r"robot_cali.txt: matrix 0 \(line 2\): rotation is not orthonormal"):
        TabbReplay(tabb_copy, Workspace(tmp_path))
    robot.write_text(original.replace("-525.397105", "nan", 1))
    with pytest.raises(FileError, match=r"robot_cali.txt: matrix 0 \(line 2\): non-finite"):
        TabbReplay(tabb_copy, Workspace(tmp_path))
    robot.write_text(original.replace("88", "89", 1))
    with pytest.raises(FileError, match="announces 89 matrices but holds 88"):
        TabbReplay(tabb_copy, Workspace(tmp_path))
    lines = original.splitlines()
    scaled = [lines[0]]
    for line in lines[1:]:  # the same poses written in metres: implausible for Tabb's millimetres
        values = line.split()
        if len(values) == 4 and values[3] not in ("1.000000",):
            values[3] = repr(float(values[3]) / 1000.0)
        scaled.append(" ".join(values))
    robot.write_text("\n".join(scaled))
    with pytest.raises(FileError, match="implausible for mm"):
        TabbReplay(tabb_copy, Workspace(tmp_path))
    robot.write_text(original)
    (tabb_copy / "calibration_object.txt").write_text("chess_width 8\nchess_height 6\n")
    with pytest.raises(FileError, match="calibration_object.txt: missing chess_mm_width"):
        TabbReplay(tabb_copy, Workspace(tmp_path))


def add_joint_columns(robot_csv: Path, joints_deg, columns=None):
    """Append encoder-reading columns to a recorded robot.csv (what a KUKA logger adds)."""
    columns = columns or [f"{r}_j{k}" for r in ("camera", "target") for k in range(1, 7)]
    lines = robot_csv.read_text().splitlines()
    out = [lines[0] + "," + ",".join(columns)]
    for line, values in zip(lines[1:], joints_deg, strict=True):
        out.append(line + "," + ",".join(repr(float(v)) for v in values[:len(columns)]))
    robot_csv.write_text("\n".join(out) + "\n")


def test_recorded_encoder_readings_replay_in_radians(tmp_path):
    rows = recorded_rows()
    source = write_session(tmp_path / "session", rows)
    joints_deg = np.random.default_rng(5).uniform(-90, 90, (len(rows), 12))
    add_joint_columns(source / "robot.csv", joints_deg)
    ws = acquire(source, tmp_path)
    captures = {r["sample_id"]: r for r in read_manifest(ws, "captures").to_pylist()}
    for row, joints in zip(rows, joints_deg, strict=True):
        got = captures[row["sample_id"]]
        np.testing.assert_allclose(got["kuka_camera_joints_rad"], np.radians(joints[:6]), atol=1e-12)
        np.testing.assert_allclose(got["kuka_target_joints_rad"], np.radians(joints[6:]), atol=1e-12)
        assert got["kuka_rail_m"] == pytest.approx(row["rail"])
        assert got["capture_time_s"] is None  # not recorded


def test_recorded_capture_times_replay_and_bad_ones_name_the_line(tmp_path):
    rows = recorded_rows()
    source = write_session(tmp_path / "session", rows)
    times = np.arange(len(rows)) * 7.5
    add_joint_columns(source / "robot.csv", times[:, None], ["time_s"])
    captures = {r["sample_id"]: r for r in read_manifest(acquire(source, tmp_path), "captures").to_pylist()}
    assert [captures[r["sample_id"]]["capture_time_s"] for r in rows] == times.tolist()
    lines = (source / "robot.csv").read_text().splitlines()
    lines[3] = lines[3].rsplit(",", 1)[0] + ",soon"
    (source / "robot.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(FileError, match="robot.csv.*line 4.*time_s"):
        SessionReplay(source, Workspace(tmp_path / "w2"))


def test_a_partial_set_of_encoder_columns_is_refused(tmp_path):
    rows = recorded_rows()
    source = write_session(tmp_path / "session", rows)
    add_joint_columns(source / "robot.csv", np.zeros((len(rows), 6)), [f"camera_j{k}" for k in range(1, 7)])
    with pytest.raises(FileError, match="robot.csv.*missing column\\(s\\) target_j1"):
        SessionReplay(source, Workspace(tmp_path / "w"))


def one_robot_session(directory: Path, rows, static="target", extra_pattern=""):
    """A one-robot session: the other body stands still in the robot world, no columns for it."""
    moving = "camee" if static == "target" else "targetee"
    directory.mkdir(parents=True)
    (directory / "images").mkdir()
    (directory / "session.toml").write_text(
        'format_version = 1\nlength_unit = "mm"\nangle_unit = "deg"\neuler = "ZYX"\nsources = ["kuka"]\n'
        f'[setup]\n{static}_on = "world"\n[camera]\nwidth = 32\nheight = 20\n'
        f'[pattern]\nkind = "chessboard"\nsize = [9, 6]\nsquare_m = 0.02\n{extra_pattern}')
    with open(directory / "robot.csv", "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["sample_id", "session"] + [f"{moving}_{a}" for a in "xyzabc"])
        for row in rows:
            xyzabc = g.transform_to_kuka(row[moving])
            writer.writerow([row["sample_id"], "calibration", *(repr(float(v)) for v in xyzabc)])
    for row in rows:
        fake_png(directory / "images" / f"{row['sample_id']}.png")
    return directory


@pytest.mark.parametrize("static", ["target", "camera"])
def test_one_robot_sessions_need_no_invented_columns(tmp_path, static):
    rows = recorded_rows()
    moving = "camee" if static == "target" else "targetee"
    rows[0][moving] = np.eye(4)  # a pose at the robot's origin is plausible
    ws = acquire(one_robot_session(tmp_path / "one", rows, static), tmp_path)
    captures = read_manifest(ws, "captures").to_pylist()
    for row, got in zip(rows, captures, strict=True):
        camee = g.transform_from_qt(got["kuka_world_from_camee_q"], got["kuka_world_from_camee_t"])
        targetee = g.transform_from_qt(got["kuka_world_from_targetee_q"], got["kuka_world_from_targetee_t"])
        moved, still = (camee, targetee) if static == "target" else (targetee, camee)
        np.testing.assert_allclose(moved, row[moving], atol=1e-9)
        np.testing.assert_allclose(still, np.eye(4), atol=1e-15)
        assert got["kuka_rail_m"] is None
    pattern = json.loads((ws.root / "session.json").read_text())["pattern"]
    assert pattern["target_from_pattern_q"] == [1.0, 0.0, 0.0, 0.0] and pattern["target_from_pattern_t"] == [0, 0, 0]


def test_one_robot_sessions_refuse_columns_of_the_still_body_and_bad_patterns(tmp_path):
    rows = recorded_rows()
    source = one_robot_session(tmp_path / "one", rows)
    text = (source / "robot.csv").read_text().splitlines()
    text = [text[0] + ",targetee_x"] + [line + ",1.0" for line in text[1:]]
    (source / "robot.csv").write_text("\n".join(text) + "\n")
    with pytest.raises(FileError, match=r"robot.csv: column\(s\) targetee_x given, but session.toml \[setup\]"):
        acquire(source, tmp_path)
    source = one_robot_session(tmp_path / "two", rows, extra_pattern="target_from_pattern_q = [1, 0, 0]\n")
    with pytest.raises(InputError, match=r"session.toml: \[pattern\] target_from_pattern_q must be 4 finite numbers"):
        acquire(source, tmp_path, name="w2")
    source = one_robot_session(tmp_path / "three", rows, extra_pattern="dictionary = 'DICT_5X5_100'\n")
    with pytest.raises(InputError, match=r"session.toml: \[pattern\] marker_m and dictionary belong to charuco"):
        acquire(source, tmp_path, name="w3")


def test_degrees_declared_as_radians_are_refused(tmp_path):
    rows = recorded_rows()
    source = write_session(tmp_path / "deg", rows)
    edit_toml = source / "session.toml"
    edit_toml.write_text(edit_toml.read_text().replace('angle_unit = "deg"', 'angle_unit = "rad"'))
    angles = np.abs(g.transform_to_kuka(rows[0]["camee"])[3:])
    assert angles.max() > 2 * np.pi  # the fixture's rows turn by more than a turn in radians
    with pytest.raises(FileError, match=r"robot.csv: line 2 \(sample_id cal000000\), camee: angle .* rad is more "
                                          r"than a turn; is the file in degrees"):
        acquire(source, tmp_path)
