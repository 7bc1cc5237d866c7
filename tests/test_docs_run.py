"""The docs are tests (issue 59): every fenced block of README.md and docs/*.md says what
it is (``tests/docs_blocks.py``), the command summaries name commands and options that
exist, the blocks that need a cluster, a bucket or hours name the tests that run them, and
the walk runs every other command and Python block as written, in order, on the smoke
profile, in a sandbox with the repository's layout."""

import os
import re
import shlex
import subprocess
import sys
from functools import cache
from pathlib import Path

import pytest
from typer.testing import CliRunner

from pipeline.cli import app
from tests.docs_blocks import KINDS, OWN_FOLDER, ROOT, Block, all_blocks, filled, own_folders, run_blocks, walks

#: what the walk changes in a documented command, and only this: every profile is the smoke
#: profile (seconds per stage; a command that names none gets it), and a placeholder stands
#: for the shipped example the block names
PROFILE = re.compile(r"(?<!\S)(-p|--profile)\s+\w+")


def test_every_block_says_what_it_is():
    found = all_blocks()
    assert len(found) >= 20  # the parser still finds them
    assert [b.where for b in found if b.kind not in KINDS] == []


def test_a_block_covered_elsewhere_names_tests_that_exist():
    for block in (b for b in all_blocks() if b.kind == "covered-by"):
        assert block.arguments, block.where
        for cited in block.arguments:
            path, _, name = cited.partition("::")
            text = (ROOT / path).read_text()
            if name:
                assert f"def {name}(" in text, (block.where, cited)
            else:  # a script that runs the block's commands itself (.ci/run: make dataset, make test)
                assert all(command.split(" ")[:2] == ["make", "dataset"] and "make dataset" in text
                           or command in text for command in block.commands()), (block.where, cited)


@cache
def _help(command: str) -> str:
    result = CliRunner().invoke(app, [command, "--help"], env={"COLUMNS": "200"})
    assert result.exit_code == 0, (command, result.output)
    return result.output


def test_every_command_summary_names_commands_and_options_that_exist():
    for block in (b for b in all_blocks() if b.kind in ("synopsis", "run", "covered-by")):
        for line in block.text.splitlines():
            words = line.split("#")[0].replace("[", " ").replace("]", " ").split()
            if words[:1] != ["speedplus"]:
                continue
            first_option = next((i for i, w in enumerate(words) if w.startswith("-")), len(words))
            # the command, and the alternatives a summary gives it (plan | acquire | ...); not its arguments
            commands = [words[1], *(words[i + 1] for i in range(1, first_option - 1) if words[i] == "|")]
            options = {w.split("=")[0] for w in words if re.fullmatch(r"--?[a-z][\w-]*(=.*)?", w)}
            for command in commands:
                shown = _help(command)
                assert [o for o in options if o not in shown] == [], (block.where, command, line)


def _sandbox(root: Path) -> Path:
    """A folder laid out as the repository (its tracked entries linked) with its own, empty
    ``data/`` and ``../shared`` beside it: what the docs write stays here."""
    repository = root / "speedplus-builder"
    repository.mkdir()
    for entry in ROOT.iterdir():
        if entry.name not in ("data", "exports", ".git"):
            (repository / entry.name).symlink_to(entry)
    (repository / "data").mkdir()
    (root / "shared").symlink_to((ROOT.parent / "shared").resolve())
    return repository


def _shell(block: Block, command: str, cwd: Path) -> None:
    line = PROFILE.sub(lambda m: f"{m.group(1)} smoke", command)
    words = shlex.split(line)
    if not PROFILE.search(line) and len(words) > 1 and "--profile" in _help(words[1]):
        line += " --profile smoke"  # a new workspace takes the default profile: the walk's is smoke
    for name, value in block.placeholders.items():
        line = re.sub(rf"(?<![\w/]){name}(?![\w/])", value, line)
    assert shlex.split(line)[0] == "speedplus", f"{block.where}: {line}: only speedplus commands run in the walk"
    env = {**os.environ, "COLUMNS": "100", "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}"}
    result = subprocess.run(line, shell=True, cwd=cwd, env=env, capture_output=True, text=True, timeout=1200)
    said = result.stdout[-1500:] + result.stderr[-3000:]
    assert result.returncode == 0, f"{block.where}: `{line}` exited {result.returncode}:\n{said}"
    assert "Traceback" not in result.stderr, f"{block.where}: `{line}`:\n{said}"


@pytest.mark.skipif(not (ROOT.parent / "shared" / "external").is_dir(), reason="the docs cite ../shared/external")
def test_the_docs_run_as_written(tmp_path):
    """Every run block that reaches the guide's workspace (``docs_blocks.walks``), in reading
    order; then every Python block on the workspaces and exports they made. The other blocks
    walk in tests/test_docs_walk_apart.py."""
    cwd = _sandbox(tmp_path)
    ran = walk(walks()[0], cwd)
    assert len(ran) >= 15
    for block in (b for b in all_blocks() if b.kind == "python"):
        script = tmp_path / "block.py"
        script.write_text(block.text)
        result = subprocess.run([sys.executable, str(script)], cwd=cwd, capture_output=True, text=True, timeout=600,
                                env={**os.environ, "PYTHONPATH": str(ROOT)})
        assert result.returncode == 0, f"{block.where}:\n{result.stderr[-3000:]}"


def walk(found: list[Block], cwd: Path) -> list[str]:
    """Run the blocks' commands in order in the sandbox ``cwd``; the commands run."""
    ran = []
    for block in found:
        for command in block.commands():
            _shell(block, command, cwd)
            ran.append(command)
    return ran


def test_the_two_walks_hold_every_run_block_once_and_share_no_folder():
    first, second = walks()
    assert sorted(b.where for b in first + second) == sorted(b.where for b in run_blocks())
    assert first and second and not {b.where for b in first} & {b.where for b in second}

    def folders(found: list[Block]) -> set[str]:
        return {f for b in found for f in own_folders(b)}

    assert "data/default" in folders(first) and not folders(first) & folders(second)
    # a command on a workspace names it: none takes one by default, unseen by the split
    for block in first + second:
        for command in filled(block):
            words = shlex.split(command)
            if len(words) > 1 and "--workspace" in _help(words[1]):
                assert OWN_FOLDER.search(command), f"{block.where}: `{command}` names no folder of the walk's"


def test_the_shipped_example_target_is_the_one_its_code_writes(tmp_path):
    """The guide's example (examples/targets/cubesat3u) is what ``bench.targets.cubesat3u``
    makes, byte for byte: written once, in code."""
    from bench.targets import cubesat3u

    made = cubesat3u(tmp_path / "cubesat3u")
    shipped = ROOT / "examples" / "targets" / "cubesat3u"
    assert sorted(p.name for p in shipped.iterdir()) == sorted(p.name for p in made.iterdir())
    for path in made.iterdir():
        assert (shipped / path.name).read_bytes() == path.read_bytes(), path.name
