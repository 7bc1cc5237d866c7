"""A calibration refused for want of motion capture says which markers it saw on which
captures (issue 57, part 5)."""

from types import SimpleNamespace

import numpy as np

from stages.calibrate.per_source import markers_seen


def _row(sample_id: str, target: int | None, camera: int | None, measured: bool) -> dict:
    pose = [1.0, 0.0, 0.0, 0.0] if measured else None
    return {"sample_id": sample_id, "vicon_world_from_camrb_q": pose, "vicon_world_from_camrb_t": [0.0] * 3,
            "vicon_world_from_targetrb_q": pose, "vicon_world_from_targetrb_t": [0.0] * 3,
            "vicon_targetrb_markers": target, "vicon_camrb_markers": camera}


def test_the_lost_captures_are_named_with_the_markers_seen():
    rows = {r["sample_id"]: r for r in (_row("cal000000", 6, 5, True), _row("cal000001", 2, 5, False),
                                          _row("cal000002", 1, 4, False), _row("cal000003", None, None, False))}
    observations = [SimpleNamespace(sample_id=s, cam_from_target=np.eye(4)) for s in rows]
    observations.append(SimpleNamespace(sample_id="cal000004", cam_from_target=None))  # no board: not motion capture's
    said = markers_seen(observations, {**rows, "cal000004": _row("cal000004", 0, 0, False)})
    assert said.startswith("motion capture lost 3 posed capture(s)")
    assert "cal000001 target body 2, camera body 5" in said and "cal000002 target body 1" in said
    assert "cal000003 target body -" in said and "cal000000" not in said and "cal000004" not in said
    assert "[mockup] markers" in said


def test_each_capture_motion_capture_lost_has_its_reason_in_the_manifest(tmp_path):
    """The refusal sends the user to calibration_samples for every image's reason (issue 58,
    part 3): a capture the robots measured and motion capture did not says why there."""
    from manifests import Workspace, read_manifest
    from pipeline.config import load_config
    from stages.calibrate.stage import _write_samples

    rows = {r["sample_id"]: {**r, "fixture": "A"} for r in (_row("cal000000", 6, 5, True),
                                                             _row("cal000001", 2, 5, False))}
    observations = [SimpleNamespace(sample_id=s, cam_from_target=np.eye(4), reason=None, ids=[], rms_px=0.1,
                                    pixels=[], object_points=[]) for s in rows]
    ws = Workspace(tmp_path).for_run({"calibration_samples": "test"})
    _write_samples(load_config("smoke"), ws, observations, rows, {}, ("kuka", "vicon"))
    reasons = {r["sample_id"]: r["reason"] for r in read_manifest(ws, "calibration_samples").to_pylist()}
    assert reasons["cal000000"] is None
    assert reasons["cal000001"] == ("motion capture did not measure it (markers seen: target body 2, camera body 5; "
                                    "a rigid body needs 3): robots only")
    _write_samples(load_config("smoke"), ws, observations, rows, {}, ("kuka",))  # no motion capture: no reason
    assert all(r["reason"] is None for r in read_manifest(ws, "calibration_samples").to_pylist())
