"""The stage registry is the one place a stage is declared: every entry names things that
exist (its function, its manifests, its configuration sections), for every configuration
that changes them, and the CLI has a command for each."""

import inspect
import re
from dataclasses import fields
from pathlib import Path

from typer.testing import CliRunner

from manifests import MANIFESTS, Workspace
from pipeline import registry
from pipeline.cli import app
from pipeline.config import SECTION_TYPES, load_config

TABB = Path(__file__).resolve().parents[3] / "shared" / "external" / "tabb_ds1"
MARKERS = {"report"}  # completion markers without Parquet parts

CONFIGS = {
    "default": [],
    "replay": ["acquire.backend=replay", "acquire.format=tabb", f"acquire.source='{TABB}'"],
    "train set": ["render.set=train"],
    "bop": ["export.format=bop"],
    "sequences": ["plan.mode=trajectory", "export.format=shirt"],
    "export all sets": ['export.sets=["testbed", "twins", "train"]'],
    "robot programs": ["export.format=robot"],
    "logger's session": ["export.format=session"],
    "ROS 2 bag": ["export.format=rosbag", "acquire.backend=replay", "acquire.format=rosbag",
                  "acquire.source='/nowhere/bag'"],
}


def test_every_entry_names_existing_manifests_and_sections(tmp_path):
    produced, needed = set(), set()
    for overrides in CONFIGS.values():
        config = load_config("smoke", overrides=overrides)
        for entry in registry.STAGES:
            resolved = entry.resolved(config, Workspace(tmp_path))
            assert set(resolved.inputs) <= set(MANIFESTS), entry.name
            assert set(resolved.outputs) <= set(MANIFESTS) | MARKERS and resolved.outputs, entry.name
            for name in resolved.sections:  # a section, or one key of it
                section, _, key = name.partition(".")
                assert section in SECTION_TYPES, (entry.name, name)
                assert not key or key in {f.name for f in fields(SECTION_TYPES[section])}, (entry.name, name)
            produced |= set(resolved.outputs)
            needed |= set(resolved.inputs)
    assert needed <= produced  # every input is some stage's output under some configuration
    assert set(MANIFESTS) <= produced  # and every manifest has a stage that writes it


def test_every_entry_runs_with_config_and_workspace_only():
    for entry in registry.STAGES:
        assert list(inspect.signature(entry.function()).parameters) == ["config", "workspace"], entry.name


def test_the_cli_has_a_command_per_stage_and_no_unbuilt_path():
    commands = {command.name for command in app.registered_commands}
    assert set(registry.STAGE_NAMES) | {"run", "status", "verify", "target", "facility", "keys", "view"} == commands
    assert registry.CHAIN == ("plan", "acquire", "calibrate", "fuse", "label", "render", "evaluate", "report")
    result = CliRunner().invoke(app, ["export", "--help"])
    help_text = " ".join(result.output.replace("│", " ").split())
    assert "the layout the Stanford SPEED+ devkits read" in help_text and "(export.format)" in help_text


def test_what_a_stage_resolves_is_what_the_design_record_says(tmp_path):
    """A stage's own resolve is the one truth of what it reads and writes; docs/architecture.md
    section 1's table names the same manifests (over every configuration above)."""
    table = {}
    text = (Path(__file__).resolve().parents[2] / "docs" / "architecture.md").read_text()
    for line in text.split("## 1.")[1].split("## 2.")[0].splitlines():
        cells = [c.strip() for c in line.split("|")[1:-1]]
        if len(cells) == 3 and cells[0] in registry.STAGE_NAMES:
            named = [set(re.findall(r"`([a-z_]+)`", cell)) & (set(MANIFESTS) | MARKERS) for cell in cells[1:]]
            table[cells[0]] = tuple(named)
    assert set(table) == set(registry.STAGE_NAMES)
    for entry in registry.STAGES:
        reads, writes = set(), set()
        for overrides in CONFIGS.values():
            resolved = entry.resolved(load_config("smoke", overrides=overrides), Workspace(tmp_path))
            reads |= set(resolved.inputs)
            writes |= set(resolved.outputs)
        assert (reads, writes) == table[entry.name], entry.name


def test_every_hook_an_entry_declares_is_in_its_package():
    """A flag of a StageEntry promises a function of its package: preflight, status_views,
    skipped_in_chain; and a package has none that its entry does not declare."""
    import importlib

    hooks = {"preflight": "preflight", "views": "status_views", "may_skip": "skipped_in_chain"}
    for entry in registry.STAGES:
        package = importlib.import_module(f"{entry.package}.stage")
        for flag, function in hooks.items():
            assert getattr(entry, flag) == callable(getattr(package, function, None)), (entry.name, function)
