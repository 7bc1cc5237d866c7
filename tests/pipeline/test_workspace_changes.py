"""A stage changes the workspace only when it succeeds (issue: bring your own model, data
and settings; issue 58): refused and failed stages leave every byte as they found it, a
chain keeps the stages it completed, what can be refused is refused before the first
stage, settings layer on the saved configuration, stale results say why, models are
added beside the shipped ones, and Ctrl-C says what it kept."""

import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from manifests import Workspace, read_manifest
from tests.conftest import missing_named, speedplus

REPOSITORY = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def digest(root):
    """One hash of every file of a workspace (its lock file aside: it says who held it)."""
    total = hashlib.sha256()
    for path in sorted(p for p in root.rglob("*") if p.is_file() and p.name != ".lock"):
        total.update(path.relative_to(root).as_posix().encode() + b"\0" + path.read_bytes())
    return total.hexdigest()


@pytest.fixture
def finished(smoke_finished, tmp_path):
    """A writable copy of the finished smoke workspace."""
    root = tmp_path / "w"
    shutil.copytree(smoke_finished[0].root, root)
    return root


#: per command, a setting that makes its results stale (so that it is refused without --force)
REFUSED = {
    "plan": ["--set", "plan.n_dataset=9"],
    "acquire": ["--set", "virtual.seed=99"],
    "calibrate": ["--set", "calibrate.folds=3"],
    "fuse": ["--set", "fuse.rejection_k=2.5"],
    "label": ["--set", "label.filename_template=x{sample_id}.jpg"],
    "render": ["--set", "render.spp=3"],
    "evaluate": ["--set", "evaluate.batch_size=3"],
    "run": ["--set", "plan.n_dataset=9"],
}


@pytest.mark.parametrize("command", [*sorted(REFUSED), "export"])
def test_a_refused_command_leaves_every_byte_as_it_was(finished, command, tmp_path):
    before = digest(finished)
    if command == "export":  # refused inside the stage, after its old results were set aside
        (tmp_path / "thesis").mkdir()
        (tmp_path / "thesis" / "chapter1.tex").write_text("mine")
        args = ["--format", "bop", "--out", str(tmp_path / "thesis")]
    else:
        args = REFUSED[command]
    result = speedplus(command, "--workspace", str(finished), *args)
    assert result.returncode == 1, result.stdout + result.stderr
    assert "--force" in result.stderr
    # what the message sends the user to exists; export's names the folder it would make instead
    assert command == "export" or not missing_named(result.stderr, finished), result.stderr
    assert digest(finished) == before
    if command in ("plan", "fuse", "label"):  # the command it suggests clears it (run: a few seconds each)
        said = " ".join(result.stderr.split())
        suggested = said[said.index("(`speedplus ") + 2:]
        suggested = suggested[: suggested.index("`")].split()
        cleared = speedplus(*suggested[1:], *args)
        assert cleared.returncode == 0, cleared.stderr
        assert speedplus(command, "--workspace", str(finished), *args).returncode == 0  # up to date now


def test_a_stage_that_fails_puts_back_what_force_discarded(finished):
    before = digest(finished)
    # absurdly tight limits: the solve runs, then the result is refused after --force cleared the old one
    result = speedplus("calibrate", "--workspace", str(finished), "--force", "--set",
                       "calibrate.max_rotation_error_rad=1e-9")
    assert result.returncode == 1 and "calibration refused" in result.stderr
    said = " ".join(result.stderr.split())
    assert not missing_named(said, finished) and "calibration_samples manifest still holds the results" in said, said
    assert digest(finished) == before
    assert speedplus("status", "--workspace", str(finished)).stdout.count("done") >= 8


def test_config_file_and_set_layer_on_the_saved_configuration(finished, tmp_path):
    tweak = tmp_path / "tweak.toml"
    tweak.write_text("[render]\nspp = 32\n")
    refused = speedplus("render", "--workspace", str(finished), "--config", str(tweak))
    # the smoke workspace stays smoke: only render.spp differs, and the refusal names it
    assert refused.returncode == 1 and "render.spp 64 -> 32" in " ".join(refused.stderr.split())
    status = speedplus("status", "--workspace", str(finished), "--config", str(tweak))
    line = next(line for line in status.stdout.splitlines() if line.startswith("│ render"))
    assert "stale" in line and "render.spp 64 -> 32" in line
    assert all(state in status.stdout for state in ("plan", "done"))
    done = speedplus("render", "--workspace", str(finished), "--config", str(tweak), "--force")
    assert done.returncode == 0, done.stderr
    saved = tomllib.loads((finished / "config.toml").read_text())
    assert saved["profile"] == "smoke" and saved["render"]["spp"] == 32 and saved["camera"]["width_px"] == 320


def test_switching_profile_is_explicit_and_names_the_stages_to_redo(finished, tmp_path):
    before = digest(finished)
    other = tmp_path / "other.toml"
    other.write_text('profile = "default"\n')
    named = speedplus("plan", "--workspace", str(finished), "--config", str(other))
    assert named.returncode == 1 and "--profile default" in " ".join(named.stderr.split())
    switched = speedplus("plan", "--workspace", str(finished), "--profile", "default")
    said = " ".join(switched.stdout.split())
    assert switched.returncode == 1
    assert "profile smoke -> default: stages to redo: plan (camera.height_px 200 -> 600" in said
    assert "acquire (its input plan is redone by plan)" in said and "evaluate (its input labels" in said
    assert digest(finished) == before


def test_status_and_verify_refuse_a_missing_workspace(tmp_path):
    for command in ("status", "verify"):
        result = speedplus(command, "--workspace", str(tmp_path / "nowhere"))
        assert result.returncode == 1 and "nowhere: no such workspace" in result.stderr
    assert not (tmp_path / "nowhere").exists()


def test_an_export_of_a_training_set_not_rendered_gives_the_command_that_renders_it(finished):
    result = speedplus("export", "--workspace", str(finished), "--set", 'export.sets=["train"]')
    said = " ".join(result.stderr.split())
    assert result.returncode == 1 and f"make it first: `speedplus render --set train -w {finished}`" in said, said


def test_a_refused_command_on_a_new_folder_leaves_no_folder(tmp_path):
    result = speedplus("calibrate", "--workspace", str(tmp_path / "new"))
    assert result.returncode == 1 and "needs the complete manifest" in " ".join(result.stderr.split())
    assert not (tmp_path / "new").exists()


def fixed_batch_copy(source, destination, batch):
    """The model with its batch axis fixed to ``batch`` (torch.onnx.export without dynamic axes)."""
    import onnx

    model = onnx.load(source)
    for value in [*model.graph.input, *model.graph.output]:
        dim = value.type.tensor_type.shape.dim[0]
        dim.Clear()
        dim.dim_value = batch
    onnx.save(model, destination)


def test_a_model_is_added_beside_the_others_and_redone_alone(finished, tmp_path):
    missing = speedplus("evaluate", "--workspace", str(finished), "--model", str(tmp_path / "mine.onnx"), "--force")
    assert missing.returncode == 1 and "mine.onnx: model file not found" in missing.stderr
    before = read_manifest(Workspace(finished), "predictions").to_pylist()
    broken = tmp_path / "broken.onnx"
    broken.write_bytes(b"not a model")
    bad = speedplus("evaluate", "--workspace", str(finished), "--model", str(broken))
    assert bad.returncode == 1 and "broken.onnx: not a loadable ONNX model" in bad.stderr
    mine = tmp_path / "mine.onnx"
    fixed_batch_copy(os.path.join(REPOSITORY, "models", "reference.onnx"), mine, 1)
    # scored by two spawned workers, against the shipped model's predictions made in one process
    added = speedplus("evaluate", "--workspace", str(finished), "--model", str(mine), "--workers", "2")
    assert added.returncode == 0, added.stderr
    assert "Table 2: mine (" in added.stdout and "Table 2: reference_augmented (" in added.stdout
    after = read_manifest(Workspace(finished), "predictions").to_pylist()
    kept = [row for row in after if row["model"] != "mine"]
    strip = lambda rows: sorted((r["prediction_id"], r["q_pred"], r["t_pred"]) for r in rows)  # noqa: E731
    assert strip(kept) == strip(before)  # the shipped models' predictions are untouched
    ours = {(r["crop"], r["domain"], r["sample_id"]): r["score_speed"] for r in after if r["model"] == "mine"}
    theirs = {(r["crop"], r["domain"], r["sample_id"]): r["score_speed"] for r in after if r["model"] == "reference"}
    assert ours.keys() == theirs.keys()  # fed one image at a time, the same weights score the same
    np.testing.assert_allclose([ours[k] for k in ours], [theirs[k] for k in ours], atol=1e-6)
    models = set(read_manifest(Workspace(finished), "scores").column("model").to_pylist())
    assert models == {"reference", "reference_augmented", "mine"}
    assert "up to date" in speedplus("evaluate", "--workspace", str(finished)).stdout
    redone = speedplus("evaluate", "--workspace", str(finished), "--model", str(mine), "--force")
    assert redone.returncode == 0, redone.stderr
    again = read_manifest(Workspace(finished), "predictions").to_pylist()
    assert strip([r for r in again if r["model"] != "mine"]) == strip(before)


def interrupt_when(ready, *args, timeout=300, env=None):
    """Run the CLI in its own process group and press Ctrl-C once ``ready()`` holds; ``env``:
    more variables (a fault of tests/faults/sitecustomize.py)."""
    import time

    env = {**os.environ, "COLUMNS": "200", **(env or {})}
    if any(name.startswith("SPEEDPLUS_FAULT_") for name in env):
        env["PYTHONPATH"] = os.pathsep.join(p for p in (str(Path(__file__).resolve().parents[1] / "faults"),
                                                        env.get("PYTHONPATH", "")) if p)
    process = subprocess.Popen([sys.executable, "-m", "pipeline.cli", *args], stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True, start_new_session=True, env=env,
                               preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.monotonic() + timeout
    while process.poll() is None and not ready() and time.monotonic() < deadline:
        time.sleep(0.1)
    if process.poll() is None:
        os.killpg(process.pid, signal.SIGINT)
    out, err = process.communicate(timeout=120)
    return process.returncode, out, err


def test_ctrl_c_says_what_it_kept_in_one_line_and_the_same_command_resumes(tmp_path):
    ws = tmp_path / "w"
    assert speedplus("plan", "--profile", "smoke", "--workspace", str(ws)).returncode == 0
    # with two spawned workers, which ignore the Ctrl-C and are stopped by the driver (the smoke
    # profile's own one process is interrupted in test_object_storage.py); each capture half a
    # second slower while the file is there, so that the press falls between the first and the last
    slow = tmp_path / "slow"
    slow.touch()
    code, _, err = interrupt_when(lambda: len(list((ws / "images").rglob("*.png"))) >= 2, "acquire", "--workspace",
                                  str(ws), "--workers", "2", env={"SPEEDPLUS_FAULT_SLOW_CAPTURE_WHILE": str(slow)})
    slow.unlink()
    assert code == 130, err
    lines = [line for line in err.splitlines() if line.startswith("interrupted")]
    assert len(lines) == 1 and lines[0].endswith("of 24 rows kept (acquire); run the same command to resume")
    kept = int(lines[0].split()[1])
    assert 0 < kept < 24
    assert "Traceback" not in err and "winding down" not in err
    resumed = speedplus("acquire", "--workspace", str(ws))
    assert resumed.returncode == 0 and "acquire: resumed" in resumed.stdout


def test_run_after_a_stages_force_redoes_what_depends_on_it_and_says_so(finished):
    """Issue 42: after `render --force` (here with another spp), `run` stopped at evaluate,
    then at report."""
    assert speedplus("render", "--workspace", str(finished), "--force", "--set", "render.spp=3").returncode == 0
    alone = speedplus("evaluate", "--workspace", str(finished))
    said = " ".join(alone.stderr.split())
    assert alone.returncode == 1 and f"`speedplus evaluate -w {finished} --force`" in said, said
    result = speedplus("run", "--workspace", str(finished))
    assert result.returncode == 0, result.stderr
    out = " ".join((result.stdout + result.stderr).split())
    assert "evaluate: its input renders was redone; redoing it" in out
    assert "evaluate: ran in" in out and "report: ran in" in out
    again = speedplus("run", "--workspace", str(finished))
    assert again.returncode == 0 and "report: up to date" in again.stdout and "redoing" not in again.stdout


def test_the_report_is_a_view_made_anew_without_force(finished):
    redone = speedplus("evaluate", "--workspace", str(finished), "--force", "--set", "evaluate.batch_size=3")
    assert redone.returncode == 0, redone.stderr
    result = speedplus("report", "--workspace", str(finished))
    assert result.returncode == 0, result.stderr
    assert "report: ran in" in result.stdout


def test_a_file_given_as_the_workspace_is_named(tmp_path):
    file = tmp_path / "notes.txt"
    file.write_text("mine")
    for command in ("run", "status"):
        result = speedplus(command, "--workspace", str(file))
        said = " ".join(result.stderr.split())
        assert result.returncode == 1 and f"{file}: --workspace names a file" in said and "bug" not in said, said
    assert file.read_text() == "mine"


def test_a_chain_that_fails_late_keeps_the_stages_it_completed(tmp_path):
    """Issue 58: a refusal at calibrate does not throw away the plan and the captures. The
    refused stage puts back its own work, the error's last line says what was kept, and the
    same command, fixed, resumes: plan and acquire are up to date."""
    root = tmp_path / "new"
    args = ("run", "--workspace", str(root), "--profile", "smoke", "--until", "calibrate")
    refused = speedplus(*args, "--set", "calibrate.max_rotation_error_rad=1e-9")
    assert refused.returncode == 1 and "calibration refused" in refused.stderr
    assert f"{root}: a new workspace, profile smoke" in " ".join(refused.stdout.split())  # said, not silent
    said = " ".join(refused.stderr.split())
    assert "pose file" not in said and "plan more of them (plan.n_calibration)" in said, said  # a virtual run's advice
    last = said[said.index("calibration refused"):]
    assert "kept: plan, acquire (completed;" in last and f"speedplus status -w {root}" in last, last
    assert said.endswith("run the same command to resume from the stage that failed")
    assert not missing_named(said, root), said
    status = " ".join(speedplus("status", "--workspace", str(root)).stdout.split())
    assert "│ plan │ done" in status and "│ acquire │ done" in status and "│ calibrate │ partial" in status, status
    assert f"kept: plan, acquire; `speedplus run -w {root}` goes on from calibrate" in status
    # the manifest the refusal sends the user to exists after it, with every image's reason
    assert "every image's reason is in the calibration_samples manifest" in said
    reasons = read_manifest(Workspace(root), "calibration_samples").to_pylist()
    assert len(reasons) == 16 and all("reason" in row for row in reasons)
    captured = sorted(p.name for p in (root / "images").rglob("*.png"))
    assert len(captured) == 24 and not (root / "calibration.json").exists()
    fixed = ("--set", "calibrate.max_rotation_error_rad=0.08726646259971647")
    status = " ".join(speedplus("status", "--workspace", str(root), *fixed).stdout.split())
    assert "the diagnostics of its last refusal" in status, status
    resumed = speedplus(*args, *fixed)
    assert resumed.returncode == 0, resumed.stderr
    said = " ".join(resumed.stdout.split())
    assert "plan: up to date" in said and "acquire: up to date" in said and "calibrate: ran" in said


def test_what_can_be_refused_is_refused_before_the_first_stage(tmp_path):
    """Issue 58: a mistyped model path and a plan too short for calibrate end the command
    in seconds, before the plan, naming the key; `run --check` says what would run and
    writes nothing; a new folder is not left behind."""
    root = tmp_path / "new"
    model = speedplus("run", "--workspace", str(root), "--profile", "smoke", "--set", 'evaluate.models=["bad.onnx"]')
    assert model.returncode == 1 and "bad.onnx: model file not found" in " ".join(model.stderr.split())
    count = speedplus("run", "--workspace", str(root), "--profile", "smoke", "--until", "calibrate",
                      "--set", "plan.n_calibration=7")
    said = " ".join(count.stderr.split())
    assert count.returncode == 1 and "plan.n_calibration = 7: calibrate needs at least 8" in said, said
    assert not root.exists()
    check = speedplus("run", "--workspace", str(root), "--profile", "smoke", "--check")
    table = " ".join(check.stdout.split())
    assert check.returncode == 0 and "│ plan │ missing: not run │ run │" in table and "checks passed" in table, table
    assert not root.exists()
    refused = speedplus("run", "--workspace", str(root), "--profile", "smoke", "--check", "--set",
                        "plan.n_calibration=7")
    assert refused.returncode == 1 and "plan.n_calibration = 7" in " ".join(refused.stderr.split())
    disk = speedplus("run", "--workspace", str(root), "--profile", "paper", "--set", "plan.n_dataset=10000000")
    said = " ".join(disk.stderr.split())
    assert disk.returncode == 1 and "10000064 captures of 1920 x 1200 px need about" in said and "GB free" in said
    assert not root.exists()


def test_check_says_which_stages_are_up_to_date(finished):
    before = digest(finished)
    check = speedplus("run", "--workspace", str(finished), "--check", "--set", "fuse.rejection_k=2.5")
    table = " ".join(check.stdout.split())
    assert check.returncode == 0, check.stderr
    assert "│ calibrate │ done │ skip: up to date │" in table
    assert "│ fuse │ stale: fuse.rejection_k" in table and "refuse:" in table and "(--force redoes it)" in table
    assert digest(finished) == before


def _parts(root, name):
    """Each part of a manifest, by name, with its bytes' hash."""
    folder = root / "manifests" / name
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.glob("*.parquet"))}


#: columns that measure this run (wall time), not what it made
VOLATILE = ("seconds", "train_seconds")


def _same_results(got, want, name):
    """A manifest equal to a reference run's: byte for byte, or, where it records wall time,
    equal but for that column; and the files its rows name, byte for byte."""
    a, b = (pq.read_table(root / "manifests" / name) for root in (got, want))
    volatile = [c for c in VOLATILE if c in a.column_names]
    assert a.drop_columns(volatile).equals(b.drop_columns(volatile)), name
    if not volatile:
        assert _parts(got, name) == _parts(want, name), name
    for column in (c for c in a.column_names if c.endswith("_path")):
        for relpath in a.column(column).to_pylist():
            if relpath:
                assert (got / relpath).read_bytes() == (want / relpath).read_bytes(), relpath


def _unnamed(root):
    """Media files of the workspace that no manifest row names: what a failed stage left."""
    named = set()
    for folder in (root / "manifests").iterdir():
        if folder.name != "_state" and any(folder.glob("*.parquet")):
            table = pq.read_table(folder)
            for column in (c for c in table.column_names if c.endswith("_path")):
                named.update(table.column(column).to_pylist())
    media = {p.relative_to(root).as_posix() for p in root.rglob("*")
             if p.is_file() and p.suffix in (".png", ".exr", ".tif", ".onnx")
             and p.relative_to(root).parts[0] not in ("report", "target")}
    return sorted(media - named)


def _outputs(stage):
    from pipeline import registry
    from pipeline.config import load_config

    return registry.stage(stage).resolved(load_config("smoke"), Workspace(REPOSITORY)).outputs


def test_a_chain_failing_at_each_stage_keeps_every_stage_before_it_byte_for_byte(smoke_finished, tmp_path):
    """Issue 58: the chain fails at each stage in turn, once the stage has written all it
    writes (fault injection); the stages before it are kept, equal to an uninterrupted run's
    (same seed, same bytes) and intact, the failing stage's rows and files are put back, and
    the same command resumes from it. At render, the engine is lost instead: the twins it
    finished are kept and resumed."""
    from pipeline import registry

    reference = smoke_finished[0].root
    root = tmp_path / "new"
    chain = list(registry.CHAIN)
    for index, failing in enumerate(chain):
        args = ("run", "--workspace", str(root), "--profile", "smoke", "--until", failing)
        kept_rows = 0
        if failing == "render":  # its engine lost: the twins it finished are kept for resume
            lost = speedplus(*args, env={"SPEEDPLUS_FAULT_ENGINE_LOST_AFTER": "3"})
            said = " ".join(lost.stderr.split())
            assert lost.returncode == 1 and "kept: 3 finished rows of render (the engine failed" in said, said
            assert not missing_named(said, root), said
            assert "kept: plan, acquire, calibrate, fuse, label (completed;" in said
            kept_rows = 3
        failed = speedplus(*args, env={"SPEEDPLUS_FAULT_FAIL_STAGE": failing})
        said = " ".join(failed.stderr.split())
        assert failed.returncode == 1 and f"injected fault: stage {failing} failed" in said, said
        assert "Traceback" not in said
        if index == 0:
            assert not root.exists()  # nothing completed: no folder left behind
            continue
        assert f"kept: {', '.join(chain[:index])} (completed;" in said and not missing_named(said, root), said
        for stage in chain[:index]:
            for name in _outputs(stage):
                _same_results(root, reference, name)
        for name in _outputs(failing):  # its own work put back: the rows it found, no marker
            rows = pq.read_table(root / "manifests" / name).num_rows if _parts(root, name) else 0
            assert rows == kept_rows and not (root / "manifests" / "_state" / f"{name}.json").exists(), name
        assert not (root / "report").exists() and not _unnamed(root), _unnamed(root)[:5]
        verified = speedplus("verify", "--workspace", str(root))
        assert verified.returncode == 0 and "intact" in verified.stdout, verified.stdout + verified.stderr
    resumed = speedplus("run", "--workspace", str(root))
    assert resumed.returncode == 0, resumed.stderr
    said = " ".join(resumed.stdout.split())
    assert "evaluate: up to date" in said and "report: ran" in said, said
    for stage in chain[:-1]:
        for name in _outputs(stage):
            _same_results(root, reference, name)
    assert (root / "report" / "index.html").is_file()


def test_a_target_without_a_model_is_refused_first_with_a_command_that_trains_for_it(tmp_path):
    """Issue 58: the chain is refused before the plan, and the training command it gives
    names the same target (the refused workspace saved none)."""
    root, target = tmp_path / "new", os.path.join(REPOSITORY, "examples", "targets", "cubesat3u")
    refused = speedplus("run", "--workspace", str(root), "--profile", "smoke", "--target", target)
    said = " ".join(refused.stderr.split())
    assert refused.returncode == 1 and "holds no model" in said and not root.exists(), said
    command = said[said.index("`speedplus train-reference") + 1:]
    command = command[: command.index("`")]
    assert command == f"speedplus train-reference -w {root} --set target.path={target}", command
    assert "with this command's --profile" in said


def test_a_moved_workspace_exports_again_into_its_own_export_folder(finished, tmp_path):
    """The refusal of a foreign export folder says to leave --out out: the workspace's own
    folder stays its own when the workspace is moved (issue 58, part 3)."""
    assert speedplus("export", "--workspace", str(finished)).returncode == 0
    moved = tmp_path / "moved"
    finished.rename(moved)
    again = speedplus("export", "--workspace", str(moved), "--force")
    assert again.returncode == 0, again.stderr
    mark = json.loads((moved / "export" / "speedplus" / ".speedplus-export.json").read_text())
    assert mark["workspace"] == str(moved)


def test_run_rescores_after_models_are_trained_in_the_workspace(finished):
    """Issue 59: models and a detector that train-reference made in W/models/ are this
    workspace's own work, as a redone input is: after they are trained again, `speedplus run`
    rescores with them, saying so, where it used to refuse until `evaluate --force`."""
    recipe = ("--set", "reference.images=6", "--set", 'reference.variants=["plain", "detector"]')
    for steps in (1, 2):
        trained = speedplus("train-reference", "--workspace", str(finished), *recipe, "--set",
                            f"reference.max_steps={steps}", *(("--force",) if steps > 1 else ()))
        assert trained.returncode == 0, trained.stderr
        result = speedplus("run", "--workspace", str(finished))
        said = " ".join((result.stdout + result.stderr).split())
        assert result.returncode == 0, result.stderr
        assert "evaluate: ran" in said, said
    assert "evaluate: detector retrained in this workspace" in said, said
    scored = {row["model"] for row in read_manifest(Workspace(finished), "scores").to_pylist()}
    assert "reference" in scored, scored
    again = speedplus("run", "--workspace", str(finished))
    assert again.returncode == 0 and "evaluate: up to date" in again.stdout, again.stdout + again.stderr
