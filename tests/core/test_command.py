"""A stage's own command options (core/command.py, stages/<name>/cli.py): what they ask of
a run, and the help they show, read from the configuration key they set."""

from __future__ import annotations

from pathlib import Path

import pytest

from core.command import Request, absolute, key_help
from core.config import Override, RunConfig
from pipeline import registry
from stages.render.config import RenderConfig


def test_an_options_help_is_its_keys_help_unit_and_name():
    assert key_help(RenderConfig, "train_count").endswith("[count] (render.train_count)")
    assert key_help(RunConfig, "workers").endswith("(run.workers)")
    with pytest.raises(KeyError, match="no key 'nope'"):
        key_help(RenderConfig, "nope")


def test_a_folder_option_is_saved_absolute(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (override,) = absolute("acquire.source", Path("rec"), "--source")
    assert override == Override("acquire", "source", str(tmp_path / "rec"), "--source")
    assert absolute("acquire.source", None, "--source") == ()


def test_a_request_merged_keeps_the_order_of_its_overrides():
    first = Override.of("render.spp", 8, "--set")
    second = Override.of("render.spp", 16, "--later")
    merged = Request(saved=(first,), stages=("render",)).merged(Request(saved=(second,), notes=("n",)))
    assert merged.saved == (first, second) and merged.stages == ("render",) and merged.notes == ("n",)
    assert merged.then is None


def test_render_splits_its_set_into_the_image_set_and_saved_keys():
    options = registry.stage("render").options()
    request = options(set_=["train", "render.spp=4"], count=12)
    assert [(o.key, o.value) for o in request.transient] == [("set", "train")]
    assert [(o.section, o.key, o.value) for o in request.saved] == [("render", "spp", 4),
                                                                      ("render", "train_count", 12)]


def test_only_stages_with_options_of_their_own_have_a_cli_module():
    with_options = {entry.name for entry in registry.STAGES if entry.options() is not None}
    assert with_options == {"plan", "acquire", "render", "evaluate", "export", "train-reference"}
    export = registry.stage("export").options()(format_="bop", out_dir=None)
    assert [(o.key, o.value) for o in export.transient] == [("format", "bop")] and export.saved == ()
