"""Manifest writer and validating reader: round trips and errors that name the culprit."""

import re

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from manifests import CompletionMarker, ManifestError, Workspace, read_manifest, read_marker, write_marker, write_part
from manifests.io import list_parts, part_fingerprints, remove_temporaries, to_table
from manifests.marker import MarkerError
from manifests.schema import MANIFESTS, SCHEMA_VERSION, TRUTH


def truth_rows(n, start=0):
    rng = np.random.default_rng(start)
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[q[:, 0] < 0] *= -1
    return [{"sample_id": f"img{start + i:06d}", "cam_from_target_q": q[i], "cam_from_target_t": [0.1, 0.0, 4.0 + i],
             "world_from_camee_q": [1.0, 0, 0, 0], "world_from_camee_t": [5.0, 1.5, 2.0],
             "world_from_targetee_q": q[i], "world_from_targetee_t": [1.0, 1.5, 1.0], "fixture_sag_rad": 0.003,
             "vicon_camrb_ghost": False, "vicon_targetrb_ghost": i == 1, "maps_path": None}
            for i in range(n)]


def test_round_trip_through_parts_and_pandas(tmp_path):
    ws = Workspace(tmp_path)
    write_part(ws, "truth", truth_rows(3), "fp")
    write_part(ws, "truth", truth_rows(2, start=3), "fp")
    write_marker(ws, "truth", CompletionMarker("fp", 5))
    table = read_manifest(ws, "truth")
    assert table.num_rows == 5
    assert [p.name for p in list_parts(ws, "truth")] == ["part-00000.parquet", "part-00001.parquet"]
    # what an ML team does: pandas on the directory (the marker is ignored)
    frame = pd.read_parquet(ws.manifest_dir("truth"))
    assert sorted(frame.sample_id) == [f"img{i:06d}" for i in range(5)]
    assert part_fingerprints(ws, "truth") == {"fp"}
    assert read_marker(ws, "truth").rows == 5


def test_schema_carries_units_and_version():
    field = TRUTH.schema().field("cam_from_target_t")
    assert field.metadata[b"unit"] == b"m"
    assert TRUTH.schema().metadata[b"speedplus.schema_version"]
    for spec in MANIFESTS.values():
        for column in spec.columns:
            assert column.unit is not None and column.description, (spec.name, column.name)


def corrupt(ws, name, column, row, value):
    path = list_parts(ws, name)[0]
    table = pq.read_table(path)
    values = table.column(column).to_pylist()
    values[row] = value
    index = table.column_names.index(column)
    table = table.set_column(index, table.schema.field(index), pa.array(values, type=table.schema.field(index).type))
    pq.write_table(table, path)
    return path


@pytest.mark.parametrize(
    "column, value, message",
    [
        ("cam_from_target_q", [0.9, 0.1, 0.0, 0.0], "quaternion norm"),
        ("cam_from_target_q", [-1.0, 0.0, 0.0, 0.0], "w < 0"),
        ("cam_from_target_t", [0.0, float("nan"), 1.0], "not finite"),
        ("cam_from_target_t", None, "null"),
        ("sample_id", "img000000", "duplicate key"),
    ],
)
def test_reader_names_file_row_and_column(tmp_path, column, value, message):
    ws = Workspace(tmp_path)
    write_part(ws, "truth", truth_rows(4), "fp")
    path = corrupt(ws, "truth", column, 2, value)
    with pytest.raises(ManifestError) as error:
        read_manifest(ws, "truth")
    text = str(error.value)
    assert path.name in text and "row 2" in text and column in text and message in text


def test_reader_rejects_paths_outside_the_workspace(tmp_path):
    ws = Workspace(tmp_path)
    spec = MANIFESTS["captures"]
    row = {c.name: None for c in spec.columns}
    row.update(sample_id="cal000000", session="calibration", fixture="fixed",
               image_path="images/calibration/cal000000.png",
               kuka_world_from_camee_q=[1, 0, 0, 0], kuka_world_from_camee_t=[0, 0, 0],
               kuka_world_from_targetee_q=[1, 0, 0, 0], kuka_world_from_targetee_t=[0, 0, 0],
               vicon_camrb_markers=5, vicon_targetrb_markers=0, status="ok")
    write_part(ws, "captures", [row], "fp")  # nullable motion capture is fine
    for bad in ("../secrets.png", "/etc/passwd"):
        corrupt(ws, "captures", "image_path", 0, bad)
        with pytest.raises(ManifestError, match="image_path.*inside"):
            read_manifest(ws, "captures")


def test_enum_and_unknown_columns_are_errors(tmp_path):
    ws = Workspace(tmp_path)
    rows = truth_rows(1)
    table = to_table(rows, TRUTH).append_column("extra", pa.array([1]))
    with pytest.raises(ManifestError, match="unexpected column"):
        write_part(ws, "truth", table, "fp")
    incomplete = dict(rows[0])
    del incomplete["cam_from_target_t"]
    with pytest.raises(ManifestError, match="column 'cam_from_target_t'.*lacks"):
        write_part(ws, "truth", [incomplete], "fp")


def test_writer_validates_before_anything_is_written(tmp_path):
    ws = Workspace(tmp_path)
    rows = truth_rows(2)
    rows[1]["cam_from_target_t"] = [0.0, 0.0, float("inf")]
    with pytest.raises(ManifestError, match="row 1"):
        write_part(ws, "truth", rows, "fp")
    assert list_parts(ws, "truth") == []


def test_keys_must_be_unique_across_parts(tmp_path):
    ws = Workspace(tmp_path)
    write_part(ws, "truth", truth_rows(2), "fp")
    write_part(ws, "truth", truth_rows(1), "fp")
    with pytest.raises(ManifestError, match="part-00001.parquet, row 0.*also in"):
        read_manifest(ws, "truth")


def test_half_written_parts_stay_outside_the_folder_and_are_removable(tmp_path):
    ws = Workspace(tmp_path)
    write_part(ws, "truth", truth_rows(2), "fp")
    write_marker(ws, "truth", CompletionMarker("fp", 2))
    # what a writer killed mid-part leaves
    (ws.staging_dir("truth") / "part-00001.parquet.123.tmp").write_bytes(b"half a file")
    assert sorted(p.name for p in ws.manifest_dir("truth").iterdir()) == ["part-00000.parquet"]
    assert read_manifest(ws, "truth").num_rows == 2
    assert remove_temporaries(ws, "truth") == 1


def test_a_workspace_of_an_older_layout_is_refused_with_the_reason(tmp_path):
    ws = Workspace(tmp_path)
    write_part(ws, "truth", truth_rows(2), "fp")
    ws.legacy_marker_path("truth").write_text('{"fingerprint": "fp", "rows": 2}')
    with pytest.raises(ManifestError, match=r"truth/_SUCCESS.json: written by an older version.*--force"):
        read_manifest(ws, "truth")


def test_a_truncated_part_is_reported_by_name(tmp_path):
    ws = Workspace(tmp_path)
    path = write_part(ws, "truth", truth_rows(2), "fp")
    path.write_bytes(path.read_bytes()[:50])
    with pytest.raises(ManifestError, match="part-00000.parquet: not a readable Parquet"):
        read_manifest(ws, "truth")


@pytest.mark.parametrize("text, key", [
    ("[1]", "(top level)"),
    ('{"rows": 3}', "fingerprint"),
    ('{"fingerprint": "f", "rows": -1}', "rows"),
    ('{"fingerprint": "f", "rows": 3, "parts": [{"name": "../x", "rows": 3, "sha256": "0"}]}', "parts"),
    ('{"fingerprint": "f", "rows": 3, "files": {"images/a.png": {"bytes": "many"}}}', "files"),
])
def test_a_malformed_completion_marker_names_the_file_and_key(tmp_path, text, key):
    ws = Workspace(tmp_path)
    ws.marker_path("truth").parent.mkdir(parents=True)
    ws.marker_path("truth").write_text(text)
    with pytest.raises(MarkerError, match=rf"_state/truth.json: key {re.escape(key)}: expected"):
        read_marker(ws, "truth")


def test_a_marker_reads_back_as_written_and_an_older_one_with_defaults(tmp_path):
    """Seeded: a marker's JSON round trip is the identity; one written before a key existed
    (no parts, files, members or timing) reads with that key's default."""
    import random

    from manifests.marker import FileRecord, PartRecord

    ws = Workspace(tmp_path)
    rng = random.Random(4)
    for _ in range(20):
        marker = CompletionMarker(
            f"{rng.getrandbits(64):016x}", rng.randrange(100), "plan", "1.12", "0.1", rng.random(), rng.random() < 0.5,
            "2026-12-04T17:00:00+00:00", {"config": {"plan": {"seed": rng.randrange(9)}}},
            tuple(PartRecord(f"part-{i:05d}.parquet", rng.randrange(9), "ab") for i in range(rng.randrange(3))),
            {f"images/{i}.png": FileRecord(rng.randrange(999), "cd") for i in range(rng.randrange(3))},
            {"reference": "ef"} if rng.random() < 0.5 else {})
        write_marker(ws, "plan", marker)
        assert read_marker(ws, "plan") == marker
    ws.marker_path("plan").write_text('{"fingerprint": "fp", "rows": 2}')
    old = read_marker(ws, "plan")
    assert (old.parts, old.files, old.members, old.made_with, old.seconds) == (None, None, {}, None, None)


def _restamp(path, version, schema=None):
    """Rewrite a part as another schema version would have (and with another schema)."""
    table = pq.read_table(path)
    metadata = {**table.schema.metadata, b"speedplus.schema_version": version.encode()}
    if schema is not None:
        table = table.cast(schema)
    pq.write_table(table.replace_schema_metadata(metadata), path)


def test_an_older_version_reads_only_where_its_columns_are_unchanged(tmp_path):
    """A kept 1.7 recording (plan, captures, truth: columns 1.8 did not change) reads as it
    is; a 1.7 labels part, whose keypoints were 11 fixed, or an unknown version, does not."""
    ws = Workspace(tmp_path)
    write_part(ws, "truth", truth_rows(3), "fp")
    part = list_parts(ws, "truth")[0]
    _restamp(part, "1.7")
    assert read_manifest(ws, "truth").num_rows == 3
    _restamp(part, "1.6")
    with pytest.raises(ManifestError, match=rf"schema version 1.6, this program reads {SCHEMA_VERSION}; rerun the"):
        read_manifest(ws, "truth")
    fields = [pa.field(f.name, pa.list_(pa.float32(), 3) if f.name == "cam_from_target_t" else f.type, f.nullable)
              for f in TRUTH.schema()]
    _restamp(part, "1.7", pa.schema(fields))
    with pytest.raises(ManifestError, match=rf"schema version 1.7, this program reads {SCHEMA_VERSION}"):
        read_manifest(ws, "truth")


def test_an_older_part_without_a_nullable_column_added_since_reads_it_as_nulls(tmp_path):
    """A 1.8 part lacks 1.9's nullable columns (the plan's trajectory columns, captures'
    move_s): it reads with them null; a part lacking a column that may not be null does not."""
    ws = Workspace(tmp_path)
    write_part(ws, "truth", truth_rows(3), "fp")
    part = list_parts(ws, "truth")[0]
    table = pq.read_table(part)
    metadata = {**table.schema.metadata, b"speedplus.schema_version": b"1.8"}
    pq.write_table(table.drop_columns(["maps_path"]).replace_schema_metadata(metadata), part)
    read = read_manifest(ws, "truth")
    assert read.column_names == [c.name for c in TRUTH.columns]
    assert read.column("maps_path").null_count == 3
    assert read.column("fixture_sag_rad").to_pylist() == table.column("fixture_sag_rad").to_pylist()
    pq.write_table(table.drop_columns(["fixture_sag_rad"]).replace_schema_metadata(metadata), part)
    with pytest.raises(ManifestError, match="schema version 1.8"):
        read_manifest(ws, "truth")


def test_a_ragged_list_column_is_checked_row_by_row(tmp_path):
    """calibration_samples.corners_px holds each capture's own number of corners: a NaN in the
    second row's is named in that row."""
    from manifests.schema import CALIBRATION_SAMPLES

    rows = []
    for index, count in enumerate((5, 3, 7)):
        corners = np.arange(2 * count, dtype=float).reshape(count, 2)
        if index == 1:
            corners[2, 1] = np.nan
        rows.append({"sample_id": f"cal{index:06d}", "fixture": "fixed", "corners": count, "used": True,
                     "reason": None, "pnp_rms_px": 0.1, **{f"{p}_{s}": None for p in (
                         "cam_from_target_cal", "kuka_cam_from_target", "vicon_cam_from_target") for s in "qt"},
                     "corners_px": corners, "corners_target_m": np.zeros((count, 3))})
    ws = Workspace(tmp_path)
    with pytest.raises(ManifestError, match=r"row 1.*corners_px|corners_px.*row 1") as error:
        write_part(ws, CALIBRATION_SAMPLES, rows, "fp")
    assert "cal000001" in str(error.value) and "not finite" in str(error.value)
    rows[1]["corners_px"][2, 1] = 0.0
    write_part(ws, CALIBRATION_SAMPLES, rows, "fp")
    assert [len(c) for c in read_manifest(ws, "calibration_samples").column("corners_px").to_pylist()] == [5, 3, 7]
