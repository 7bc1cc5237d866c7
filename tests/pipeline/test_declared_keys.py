"""A stage's fingerprint holds exactly the configuration keys its code reads (issue 45):
read and not declared, a change would leave stale results looking done; declared and not
read, a change would redo work for nothing. The reads are found in the source
(tests/pipeline/config_reads.py); the declarations are each stage's ``resolve`` under the
configurations that change what it declares."""

from __future__ import annotations

from pathlib import Path

import pytest

from core.config import Config, parse_override, with_overrides
from pipeline.config import load_config
from pipeline.registry import STAGES
from tests.pipeline.config_reads import WHOLE, package_reads

#: never part of a result: how stages execute (``run``), and the target folder, whose digest
#: (not its configuration key) is in every fingerprint
NOT_RESULTS = {"run", "target"}
VARIANTS = ((), ("plan.mode=trajectory",), ("acquire.backend=replay", "acquire.source=somewhere"),
            ("render.set=train",), ("export.sets=[\"testbed\",\"twins\",\"train\"]",), ("export.format=robot",),
            ("export.format=session",),
            (f'facility.path="{Path(__file__).resolve().parents[1] / "facilities" / "ur10_tripod"}"',))


def _config(overrides: tuple[str, ...]) -> Config:
    return with_overrides(load_config("smoke"), [parse_override(text) for text in overrides])


def declared(stage_name: str) -> set[tuple[str, str]]:
    """(section, key) pairs the stage declares under any variant (key ``*``: the section)."""
    stage = next(entry for entry in STAGES if entry.name == stage_name)
    out: set[tuple[str, str]] = set()
    for overrides in VARIANTS:
        resolved = stage.resolved(_config(overrides), None)
        for name in resolved.sections:
            section, _, key = name.partition(".")
            out.add((section, key or WHOLE))
        if "profile" in resolved.extra:
            out.add(("profile", WHOLE))
    return out


@pytest.mark.parametrize("stage_name", [entry.name for entry in STAGES])
def test_a_stage_declares_what_it_reads_and_reads_what_it_declares(stage_name: str) -> None:
    stage = next(entry for entry in STAGES if entry.name == stage_name)
    reads = {(section, key) for section, key in package_reads(stage.package) if section not in NOT_RESULTS}
    claims = declared(stage_name)
    whole = {section for section, key in claims if key == WHOLE}
    undeclared = sorted(f"{s}.{k}" for s, k in reads
                        if s not in whole and (k == WHOLE or (s, k) not in claims))
    assert not undeclared, f"{stage_name} reads {undeclared} without declaring them in its resolve()"
    unread = sorted(f"{s}.{k}" for s, k in claims if k != WHOLE and (s, k) not in reads and (s, WHOLE) not in reads)
    unread += sorted(s for s in whole if not any(r == s for r, _ in reads))
    # a whole section is declared only where the code hands it on whole (or reads every key)
    narrow = sorted(s for s in whole if (s, WHOLE) not in reads
                    and {k for r, k in reads if r == s} != set(_keys(s)))
    assert not unread, f"{stage_name} declares {unread} but never reads them"
    assert not narrow, (f"{stage_name} declares the whole of {narrow} but reads only "
                        f"{sorted(f'{r}.{k}' for r, k in reads if r in narrow)}")


def _keys(section: str) -> list[str]:
    from dataclasses import fields

    from pipeline.config import SECTION_TYPES

    return [f.name for f in fields(SECTION_TYPES[section])]


def test_the_scan_sees_a_read_through_a_shared_function() -> None:
    """The scan follows ``config`` into the shared layer: the render stage's training camera
    (stages/common/cameras.py) reads the camera's intrinsics (a property: any camera key)
    and the training set's scale."""
    reads = package_reads("stages.render")
    assert ("camera", WHOLE) in reads and ("render", "train_resolution_scale") in reads
    assert ("testbed", WHOLE) not in reads
