"""The undo record of a writing command (manifests/snapshot.py): whatever the command did
to manifests, markers, JSON files and recorded images, restore puts every byte back."""

import hashlib
import json
import os

from manifests import Workspace
from manifests.snapshot import SNAPSHOT_DIR, Snapshot


def digest(root):
    return {p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


def workspace(root):
    (root / "manifests" / "_state").mkdir(parents=True)
    (root / "manifests" / "plan").mkdir()
    (root / "manifests" / "plan" / "part-00000.parquet").write_bytes(b"old part")
    (root / "images").mkdir()
    (root / "images" / "a.png").write_bytes(b"old image")
    marker = {"fingerprint": "f", "rows": 1, "files": {"images/a.png": {"bytes": 9}}}
    (root / "manifests" / "_state" / "plan.json").write_text(json.dumps(marker))
    (root / "config.toml").write_text('profile = "smoke"\n')
    (root / "calibration.json").write_text('{"version": 2}')
    return Workspace(root)


def test_restore_puts_back_every_byte_whatever_the_command_changed(tmp_path):
    ws = workspace(tmp_path / "w")
    before = digest(ws.root)
    snapshot = Snapshot(ws).take()
    # what a failed --force run does: discard, rewrite by rename, add new manifests and files
    os.remove(ws.root / "manifests" / "plan" / "part-00000.parquet")
    (ws.root / "manifests" / "plan" / "part-00001.parquet").write_bytes(b"new part")
    (ws.root / "manifests" / "poses").mkdir()
    (ws.root / "manifests" / "_state" / "plan.json").write_text("{}")
    replacement = ws.root / "images" / ".a.png.tmp"
    replacement.write_bytes(b"new image")
    os.replace(replacement, ws.root / "images" / "a.png")  # writers replace files, never edit them
    (ws.root / "calibration.json").write_text('{"version": 3}')
    (ws.root / "fusion.json").write_text("{}")
    (ws.root / "config.toml").write_text('profile = "default"\n')
    snapshot.restore()
    assert digest(ws.root) == before
    assert not (ws.root / SNAPSHOT_DIR).exists()


def test_a_refusals_diagnostics_stay_only_where_there_was_nothing(tmp_path):
    ws = workspace(tmp_path / "w")
    snapshot = Snapshot(ws).take()
    (ws.root / "manifests" / "calibration_samples").mkdir()
    (ws.root / "manifests" / "calibration_samples" / "part-00000.parquet").write_bytes(b"reasons")
    (ws.root / "manifests" / "plan" / "part-00000.parquet").unlink()
    snapshot.restore(keep_new=("calibration_samples", "plan"))
    assert (ws.root / "manifests" / "calibration_samples" / "part-00000.parquet").read_bytes() == b"reasons"
    assert (ws.root / "manifests" / "plan" / "part-00000.parquet").read_bytes() == b"old part"


def test_a_new_workspace_is_emptied_of_what_the_command_wrote(tmp_path):
    root = tmp_path / "new"
    root.mkdir()
    snapshot = Snapshot(Workspace(root)).take()
    (root / "manifests" / "plan").mkdir(parents=True)
    (root / "manifests" / "plan" / "part-00000.parquet").write_bytes(b"x")
    (root / "config.toml").write_text("")
    snapshot.restore()
    assert digest(root) == {}


def test_a_marker_naming_a_path_outside_the_workspace_is_never_linked_or_written_back(tmp_path):
    outside = tmp_path / "outside.txt"
    outside.write_text("not the workspace's")
    ws = workspace(tmp_path / "w")
    marker = {"fingerprint": "f", "rows": 1, "files": {"../outside.txt": {"bytes": 19}, "/etc/hostname": {}}}
    (ws.root / "manifests" / "_state" / "plan.json").write_text(json.dumps(marker))
    snapshot = Snapshot(ws).take()
    assert not any("outside" in p.name for p in (ws.root / SNAPSHOT_DIR).rglob("*"))
    outside.write_text("changed since")
    snapshot.restore()
    assert outside.read_text() == "changed since"
