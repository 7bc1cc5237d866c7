"""``acquire --backend replay --format rosbag`` (stages/acquire/rosbag.py) and ``export
--format rosbag`` (stages/export/rosbag.py): a ROS 2 lab's bag replayed without a
converter. A bag written here with ``rosbags``' writer, as a lab records one (joints at
100 Hz through the moves, a /tf tree of static and moving edges, motion capture at 120 Hz
that loses a body, raw camera images), replays to the values at each image's stamp; the
export of a virtual session replays to the same captures as ``--format session`` of it;
each bad input is refused naming the topic, the stamp or the key, with nothing written."""

from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
import tomli_w

from manifests import Workspace
from speedplus.errors import FileError
from stages.acquire.rosbag import BagReplay
from stages.common import geometry as g
from stages.common.rosbag import messages as msg
from tests.conftest import speedplus
from tests.stages.export.test_session import assert_same_row

NS = 1_000_000_000
START = 1_700_000_000 * NS
#: the lab's three captures (s after START): the robots stand still from 1 s before each to 0.3 s after
CAPTURES_S = (2.0, 5.0, 8.0)
JOINTS = {"camera": [f"cam_j{k}" for k in range(1, 7)], "target": [f"tgt_j{k}" for k in range(1, 7)]}
WORLD_FROM_CAMERA_BASE = g.make_transform(g.rotvec_to_matrix([0.0, 0.0, 0.3]), [1.0, 0.5, 0.0])


def joints_at(robot: str, seconds: float) -> np.ndarray:
    """(6,) rad: still about each capture, moving linearly between."""
    def pose(k: int) -> np.ndarray:
        return np.linspace(0.1, 0.6, 6) * (k + 1) * (1.0 if robot == "camera" else -0.5)

    for k, c in enumerate(CAPTURES_S):
        if c - 1.0 <= seconds <= c + 0.3:
            return pose(k)
        if seconds < c - 1.0:
            if k == 0:
                return pose(0)
            previous = CAPTURES_S[k - 1] + 0.3
            share = (seconds - previous) / (c - 1.0 - previous)
            return pose(k - 1) + share * (pose(k) - pose(k - 1))
    return pose(len(CAPTURES_S) - 1)


def flange_from_joints(joints: np.ndarray) -> np.ndarray:
    """A stand-in for an arm's forward kinematics (what robot_state_publisher puts on /tf)."""
    return g.make_transform(g.rotvec_to_matrix([joints[3], joints[4], joints[0]]),
                            [0.8 + 0.1 * joints[1], 0.2 * joints[2], 1.2 + 0.05 * joints[5]])


def mapping(**changes) -> dict:
    document = {
        "format_version": 1, "sources": ["kuka", "vicon"], "world_frame": "world",
        "camera": {"topic": "/cam/image_raw"},
        "robots": {"camera": {"joints_topic": "/joint_states", "joints": JOINTS["camera"],
                              "flange_frame": "cam_tool0"},
                   "target": {"joints_topic": "/joint_states", "joints": JOINTS["target"],
                              "flange_frame": "tgt_tool0"}},
        "rail": {"topic": "/joint_states", "joint": "rail"},
        "motion_capture": {"camera_body": {"topic": "/vrpn/cam/pose"}, "target_body": {"topic": "/vrpn/tgt/pose"}},
        "captures": {"still_s": 0.5, "exposure_s": 0.02, "sessions": [["calibration", 0.0, 6.0],
                                                                     ["dataset", 6.0, 100.0]]},
    }
    for key, value in changes.items():
        section, _, name = key.partition("__")
        if name:
            document[section][name] = value
        elif value is None:
            document.pop(section)
        else:
            document[section] = value
    return document


def lab_bag(folder: Path, *, skip=(), clock_jump=False, moved=False, document=None, storage="mcap",
            extra=()) -> Path:
    """The lab's bag in ``folder`` with its ``rosbag.toml``. ``skip``: topics not recorded
    ("joints gap": /joint_states between 4 and 6 s); ``clock_jump``: /joint_states'
    stamps step 2 s against the recorder at 6.5 s; ``moved``: the camera arm drifts 1 mrad
    through the second capture's exposure; ``storage``: "mcap" (ROS 2 Iron on) or "sqlite3";
    ``extra``: more (recording ns, topic, type, message) to record."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    store, items = msg.typestore(), []
    for k in range(0, 1000):  # joints at 100 Hz over 10 s
        seconds = k / 100
        camera, target = joints_at("camera", seconds), joints_at("target", seconds)
        if moved and 4.9 <= seconds <= 5.1:
            camera = camera + (seconds - 4.9) * 5e-3
        stamp = START + round(seconds * NS) + (2 * NS if clock_jump and seconds >= 6.5 else 0)
        if not ("joints gap" in skip and 4.0 <= seconds <= 6.0):
            items.append((START + round(seconds * NS), "/joint_states", msg.JOINT_STATE, msg.joint_state(
                stamp, JOINTS["camera"] + JOINTS["target"] + ["rail"], [*camera, *target, 0.5])))
        edges = [msg.transform_stamped(stamp, "cam_base", "cam_link6", flange_from_joints(camera)),
                 msg.transform_stamped(stamp, "world", "tgt_tool0", flange_from_joints(target))]
        items.append((START + round(seconds * NS), "/tf", msg.TF, msg.tf_message(edges)))
    static = [msg.transform_stamped(START, "world", "cam_base", WORLD_FROM_CAMERA_BASE),
              msg.transform_stamped(START, "cam_link6", "cam_tool0", g.make_transform(np.eye(3), [0, 0, 0.1]))]
    items.append((START, "/tf_static", msg.TF, msg.tf_message(static)))
    for k in range(0, 1200):  # motion capture at 120 Hz; the target body lost from 7.5 s
        seconds = k / 120
        stamp = START + round(seconds * NS)
        items.append((stamp, "/vrpn/cam/pose", msg.POSE_STAMPED, msg.pose_stamped(
            stamp, "", flange_from_joints(joints_at("camera", seconds)) @ g.make_transform(np.eye(3), [0, 0, 0.2]))))
        if seconds < 7.5:
            items.append((stamp, "/vrpn/tgt/pose", msg.POSE_STAMPED, msg.pose_stamped(
                stamp, "", flange_from_joints(joints_at("target", seconds)))))
    pixels = np.arange(6 * 8 * 3, dtype=np.uint8).reshape(6, 8, 3)
    image_type = store.types[msg.IMAGE]
    for k, seconds in enumerate(CAPTURES_S):
        stamp = START + round(seconds * NS)
        items.append((stamp + 30_000_000, "/cam/image_raw", msg.IMAGE, image_type(
            header=msg.header(stamp, "camera"), height=6, width=8, encoding="rgb8", is_bigendian=0, step=24,
            data=(pixels + k).reshape(-1))))
    items += list(extra)
    bag = folder / "bag"
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(bag, version=9, storage_plugin=plugin) as writer:
        connections = {}
        for logged, topic, kind, message in sorted(items, key=lambda item: item[0]):
            if topic in skip:
                continue
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, kind, typestore=store)
            writer.write(connections[topic], logged, store.serialize_cdr(message, kind))
    (bag / "rosbag.toml").write_text(tomli_w.dumps(document or mapping()))
    return bag


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_a_labs_bag_replays_to_the_values_at_each_images_stamp(tmp_path, storage):
    replay = BagReplay(lab_bag(tmp_path, storage=storage), Workspace(tmp_path / "w"))
    assert [(s["sample_id"], s["session"]) for s in replay.samples()] == [
        ("cal000000", "calibration"), ("cal000001", "calibration"), ("img000000", "dataset")]
    for capture, seconds in zip(replay.captures, CAPTURES_S, strict=True):
        row = capture.row
        camera, target = joints_at("camera", seconds), joints_at("target", seconds)
        np.testing.assert_allclose(row["kuka_camera_joints_rad"], camera, atol=1e-12)
        np.testing.assert_allclose(row["kuka_target_joints_rad"], target, atol=1e-12)
        assert row["kuka_rail_m"] == pytest.approx(0.5, abs=1e-12)
        world_from_flange = WORLD_FROM_CAMERA_BASE @ flange_from_joints(camera) @ g.make_transform(
            np.eye(3), [0, 0, 0.1])
        got = g.transform_from_qt(row["kuka_world_from_camee_q"], row["kuka_world_from_camee_t"])
        np.testing.assert_allclose(got, world_from_flange, atol=1e-9)
        body = g.transform_from_qt(row["vicon_world_from_camrb_q"], row["vicon_world_from_camrb_t"])
        np.testing.assert_allclose(body[:3, 3], flange_from_joints(camera)[:3, 3] + flange_from_joints(camera)[:3, 2]
                                   * 0.2, atol=1e-9)
    assert replay.captures[2].row["vicon_world_from_targetrb_q"] is None  # lost from 7.5 s: not tracked
    assert replay.captures[0].row["vicon_world_from_targetrb_q"] is not None
    assert replay.captures[1].row["capture_time_s"] == pytest.approx(3.0)
    session = replay.session()
    assert (session.format, session.camera.width, session.camera.height) == ("rosbag", 8, 6)
    record = replay.capture(replay.samples()[1])
    from stages.common.image_io import read_image

    stored = read_image(tmp_path / "w" / record.captures["image_path"])
    np.testing.assert_array_equal(stored, (np.arange(144, dtype=np.uint8).reshape(6, 8, 3) + 1)[:, :, ::-1])
    assert "rgb8 -> png" in record.captures["image_conversion"]


@pytest.mark.parametrize(("case", "said"), [
    ({"skip": ("/vrpn/tgt/pose",)}, "motion_capture.target_body.topic: topic /vrpn/tgt/pose is not in the bag"),
    ({"clock_jump": True}, "/joint_states joints of the camera robot: at stamp 1700000008.500000000 s the stamps "
                           "stepped +2.000 s"),
    ({"skip": ("joints gap",)},
     "capture cal000001 at 1700000005.000000000 s: no message of /joint_states joints of the camera robot covers"),
    ({"moved": True}, "capture cal000001 at 1700000005.000000000 s: moved: /tf cam_base -> cam_link6 changed by"),
    ({"document": mapping(robots={"camera": {"joints_topic": "/joint_states", "joints": JOINTS["camera"],
                                             "flange_frame": "cam_flange"},
                                  "target": {"joints_topic": "/joint_states", "joints": JOINTS["target"],
                                             "flange_frame": "tgt_tool0"}})},
     "key robots.camera.flange_frame: frame cam_flange is not in /tf or /tf_static"),
    ({"document": mapping(captures={"sessions": [["calibration", 0.0, 4.0]]})},
     "key captures.sessions: the capture at 1700000005.000000000 s (5.000 s after the bag's start) is in no window"),
    ({"document": mapping(camera={"topic": "/vrpn/cam/pose"})},
     "key camera.topic: topic /vrpn/cam/pose carries geometry_msgs/msg/PoseStamped"),
    ({"document": {**mapping(), "captures": {"sesions": []}}}, "unknown key(s) in [captures] sesions (did you mean "
                                                               "sessions?)"),
])
def test_each_bad_input_is_refused_naming_it(tmp_path, case, said):
    with pytest.raises(FileError) as refused:
        BagReplay(lab_bag(tmp_path, **case), Workspace(tmp_path / "w"))
    assert said in str(refused.value), str(refused.value)


def test_a_refused_bag_writes_nothing(tmp_path):
    bag = lab_bag(tmp_path, moved=True)
    result = speedplus("acquire", "-w", str(tmp_path / "w"), "--backend", "replay", "--format", "rosbag",
                       "--source", str(bag))
    assert result.returncode == 1 and "Traceback" not in result.stderr
    assert "capture cal000001" in result.stderr and "moved" in result.stderr, result.stderr
    assert not (tmp_path / "w" / "manifests" / "captures").exists()


NOT_IN_A_BAG = {"vicon_targetrb_used", "vicon_targetrb_residual_m", "move_s", "vicon_camrb_markers",
                "vicon_targetrb_markers"}
PATHS = {"image_path", "source_image", "image_conversion"}


def _captures(workspace: Path) -> dict[str, dict]:
    return {r["sample_id"]: r for r in pq.read_table(workspace / "manifests" / "captures").to_pylist()}


def test_an_exported_bag_replays_to_the_captures_of_the_session_folder(smoke_labelled, tmp_path):
    """The same virtual session exported both ways and replayed: the same captures, images
    byte for byte, poses, joints, rail and times to 1e-9; and the bag's bytes do not
    depend on the run."""
    workspace = tmp_path / "w"
    shutil.copytree(smoke_labelled.root, workspace)
    for export in ("session", "rosbag"):
        result = speedplus("export", "-w", str(workspace), "--format", export)
        assert result.returncode == 0, result.stderr
    replayed = {}
    for export, source in (("session", workspace / "export" / "session"),
                           ("rosbag", workspace / "export" / "rosbag" / "bag")):
        replayed[export] = tmp_path / f"from_{export}"
        result = speedplus("acquire", "-w", str(replayed[export]), "--profile", "smoke", "--backend", "replay",
                           "--format", export, "--source", str(source))
        assert result.returncode == 0, result.stderr
    original, folder, bag = (_captures(p) for p in (workspace, replayed["session"], replayed["rosbag"]))
    assert set(original) == set(folder) == set(bag)
    for sample_id, row in folder.items():
        again = bag[sample_id]
        digest = {hashlib.sha256((p / r[sample_id]["image_path"]).read_bytes()).hexdigest()
                  for p, r in ((workspace, original), (replayed["session"], folder), (replayed["rosbag"], bag))}
        assert len(digest) == 1
        assert_same_row(row, again, NOT_IN_A_BAG | PATHS, 1e-9)
    first = (workspace / "export" / "rosbag" / "bag" / "bag.mcap").read_bytes()
    result = speedplus("export", "-w", str(workspace), "--format", "rosbag", "--force")
    assert result.returncode == 0, result.stderr
    assert (workspace / "export" / "rosbag" / "bag" / "bag.mcap").read_bytes() == first


def test_a_damaged_bag_is_refused_as_such(tmp_path):
    bag = lab_bag(tmp_path)
    data = (bag / "bag.mcap").read_bytes()
    (bag / "bag.mcap").write_bytes(data[: len(data) // 2])  # a recording cut short
    with pytest.raises(FileError, match="not a readable bag"):
        BagReplay(bag, Workspace(tmp_path / "w"))


def _at(seconds: float) -> int:
    return START + round(seconds * NS)


def _edge(seconds: float, parent: str, child: str, quaternion=(0.0, 0.0, 0.0, 1.0)):
    transform = msg.transform_stamped(_at(seconds), parent, child, np.eye(4))
    transform.transform.rotation.x, transform.transform.rotation.y, transform.transform.rotation.z, \
        transform.transform.rotation.w = quaternion
    return (_at(seconds), "/tf", msg.TF, msg.tf_message([transform]))


def test_what_a_labs_bag_holds_beside_the_mapped_topics_is_left_alone(tmp_path):
    """A gripper's efforts-only JointState on /joint_states, an unrelated /tf edge with a
    zero quaternion republished with one stamp: neither is the mapping's, neither refuses."""
    extra = [(_at(s), "/joint_states", msg.JOINT_STATE, msg.joint_state(_at(s), ["gripper"], []))
             for s in (1.0, 3.0)]
    extra += [_edge(s, "world", "camera_stand", (0.0, 0.0, 0.0, 0.0)) for s in (1.0, 2.0, 3.0)]
    replay = BagReplay(lab_bag(tmp_path, extra=extra), Workspace(tmp_path / "w"))
    assert len(replay.captures) == 3


def test_a_loop_in_tf_is_refused(tmp_path):
    """Two frames each other's parent, the mapped flange one of them: refused, not a hang."""
    extra = [_edge(1.0, "loop_a", "loop_b"), _edge(1.0, "loop_b", "loop_a")]
    document = mapping(robots={"camera": {"joints_topic": "/joint_states", "joints": JOINTS["camera"],
                                          "flange_frame": "loop_a"},
                               "target": {"joints_topic": "/joint_states", "joints": JOINTS["target"],
                                          "flange_frame": "tgt_tool0"}})
    with pytest.raises(FileError, match="key robots.camera.flange_frame: /tf holds a loop through frame loop_a"):
        BagReplay(lab_bag(tmp_path, extra=extra, document=document), Workspace(tmp_path / "w"))


def test_a_trigger_takes_the_image_within_its_window_once(tmp_path):
    """Triggers 30 ms before each image (a driver that stamps on arrival): taken; a trigger
    whose frame was dropped, refused; a trigger's source names a clock, not a sample."""
    triggers = [(_at(s) - 30_000_000, "/cam/trigger", msg.TIME_REFERENCE, msg.time_reference(_at(s) - 30_000_000,
                                                                                          "hw_clock"))
                for s in CAPTURES_S]
    document = mapping(captures={"trigger_topic": "/cam/trigger", "still_s": 0.5, "exposure_s": 0.02,
                                 "sessions": [["calibration", 0.0, 6.0], ["dataset", 6.0, 100.0]]})
    replay = BagReplay(lab_bag(tmp_path / "a", extra=triggers, document=document), Workspace(tmp_path / "w"))
    assert [c.sample_id for c in replay.captures] == ["cal000000", "cal000001", "img000000"]
    assert [c.image_stamp - c.stamp for c in replay.captures] == [30_000_000] * 3
    dropped = triggers + [(_at(2.5), "/cam/trigger", msg.TIME_REFERENCE, msg.time_reference(_at(2.04), "hw_clock"))]
    with pytest.raises(FileError, match="a frame was dropped"):
        BagReplay(lab_bag(tmp_path / "b", extra=dropped, document=document), Workspace(tmp_path / "w"))


def test_an_export_of_the_dataset_alone_keeps_its_session(tmp_path):
    from manifests.sidecars import Session, SessionCamera
    from stages.export.rosbag import mapping as bag_mapping
    from stages.export.rosbag import stamps

    rows = [{"session": "dataset", "capture_time_s": None, "fixture": "fixed", "kuka_camera_joints_rad": None,
             "kuka_target_joints_rad": None, "kuka_rail_m": None} for _ in range(4)]
    at = stamps(rows)
    plan = bag_mapping(Session("replay", "session", ("kuka",), SessionCamera(8, 6, None, None), None), rows, at,
                       tmp_path)
    assert {plan.session_at((s - min(at)) / NS + 0.55) for s in at} == {"dataset"}


@pytest.mark.parametrize("suffix", [".png", ".jpg"])
def test_a_compressed_images_size_is_read_from_its_header(suffix):
    import cv2

    ok, data = cv2.imencode(suffix, np.zeros((6, 8, 3), np.uint8))
    assert ok and msg.compressed_size(data.tobytes()) == (8, 6)
    assert msg.compressed_size(b"GIF89a....") is None
