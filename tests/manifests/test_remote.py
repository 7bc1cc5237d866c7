"""Workspaces on object storage (manifests/remote.py, manifests/lease.py) against an
S3-protocol server on 127.0.0.1 (moto)."""

import json
import os
import time
import uuid

import pytest

from manifests import lease as lease_module
from manifests.lease import Lease, LeaseBusyError, holder
from manifests.remote import INDEX_FILE, Remote, RemoteCopy, StorageError, StoredFile, is_remote
from manifests.workspace import Workspace


@pytest.fixture
def prefix():
    return f"unit-{uuid.uuid4().hex[:8]}"


def _copy(object_store, prefix, root) -> RemoteCopy:
    return RemoteCopy(Remote(object_store.uri(prefix)), root)


def _write(root, relpath, data: bytes):
    path = root / relpath
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data)


def test_locations_that_are_not_a_prefix_in_a_supported_store_are_refused():
    assert is_remote("s3://bucket/w") and is_remote("gs://bucket/w")
    assert not is_remote("data/w") and not is_remote("file:///tmp/w")
    with pytest.raises(StorageError, match="unsupported storage 'http'"):
        Remote("http://example.org/w")
    with pytest.raises(StorageError, match="name a prefix inside the bucket"):
        Remote("s3://bucket")
    assert Remote("s3://key:secret@bucket/w/?region=x").display() == "s3://bucket/w"  # no credentials in messages


def test_push_uploads_files_and_parts_before_markers_and_a_pull_elsewhere_gets_all_but_media(
        object_store, prefix, tmp_path, monkeypatch):
    a = tmp_path / "a"
    files = {"config.toml": b"[run]\n", "manifests/labels/part-00000.parquet": b"PAR1",
             "manifests/_state/labels.json": b"{}", "images/dataset/img1.png": b"png", "renders/twins/rejected.json":
             b"[]", "manifests/_state/staging/labels/part-00001.parquet.1.tmp": b"half", ".lock": b"me"}
    for relpath, data in files.items():
        _write(a, relpath, data)
    order = []
    put = Remote.put
    monkeypatch.setattr(Remote, "put", lambda self, relpath, data: (order.append(relpath), put(self, relpath, data))[1])
    _copy(object_store, prefix, a).push()
    assert order[-1] == "manifests/_state/labels.json"  # the marker after everything it records
    stored = object_store.keys(prefix)
    assert set(stored) == set(files) - {"manifests/_state/staging/labels/part-00001.parquet.1.tmp", ".lock"}
    b = tmp_path / "b"
    copy = _copy(object_store, prefix, b)
    copy.pull()
    assert (b / "manifests/labels/part-00000.parquet").read_bytes() == b"PAR1"
    assert (b / "renders/twins/rejected.json").read_bytes() == b"[]"
    assert not (b / "images/dataset/img1.png").exists() and copy.has("images/dataset/img1.png")  # on demand
    assert copy.fetch("images/dataset/img1.png").read_bytes() == b"png"


def test_a_changed_marker_leaves_the_store_before_the_new_parts_arrive(object_store, prefix, tmp_path, monkeypatch):
    root = tmp_path / "w"
    _write(root, "manifests/labels/part-00000.parquet", b"old")
    _write(root, "manifests/_state/labels.json", b'{"v": 1}')
    copy = _copy(object_store, prefix, root)
    copy.push()
    time.sleep(0.01)
    _write(root, "manifests/labels/part-00000.parquet", b"new")
    _write(root, "manifests/_state/labels.json", b'{"v": 2}')
    seen = []
    put = Remote.put

    def spy(self, relpath, data):
        if relpath.endswith(".parquet"):
            seen.append("manifests/_state/labels.json" in object_store.keys(prefix))
        return put(self, relpath, data)

    monkeypatch.setattr(Remote, "put", spy)
    copy.push()
    assert seen == [False]  # no reader of the store pairs the old marker with the new part
    assert object_store.keys(prefix)["manifests/_state/labels.json"] == b'{"v": 2}'


def test_what_the_writer_deleted_is_deleted_in_the_store_and_then_in_other_copies(object_store, prefix, tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    _write(a, "manifests/labels/part-00000.parquet", b"x")
    _write(a, "manifests/labels/part-00001.parquet", b"y")
    _copy(object_store, prefix, a).push()
    _copy(object_store, prefix, b).pull()
    (a / "manifests/labels/part-00001.parquet").unlink()  # a compaction, a --force
    _copy(object_store, prefix, a).push()
    assert "manifests/labels/part-00001.parquet" not in object_store.keys(prefix)
    _copy(object_store, prefix, b).pull()
    assert not (b / "manifests/labels/part-00001.parquet").exists()
    assert (b / "manifests/labels/part-00000.parquet").read_bytes() == b"x"


def test_a_pull_keeps_unpushed_work_and_otherwise_takes_the_store(object_store, prefix, tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    _write(a, "session.json", b"1")
    _write(a, "fusion.json", b"1")
    _copy(object_store, prefix, a).push()
    time.sleep(0.01)
    _write(a, "session.json", b"unpushed")  # a command killed before its push
    _copy(object_store, prefix, b).pull()
    time.sleep(1.1)  # the store's clock has whole seconds
    _write(b, "fusion.json", b"from b")
    _copy(object_store, prefix, b).push()
    _copy(object_store, prefix, a).pull()
    assert (a / "session.json").read_bytes() == b"unpushed"
    assert (a / "fusion.json").read_bytes() == b"from b"


def test_files_a_worker_uploaded_are_checked_and_recorded_with_their_hash(object_store, prefix, tmp_path):
    copy = _copy(object_store, prefix, tmp_path / "w")
    stored = copy.remote.put("renders/twins/a.png", b"pixels")
    copy.accept("renders/twins/a.png", stored)
    assert copy.record("renders/twins/a.png") == {"bytes": 6, "sha256": stored.sha256}
    workspace = Workspace(tmp_path / "w", copy=copy)
    assert workspace.has_file("renders/twins/a.png") and not (tmp_path / "w/renders/twins/a.png").exists()
    with pytest.raises(StorageError, match="the worker wrote 7 bytes, the store holds 6 bytes"):
        copy.accept("renders/twins/a.png", StoredFile(7, stored.sha256))
    with pytest.raises(StorageError, match="no such object"):
        copy.accept("renders/twins/b.png", StoredFile(1, "0" * 64))


def test_keys_that_leave_the_workspace_and_a_damaged_index_are_named(object_store, prefix, tmp_path):
    object_store.client().put_object(Bucket=object_store.BUCKET, Key=f"{prefix}/images/../../evil", Body=b"x")
    with pytest.raises(StorageError, match=r"object 'images/\.\./\.\./evil' has a key that leaves the workspace"):
        _copy(object_store, prefix, tmp_path / "w").pull()
    (tmp_path / "v").mkdir()
    (tmp_path / "v" / INDEX_FILE).write_text(json.dumps({"version": 1, "uri": "s3://x/y", "synced": {},
                                                          "stored": []}))
    with pytest.raises(StorageError, match=rf"{INDEX_FILE}: key stored: expected an object"):
        _copy(object_store, prefix, tmp_path / "v")


def test_one_writer_holds_the_lease_and_a_dead_ones_lease_expires(object_store, prefix, monkeypatch):
    remote = Remote(object_store.uri(prefix))
    monkeypatch.setattr(lease_module, "SETTLE_S", 0.05)
    with Lease(remote, "speedplus run"):
        assert f"process {os.getpid()}" in holder(remote)
        busy = rf"in use by process {os.getpid()} on .*\(speedplus run, since"
        with pytest.raises(LeaseBusyError, match=busy), Lease(remote, "speedplus render"):
            pass
    assert holder(remote) is None and remote.read(".lock") is None
    stale = json.dumps({"version": 1, "token": "dead", "renewed": time.time() - 1000.0, "pid": 1, "host": "gone",
                        "command": "speedplus run", "since": "2026-01-01T00:00:00+00:00"}).encode()
    remote.put(".lock", stale)
    with Lease(remote, "speedplus run"):  # nobody renewed it: taken over
        assert json.loads(remote.read(".lock"))["pid"] == os.getpid()
    remote.put(".lock", b'{"version": 1}')
    with pytest.raises(StorageError, match=r"\.lock: key token: expected a str"):
        Lease(remote, "x").__enter__()


def test_two_writers_racing_for_a_free_lease_never_both_win(object_store, prefix, monkeypatch):
    remote = Remote(object_store.uri(prefix))
    first, second = Lease(remote, "first"), Lease(remote, "second")
    reads = lease_module.read_lease
    calls = []

    def racing(where):  # the second writer checks while the first settles, and writes after it
        calls.append(1)
        if len(calls) == 2:
            second._write()
        return reads(where)

    monkeypatch.setattr(lease_module, "read_lease", racing)
    monkeypatch.setattr(lease_module, "SETTLE_S", 0.05)
    with pytest.raises(LeaseBusyError, match="in use by"):
        first.__enter__()
