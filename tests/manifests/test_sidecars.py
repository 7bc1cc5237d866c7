"""session.json as a typed, versioned file: one writer, one reader, errors naming file and key."""

import json

import pytest

from manifests import Workspace
from manifests.sidecars import Session, SessionCamera, SidecarError, read_session, write_session

SESSION = Session("replay", "handeye", ("kuka",), SessionCamera(1928, 1208, None, None),
                  {"kind": "chessboard", "size": [28, 17], "square_m": 0.02}, "/data/kuka",
                  {"camee": "flange", "targetee": "robot base"})


def test_a_session_survives_its_file(tmp_path):
    workspace = Workspace(tmp_path)
    write_session(workspace, SESSION)
    assert read_session(workspace) == SESSION
    assert json.loads(workspace.session_path.read_text())["version"] == 1


@pytest.mark.parametrize("change, message", [
    ({"version": None}, r"version None, this program reads version 1; rerun acquire with --force"),
    ({"backend": "robot"}, r"key backend: expected virtual or replay, got 'robot'"),
    ({"sources": ["vicon"]}, r"key sources: expected a list starting with \"kuka\""),
    ({"camera": {"width": 0, "height": 10}}, r"key camera: expected an object with positive integer width"),
    ({"mockup_scale": "half"}, r"key mockup_scale: expected a number or null, got 'half'"),
    ({"extra": 1}, r"unknown key\(s\) extra"),
])
def test_a_malformed_session_names_the_file_and_key(tmp_path, change, message):
    workspace = Workspace(tmp_path)
    workspace.session_path.write_text(json.dumps({**SESSION.to_json(), **change}))
    with pytest.raises(SidecarError, match=f"session.json: {message}"):
        read_session(workspace)


def test_missing_or_corrupt_sessions_say_what_to_rerun(tmp_path):
    workspace = Workspace(tmp_path)
    with pytest.raises(SidecarError, match="session.json: missing; run acquire first"):
        read_session(workspace)
    workspace.session_path.write_text('{"version": 1, "backend": ')
    with pytest.raises(SidecarError, match="session.json: not valid JSON .*; rerun acquire with --force"):
        read_session(workspace)
