"""Same inputs, same bytes, and damage always noticed: a completed manifest is compacted
into sample_id order and its parts and files are recorded in its completion marker."""

import shutil
from dataclasses import replace

import pytest

from manifests import ManifestError, Workspace, list_parts, read_manifest
from manifests.integrity import recover
from pipeline import registry, runner
from pipeline.config import load_config
from pipeline.registry import StageEntry
from tests.conftest import speedplus

FAKE = StageEntry("plan", "plan rows in a shuffled order", "tests.pipeline.fake_stage",
                  target_folder="configured")


def parts_bytes(ws):
    return [(p.name, p.read_bytes()) for p in list_parts(ws, "plan")]


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The real plan stage, uninterrupted."""
    ws = Workspace(tmp_path_factory.mktemp("reference"))
    runner.run_stage(registry.stage("plan"), load_config("smoke"), ws)
    return parts_bytes(ws)


@pytest.mark.parametrize("seed, part_rows", [(1, 3), (2, 7), (3, 24)])
def test_finishing_order_and_part_size_never_reach_the_bytes(tmp_path, monkeypatch, reference, seed, part_rows):
    monkeypatch.setenv("FAKE_ORDER_SEED", str(seed))
    config = load_config("smoke")
    config = config.replace(run=replace(config.run, part_rows=part_rows))
    ws = Workspace(tmp_path)
    runner.run_stage(FAKE, config, ws)
    assert parts_bytes(ws) == reference


def test_a_killed_and_resumed_run_gives_the_same_bytes(tmp_path, monkeypatch, reference):
    config = load_config("smoke")
    config = config.replace(run=replace(config.run, part_rows=5))
    ws = Workspace(tmp_path)
    monkeypatch.setenv("FAKE_ORDER_SEED", "4")
    monkeypatch.setenv("FAKE_STOP_AFTER", "13")
    with pytest.raises(KeyboardInterrupt):
        runner.run_stage(FAKE, config, ws)
    assert runner.status(FAKE, config, ws).state == "partial"
    monkeypatch.setenv("FAKE_ORDER_SEED", "5")
    monkeypatch.delenv("FAKE_STOP_AFTER")
    assert runner.run_stage(FAKE, config, ws).action == "resumed"
    assert parts_bytes(ws) == reference


@pytest.mark.parametrize("harm, message", [
    (lambda part: part.unlink(), "part-00000.parquet is missing"),
    (lambda part: shutil.copy(part, part.with_name("part-00001.parquet")), "part-00001.parquet was not written"),
    (lambda part: part.write_bytes(part.read_bytes()[:-9] + b"x" + part.read_bytes()[-8:]),
     "part-00000.parquet changed"),
])
def test_a_damaged_manifest_is_noticed_by_readers_status_and_runner(tmp_path, harm, message):
    config, ws = load_config("smoke"), Workspace(tmp_path)
    plan = registry.stage("plan")
    runner.run_stage(plan, config, ws)
    harm(list_parts(ws, "plan")[0])
    with pytest.raises(ManifestError, match=f"damaged: {message}"):  # noqa: RUF043
        read_manifest(ws, "plan")
    state = runner.status(plan, config, ws)
    assert state.state == "damaged" and message in state.detail
    with pytest.raises(runner.StageError, match="damaged"):
        runner.run_stage(plan, config, ws)
    with pytest.raises(runner.StageError, match="needs manifest plan, which is damaged"):
        runner.run_stage(registry.stage("acquire"), config, ws)
    assert runner.run_stage(plan, config, ws, force=True).action == "ran"
    assert runner.status(plan, config, ws).state == "done"


def test_a_compaction_cut_between_its_renames_is_completed(tmp_path, reference):
    config, ws = load_config("smoke"), Workspace(tmp_path)
    runner.run_stage(registry.stage("plan"), config, ws)
    directory = ws.manifest_dir("plan")
    staging, old = directory.with_name(".plan.compact"), directory.with_name(".plan.old")
    shutil.copytree(directory, staging)
    directory.rename(old)  # the crash: the old parts moved aside, the new ones not yet in place
    recover(directory)
    assert parts_bytes(ws) == reference and not staging.exists() and not old.exists()


def test_verify_rehashes_images_and_names_the_stage_to_redo(smoke_labelled, tmp_path):
    ws = Workspace(tmp_path / "w")
    shutil.copytree(smoke_labelled.root, ws.root)
    assert speedplus("verify", "-w", str(ws.root)).returncode == 0
    image = ws.root / read_manifest(ws, "captures").column("image_path")[3].as_py()
    data = bytearray(image.read_bytes())
    data[len(data) // 2] ^= 0xFF
    image.write_bytes(bytes(data))
    result = speedplus("verify", "-w", str(ws.root))
    message = " ".join((result.stdout + result.stderr).split())
    assert result.returncode == 1 and "changed since it was written" in message and "redo acquire" in message


def test_a_manifest_without_rows_is_compacted_into_one_empty_part_it_can_be_read_from(tmp_path):
    """evaluate with one model writes no comparisons: the manifest still completes, and reads
    as a dataset of its schema with no rows."""
    from manifests import to_table
    from manifests.integrity import compact
    from manifests.schema import COMPARISONS

    workspace = Workspace(tmp_path)
    compact(workspace.manifest_dir("comparisons"), to_table([], COMPARISONS), COMPARISONS.key)
    assert [p.name for p in list_parts(workspace, "comparisons")] == ["part-00000.parquet"]
    table = read_manifest(workspace, "comparisons")
    assert table.num_rows == 0 and table.schema.names == [c.name for c in COMPARISONS.columns]


def test_a_marker_that_is_not_json_is_damaged_and_force_writes_it_anew(tmp_path):
    """The message says "redo the stage that writes it with --force": that works (issue 58,
    part 3), and the chain's checks before the first stage do not stop on it either."""
    config, ws = load_config("smoke"), Workspace(tmp_path)
    plan = registry.stage("plan")
    runner.run_stage(plan, config, ws)
    ws.marker_path("plan").write_text("{not json")
    ws.marker_path("captures").write_text("{not json")
    state = runner.status(plan, config, ws)
    assert state.state == "damaged" and "not valid JSON" in state.detail and "--force" in state.detail
    with pytest.raises(runner.StageError, match="damaged"):
        runner.run_stage(plan, config, ws)
    registry.stage("acquire").check(config, ws)  # its disk check counts every capture as still to make
    assert runner.run_stage(plan, config, ws, force=True).action == "ran"
    assert runner.status(plan, config, ws).state == "done"
