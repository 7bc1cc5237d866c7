"""The speedplus command end to end, in subprocesses, as a user runs it."""

import shutil
import tomllib

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from manifests import Workspace, list_parts, read_manifest
from tests.conftest import speedplus


def test_plan_smoke_writes_a_valid_plan_then_does_nothing(tmp_path):
    ws = tmp_path / "w"
    first = speedplus("plan", "--profile", "smoke", "--workspace", str(ws))
    assert first.returncode == 0, first.stderr
    assert "plan: ran" in first.stdout
    assert read_manifest(Workspace(ws), "plan").num_rows == 24
    assert (ws / "config.toml").exists() and 'profile = "smoke"' in (ws / "config.toml").read_text()
    # the engine flags and run.* choose how this command runs: never saved, never a new fingerprint
    second = speedplus("plan", "--workspace", str(ws), "--workers", "3", "--engine", "local", "--set",
                       "run.part_rows=7")
    assert second.returncode == 0 and "up to date" in second.stdout
    saved = tomllib.loads((ws / "config.toml").read_text())["run"]
    assert (saved["workers"], saved["part_rows"]) == (1, 4)  # the smoke profile's
    status = speedplus("status", "--workspace", str(ws))
    assert status.returncode == 0
    line = next(line for line in status.stdout.splitlines() if "plan" in line and "plan 24" in line)
    assert "done" in line


def test_run_until_stops_there_and_a_rerun_skips_what_is_done(smoke_labelled, tmp_path):
    root = tmp_path / "w"
    after_fuse = ("poses", "poses.json", "labels", "labels.json", "renders*", "predictions*", "scores*", "export*")
    shutil.copytree(smoke_labelled.root, root, ignore=shutil.ignore_patterns(*after_fuse))
    result = speedplus("run", "--workspace", str(root), "--until", "fuse")
    assert result.returncode == 0 and "fuse: ran" in result.stdout and "label" not in result.stdout, result.stderr
    assert "plan: up to date" in result.stdout and "calibrate: up to date" in result.stdout
    again = speedplus("run", "--workspace", str(root), "--until", "fuse")
    assert again.returncode == 0 and again.stdout.count("up to date") == 4


def test_bad_configuration_exits_1_naming_the_key(tmp_path):
    result = speedplus("plan", "--profile", "smoke", "--workspace", str(tmp_path), "--set", "plan.n_calib=3")
    assert result.returncode == 1
    assert "plan.n_calib" in result.stderr and "plan.n_calibration" in result.stderr
    assert not list((tmp_path).glob("manifests/*"))


def test_usage_errors_exit_2(tmp_path):
    assert speedplus("plan", "--no-such-option").returncode == 2
    assert speedplus("run", "--until", "nowhere", "--workspace", str(tmp_path)).returncode == 2
    assert speedplus("frobnicate").returncode == 2


def test_killed_plan_resumes_to_the_uninterrupted_result(tmp_path):
    reference = tmp_path / "reference"
    assert speedplus("plan", "--profile", "smoke", "--workspace", str(reference)).returncode == 0
    ws = tmp_path / "killed"
    # SIGKILL while the third part is being written (temporary complete, not yet renamed)
    killed = speedplus("plan", "--profile", "smoke", "--workspace", str(ws),
                       env={"SPEEDPLUS_FAULT_KILL_AT_PART": "3"})
    assert killed.returncode == -9
    assert len(list_parts(Workspace(ws), "plan")) == 2
    # the half-written part is outside the folder: a Parquet reader sees the two whole parts
    assert sorted(p.name for p in (ws / "manifests" / "plan").iterdir()) == ["part-00000.parquet",
                                                                             "part-00001.parquet"]
    assert list(Workspace(ws).staging_dir("plan").glob("part-*.tmp"))
    status = speedplus("status", "--workspace", str(ws))
    assert "partial" in status.stdout
    resumed = speedplus("plan", "--workspace", str(ws))
    assert resumed.returncode == 0 and "resumed" in resumed.stdout
    assert not list(Workspace(ws).staging_dir("plan").glob("part-*.tmp"))
    got = read_manifest(Workspace(ws), "plan").sort_by("sample_id")
    expected = read_manifest(Workspace(reference), "plan").sort_by("sample_id")
    assert got.equals(expected)


def test_corrupted_manifest_exits_1_naming_file_row_and_column(tmp_path):
    ws = tmp_path / "w"
    speedplus("plan", "--profile", "smoke", "--workspace", str(ws), env={"SPEEDPLUS_FAULT_KILL_AT_PART": "3"})
    part = list_parts(Workspace(ws), "plan")[1]
    table = pq.read_table(part)
    rails = table.column("rail_m").to_pylist()
    rails[2] = float("nan")
    index = table.column_names.index("rail_m")
    pq.write_table(table.set_column(index, table.schema.field(index), pa.array(rails)), part)
    result = speedplus("plan", "--workspace", str(ws))
    assert result.returncode == 1
    message = " ".join(result.stderr.split())
    assert "part-00001.parquet, row 2" in message and "'rail_m'" in message and "not finite" in message


@pytest.mark.parametrize("command", ["acquire", "calibrate", "fuse", "label", "render", "evaluate", "report"])
def test_every_stage_has_a_command(command):
    result = speedplus(command, "--help")
    assert result.returncode == 0 and "--workspace" in result.stdout and "--force" in result.stdout


def test_an_unexpected_error_is_one_line_and_a_crash_log(monkeypatch, tmp_path, capsys):
    from pipeline import cli

    def broken() -> None:
        raise ZeroDivisionError("a bug [in brackets]")

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    monkeypatch.setattr(cli, "app", broken)
    with pytest.raises(SystemExit) as exited:
        cli.main()
    assert exited.value.code == 1
    stderr = capsys.readouterr().err
    message = " ".join(stderr.split())
    assert "unexpected ZeroDivisionError: a bug [in brackets]" in message and "Traceback" not in message
    (log,) = (tmp_path / "speedplus" / "crashes").iterdir()
    assert str(log) in "".join(stderr.split())
    assert "Traceback" in log.read_text() and "ZeroDivisionError" in log.read_text()


def test_export_refuses_a_folder_holding_other_files_even_with_force(smoke_labelled, tmp_path):
    out = tmp_path / "thesis"
    out.mkdir()
    (out / "chapter1.tex").write_text("mine")
    testbed = ("--set", 'export.sets=["testbed"]')  # the smoke workspace has no renders
    for force in ((), ("--force",)):
        refused = speedplus("export", "-w", str(smoke_labelled.root), "--out", str(out), *force, *testbed)
        said = " ".join(refused.stderr.split())
        assert refused.returncode == 1 and "not empty: it holds files speedplus did not write" in said, said
        assert sorted(p.name for p in out.iterdir()) == ["chapter1.tex"]


def test_each_export_format_keeps_its_own_folder_and_status_shows_each(smoke_labelled, tmp_path):
    """Issue 42: `export --format bop --out X`, then `export --format speedplus` wrote into X,
    and `--force` replaced BOP's camera.json with SPEED+'s."""
    ws = tmp_path / "w"
    shutil.copytree(smoke_labelled.root, ws)
    testbed = ("--set", 'export.sets=["testbed"]')
    bop = tmp_path / "bop"
    assert speedplus("export", "-w", str(ws), "--format", "bop", "--out", str(bop), *testbed).returncode == 0
    camera = (bop / "camera.json").read_bytes()
    plain = speedplus("export", "-w", str(ws), "--format", "speedplus", *testbed)
    assert plain.returncode == 0, plain.stderr
    assert (ws / "export" / "speedplus" / "camera.json").is_file() and (bop / "camera.json").read_bytes() == camera
    into_bop = speedplus("export", "-w", str(ws), "--format", "speedplus", "--out", str(bop), "--force", *testbed)
    said = " ".join(into_bop.stderr.split())
    assert into_bop.returncode == 1 and f"it holds a bop export of {ws}" in said, said
    assert (bop / "camera.json").read_bytes() == camera
    status = " ".join(speedplus("status", "-w", str(ws)).stdout.split())
    assert "export bop │ done" in status and "export speedplus │ done" in status, status




def test_keys_prints_every_key_of_a_section_with_its_meaning_and_refuses_an_unknown_one():
    from dataclasses import fields

    from pipeline.config import SECTION_TYPES

    result = speedplus("keys", "trajectory")
    assert result.returncode == 0, result.stderr
    for item in fields(SECTION_TYPES["trajectory"]):
        assert f"trajectory.{item.name}" in result.stdout
    assert "sequences to plan" in result.stdout
    wrong = speedplus("keys", "trajectorie")
    assert wrong.returncode == 1 and "no configuration section 'trajectorie'" in wrong.stderr
    assert "Traceback" not in wrong.stderr
