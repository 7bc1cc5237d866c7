"""``DIR/rehearsal.json``: what labels the facility folder DIR can expect, as its rehearsal
on the virtual testbed measured them (``python -m bench honesty --facility DIR``,
bench/rehearsal.py; docs/architecture.md section 11), kept beside the folder as a model's
card is kept beside the model. ``speedplus facility DIR`` shows it and says when the folder
has changed since; tests hold a facility's labels to it.

Version 1 keys: ``version``; ``facility_digest`` (``manifests.facility.facility_digest`` of
the folder it was measured on); ``profile``, ``settings`` (the ``--set`` overrides),
``target`` (the target folder's name, null: Tango); ``seeds`` (the builds, ``virtual.seed``);
``labels`` and ``under_speedplus`` (how many of them met the SPEED+ thresholds),
``interval_95`` (its Wilson interval), ``mean_e_t_mm`` (the labels' mean position error
against the truth, mm), ``inside_1_96_sigma`` and ``rms_error_over_sigma`` (per camera axis
x, y, z, pooled over the builds).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from manifests.sidecars.base import Fields, read, save

REHEARSAL_FILE = "rehearsal.json"
REHEARSAL_VERSION = 1
WRITER = "python -m bench honesty --facility DIR"
AGAIN = f"rehearse the folder again ({WRITER})"


@dataclass(frozen=True)
class RehearsalRecord:
    """One rehearsal's pooled figures (see the module's docstring for each key)."""

    facility_digest: str
    profile: str
    settings: tuple[str, ...]
    target: str | None
    seeds: tuple[int, ...]
    labels: int
    under_speedplus: int
    interval_95: tuple[float, float]
    mean_e_t_mm: float
    inside_1_96_sigma: tuple[float, float, float]
    rms_error_over_sigma: tuple[float, float, float]

    @property
    def share(self) -> float:
        return self.under_speedplus / self.labels

    def to_json(self) -> dict[str, Any]:
        return {"version": REHEARSAL_VERSION, "facility_digest": self.facility_digest, "profile": self.profile,
                "settings": list(self.settings), "target": self.target, "seeds": list(self.seeds),
                "labels": self.labels, "under_speedplus": self.under_speedplus, "interval_95": list(self.interval_95),
                "mean_e_t_mm": self.mean_e_t_mm, "inside_1_96_sigma": list(self.inside_1_96_sigma),
                "rms_error_over_sigma": list(self.rms_error_over_sigma)}

    @classmethod
    def from_fields(cls, f: Fields) -> RehearsalRecord:
        f.only("version", "facility_digest", "profile", "settings", "target", "seeds", "labels", "under_speedplus",
               "interval_95", "mean_e_t_mm", "inside_1_96_sigma", "rms_error_over_sigma")
        settings, seeds = f.raw("settings"), f.raw("seeds")
        if not isinstance(settings, list) or not all(isinstance(s, str) for s in settings):
            raise f.fail("settings", "a list of SECTION.KEY=VALUE strings")
        if not isinstance(seeds, list) or not seeds or not all(isinstance(s, int) and not isinstance(s, bool)
                                                               for s in seeds):
            raise f.fail("seeds", "a list of integers")
        labels = f.integer("labels", minimum=1)
        under = f.integer("under_speedplus")
        if under > labels:
            raise f.fail("under_speedplus", f"at most labels ({labels})")
        low, high = f.vector("interval_95", 2)
        if not 0.0 <= low <= under / labels <= high <= 1.0:
            raise f.fail("interval_95", "[low, high] in [0, 1] about under_speedplus / labels")
        return cls(f.text("facility_digest"), f.text("profile"), tuple(settings),
                   f.text("target") if f.optional("target") else None, tuple(seeds), labels, under, (low, high),
                   f.number("mean_e_t_mm"), f.vector("inside_1_96_sigma", 3), f.vector("rms_error_over_sigma", 3))


def write_rehearsal(directory: Path, record: RehearsalRecord) -> None:
    """Write the card beside the folder, replacing only a card (a ``rehearsal.json`` of
    another kind is the lab's own file: refused, naming it)."""
    path = Path(directory) / REHEARSAL_FILE
    if path.exists():
        read_rehearsal(directory)  # a SidecarError names the file and what is wrong with it
    save(path, record.to_json())


def read_rehearsal(directory: Path) -> RehearsalRecord:
    """The folder's rehearsal record; a missing or malformed one names the file (and key)."""
    return read(Path(directory) / REHEARSAL_FILE, REHEARSAL_VERSION, WRITER, RehearsalRecord.from_fields, AGAIN)
