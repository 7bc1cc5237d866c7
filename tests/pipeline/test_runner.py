"""Runner: fingerprints, skip when up to date, resume, refusal to mix results."""

from dataclasses import replace

import pyarrow.compute as pc
import pytest

from manifests import Workspace, part_fingerprints, read_manifest, read_marker, write_part
from pipeline import registry, runner
from pipeline.config import load_config
from stages.plan.stage import plan_sample, planned_samples

PLAN = registry.stage("plan")


@pytest.fixture()
def smoke():
    return load_config("smoke")


def sorted_table(table):
    return table.sort_by("sample_id")


def test_fingerprint_tracks_results_not_execution(smoke, tmp_path):
    ws = Workspace(tmp_path)
    base = runner.fingerprint(PLAN, smoke, ws)
    assert runner.fingerprint(PLAN, smoke, ws) == base
    assert runner.fingerprint(PLAN, smoke.replace(run=replace(smoke.run, part_rows=1)), ws) == base
    assert runner.fingerprint(PLAN, smoke.replace(plan=replace(smoke.plan, seed=1)), ws) != base
    assert runner.fingerprint(PLAN, smoke.replace(camera=replace(smoke.camera, fx_px=3000.0)), ws) != base


def test_run_then_skip_then_status(smoke, tmp_path):
    ws = Workspace(tmp_path)
    assert runner.status(PLAN, smoke, ws).state == "missing"
    outcome = runner.run_stage(PLAN, smoke, ws)
    assert outcome.action == "ran" and outcome.rows == {"plan": 24}
    marker = read_marker(ws, "plan")
    assert marker.rows == 24 and marker.fingerprint == runner.fingerprint(PLAN, smoke, ws)
    before = sorted(p.stat().st_mtime_ns for p in ws.manifest_dir("plan").iterdir())
    assert runner.run_stage(PLAN, smoke, ws).action == "skipped"
    assert sorted(p.stat().st_mtime_ns for p in ws.manifest_dir("plan").iterdir()) == before
    assert runner.status(PLAN, smoke, ws).state == "done"


def test_changed_configuration_is_stale_and_needs_force(smoke, tmp_path):
    ws = Workspace(tmp_path)
    runner.run_stage(PLAN, smoke, ws)
    changed = smoke.replace(plan=replace(smoke.plan, seed=5))
    assert runner.status(PLAN, changed, ws).state == "stale"
    with pytest.raises(runner.StageError, match="another configuration.*--force"):
        runner.run_stage(PLAN, changed, ws)
    outcome = runner.run_stage(PLAN, changed, ws, force=True)
    assert outcome.action == "ran"
    assert runner.status(PLAN, changed, ws).state == "done"
    assert runner.status(PLAN, smoke, ws).state == "stale"


def test_a_stage_never_builds_on_an_input_whose_stage_is_stale(smoke, tmp_path):
    """plan.seed changed after the plan: acquire, even with --force, is refused before it
    changes anything, naming the plan, the key and the command that redoes it (a changed
    target or facility folder is the same: the plan's fingerprint holds their digests)."""
    ws = Workspace(tmp_path)
    runner.run_stage(PLAN, smoke, ws)
    acquire = registry.stage("acquire")
    assert runner.outdated_inputs(acquire, smoke, ws) == []
    changed = smoke.replace(plan=replace(smoke.plan, seed=5))
    (name, state), = runner.outdated_inputs(acquire, changed, ws)
    assert (name, state.stage, state.detail) == ("plan", "plan", "plan.seed 2021 -> 5")
    before = sorted(str(p.relative_to(tmp_path)) for p in tmp_path.rglob("*"))
    for force in (False, True):
        with pytest.raises(runner.StageError, match=r"reads plan \(stage plan: plan.seed 2021 -> 5\).* Redo it first "
                                                    r"\(`speedplus plan -w .* --force`"):
            runner.run_stage(acquire, changed, ws, force=force)
    assert sorted(str(p.relative_to(tmp_path)) for p in tmp_path.rglob("*")) == before
    runner.run_stage(PLAN, changed, ws, force=True)
    assert runner.outdated_inputs(acquire, changed, ws) == []


def test_partial_results_resume_to_the_uninterrupted_plan(smoke, tmp_path):
    fresh = Workspace(tmp_path / "fresh")
    runner.run_stage(PLAN, smoke, fresh)
    ws = Workspace(tmp_path / "resumed")
    fingerprint = runner.fingerprint(PLAN, smoke, ws)
    done = [plan_sample(smoke, *item) for item in planned_samples(smoke)[3:9]]  # not even a prefix
    write_part(ws, "plan", done, fingerprint)
    assert runner.status(PLAN, smoke, ws).state == "partial"
    outcome = runner.run_stage(PLAN, smoke, ws)
    assert outcome.action == "resumed" and outcome.rows == {"plan": 24}
    assert sorted_table(read_manifest(ws, "plan")).equals(sorted_table(read_manifest(fresh, "plan")))


def test_partial_results_of_another_configuration_are_not_mixed(smoke, tmp_path):
    ws = Workspace(tmp_path)
    write_part(ws, "plan", [plan_sample(smoke, *planned_samples(smoke)[0])], "some-other-fingerprint")
    assert runner.status(PLAN, smoke, ws).state == "stale"
    with pytest.raises(runner.StageError, match="--force"):
        runner.run_stage(PLAN, smoke, ws)
    runner.run_stage(PLAN, smoke, ws, force=True)
    table = read_manifest(ws, "plan")
    assert table.num_rows == 24 and pc.count_distinct(table.column("sample_id")).as_py() == 24


def test_missing_input_names_the_manifest(smoke, tmp_path):
    with pytest.raises(runner.StageError, match="needs the complete manifest.s. captures, calibration_samples"):
        runner.run_stage(registry.stage("fuse"), smoke, Workspace(tmp_path))


def test_a_stage_run_stamps_its_parts_and_nothing_else_can(smoke, tmp_path):
    ws = Workspace(tmp_path)
    with pytest.raises(RuntimeError, match="not being written by a stage run"):
        ws.output_fingerprint("plan")
    runner.run_stage(PLAN, smoke, ws)
    assert part_fingerprints(ws, "plan") == {runner.fingerprint(PLAN, smoke, ws)}
    with pytest.raises(RuntimeError):  # the runner's view of the workspace was its own
        ws.output_fingerprint("plan")


def test_stale_results_say_when_the_target_s_files_changed():
    """A target edited in place (same target.path, another mesh) is named, not "another
    configuration" (issue 58, part 3)."""
    made = {"config": {"plan": {"seed": 1}}, "inputs": {}, "target": "aaa", "schema_version": "1"}
    said = runner.differences(made, {**made, "target": "bbb"})
    assert said == "the target's files changed (its target.toml or mesh)"
    assert runner.differences(made, made) == "made with another configuration or inputs"
