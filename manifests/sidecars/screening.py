"""The calibrate stage's screening record in ``W/calibration.json`` (``screening``): what
``stages.calibrate.screening`` checked of the calibration captures before solving, and
what it set aside (docs/accuracy.md, "Screening"). Shown to users, not computed on."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

from manifests.sidecars.base import Fields


def _ids(f: Fields, name: str) -> tuple[str, ...]:
    value = f.raw(name)
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise f.fail(name, "a list of sample ids")
    return tuple(value)


def _figure(f: Fields, name: str) -> float | None:
    """A measured figure: a number (NaN where nothing could be measured: a median of none)
    or null."""
    value = f.raw(name)
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float) or math.isinf(value):
        raise f.fail(name, "a number or null")
    return value


@dataclass(frozen=True)
class MotionFit:
    """Screw congruence of the camera's and the robot's motions (Tsai and Lenz's
    constraint: a rigid hand-eye link keeps each motion's rotation angle and pitch): the
    captures rejected, the camera-side rotation's fit as given and inverted (rad), the
    median mismatches of angle (rad) and pitch (m), the camera's motion over the robot's
    along the screw axes (scale and its standard error; null when the pitches are too
    short to tell) and the limits the captures were held to."""

    rejected: tuple[str, ...]
    rotation_fit_rad: float | None
    rotation_fit_inverted_rad: float | None
    angle_mismatch_rad_median: float | None
    pitch_mismatch_m_median: float | None
    pitch_scale: float | None
    pitch_scale_se: float | None
    angle_limit_rad: float | None
    pitch_limit_m: float | None
    travel_limit_m: float | None

    def to_json(self) -> dict[str, Any]:
        return {"rejected": list(self.rejected), **{item.name: getattr(self, item.name)
                                                    for item in fields(self) if item.name != "rejected"}}

    @classmethod
    def from_fields(cls, f: Fields) -> MotionFit:
        return cls(_ids(f, "rejected"), *(_figure(f, item.name) for item in fields(cls) if item.name != "rejected"))


@dataclass(frozen=True)
class Screening:
    """Captures whose pattern faced away (``mirrored``), whose chessboard corners were
    relabelled or could not be ordered, and the motions' check (``checked`` captures;
    ``fit`` None: too few motions to check)."""

    mirrored: tuple[str, ...]
    reordered: tuple[str, ...]
    undecided: tuple[str, ...]
    checked: int
    fit: MotionFit | None

    def to_json(self) -> dict[str, Any]:
        return {"facing": {"mirrored": list(self.mirrored)},
                "corner_order": {"reordered": list(self.reordered), "undecided": list(self.undecided)},
                "motions": {"checked": self.checked, **(self.fit.to_json() if self.fit is not None else {})}}

    @classmethod
    def from_fields(cls, f: Fields) -> Screening:
        f.only("facing", "corner_order", "motions")
        facing, order, motions = f.child("facing"), f.child("corner_order"), f.child("motions")
        facing.only("mirrored")
        order.only("reordered", "undecided")
        names = [item.name for item in fields(MotionFit)]
        motions.only("checked", *names)
        fit = MotionFit.from_fields(motions) if "rejected" in motions.data else None
        if fit is None and len(motions.data) > 1:
            raise motions.fail("rejected", "the captures rejected, beside the motions' figures")
        return cls(_ids(facing, "mirrored"), _ids(order, "reordered"), _ids(order, "undecided"),
                   motions.integer("checked"), fit)

    @classmethod
    def of(cls, record: dict[str, Any]) -> Screening:
        """From the record the calibrate stage's screening makes (the JSON's own shape)."""
        return cls.from_fields(Fields(record, "screening", "screening."))
