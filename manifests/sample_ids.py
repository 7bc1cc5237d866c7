"""Sample ids, made and read in one place: ``cal000003`` is the calibration session's fourth
capture, ``img000012`` the dataset session's thirteenth (six digits, zero-padded; more
digits past a million). Recorded sessions (replay) may name their samples otherwise; these
functions are for the ids the plan and the handeye ingest make."""

from __future__ import annotations

import re

PREFIXES = {"calibration": "cal", "dataset": "img"}
#: each session's number in the random streams seeded per sample (plan, the virtual testbed)
SESSION_CODES = {"calibration": 0, "dataset": 1}
_PATTERN = re.compile(r"(cal|img)(\d{6,})")


def make(session: str, index: int) -> str:
    """The id of a session's ``index``-th sample (from 0)."""
    if index < 0:
        raise ValueError(f"sample index {index} is negative")
    return f"{PREFIXES[session]}{index:06d}"


def parse(sample_id: str) -> tuple[str, int]:
    """(session, index) of an id that ``make`` made; ValueError naming the id otherwise."""
    match = _PATTERN.fullmatch(sample_id)
    if match is None:
        raise ValueError(f"sample id {sample_id!r} is not cal or img followed by at least six digits")
    session = next(name for name, prefix in PREFIXES.items() if prefix == match.group(1))
    return session, int(match.group(2))
