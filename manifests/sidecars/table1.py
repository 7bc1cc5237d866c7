"""Table 1's records in ``W/calibration.json`` (docs/architecture.md section 4): each
column's errors in-sample, cross-validated and against the truth, and what the
cross-validated means are over.

The errors are the TRON paper's (Park, Bosse and D'Amico, "Robotic Testbed for Rendezvous
and Optical Navigation: Multi-Source Calibration and Machine Learning Use Cases", AAS/AIAA
Astrodynamics Specialist Conference, 2021; section "Experiment", eqs. eT, eR and the
reprojection error after them): over the calibration captures, E_T the distance between
the predicted and the PnP translation (m), E_R the angle of the rotation between them
(rad), E_p the RMS distance of the ChArUco corners projected with the predicted pose from
the detected corners (px); each as [mean, std].
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

from manifests.sidecars.base import Fields

MetricKind = Literal["in_sample", "cross_validated", "truth"]
METRIC_KINDS: tuple[MetricKind, ...] = ("in_sample", "cross_validated", "truth")
METRIC_KEYS = ("E_T_m", "E_R_rad", "E_p_px")


@dataclass(frozen=True)
class MetricSet:
    """E_T (m), E_R (rad) and E_p (px) over a set of captures, each (mean, std)."""

    E_T_m: tuple[float, float]  # noqa: N815 (the paper's symbols, as calibration.json names them)
    E_R_rad: tuple[float, float]  # noqa: N815
    E_p_px: tuple[float, float]  # noqa: N815

    def value(self, key: str) -> tuple[float, float]:
        """(mean, std) of ``key`` (one of ``METRIC_KEYS``)."""
        if key not in METRIC_KEYS:
            raise KeyError(key)
        return getattr(self, key)

    def to_json(self) -> dict[str, list[float]]:
        return {key: list(self.value(key)) for key in METRIC_KEYS}

    @classmethod
    def from_fields(cls, f: Fields) -> MetricSet:
        f.only(*METRIC_KEYS)
        return cls(*(f.vector(key, 2) for key in METRIC_KEYS))  # type: ignore[arg-type]

    @classmethod
    def of(cls, values: dict[str, Any]) -> MetricSet:
        """From ``{E_T_m: [mean, std], ...}`` as the calibrate stage computes them."""
        return cls(*(tuple(float(v) for v in values[key]) for key in METRIC_KEYS))  # type: ignore[arg-type]


@dataclass(frozen=True)
class Folds:
    """What a column's cross-validated means are over: ``samples`` (those whose fold's
    offsets were determined); for a source's own column also the ``folds``, the
    ``undetermined_folds`` left out (numbered from 1) and whether enough folds were
    determined to ``judged`` the data (the fused column: the samples alone)."""

    samples: int
    folds: int | None = None
    undetermined_folds: tuple[int, ...] = ()
    judged: bool | None = None

    def to_json(self) -> dict[str, Any]:
        if self.folds is None:
            return {"samples": self.samples}
        return {"folds": self.folds, "undetermined_folds": list(self.undetermined_folds), "samples": self.samples,
                "judged": self.judged}

    @classmethod
    def from_fields(cls, f: Fields) -> Folds:
        samples = f.integer("samples")
        if not f.optional("folds"):
            f.only("samples")
            return cls(samples)
        f.only("folds", "undetermined_folds", "samples", "judged")
        folds = f.integer("folds", minimum=2)
        left_out = f.raw("undetermined_folds")
        if not isinstance(left_out, list) or not all(isinstance(k, int) and not isinstance(k, bool)
                                                     and 1 <= k <= folds for k in left_out):
            raise f.fail("undetermined_folds", f"a list of fold numbers 1..{folds}")
        return cls(samples, folds, tuple(left_out), f.boolean("judged"))


@dataclass(frozen=True)
class Metrics:
    """One column of Table 1: its errors in-sample, cross-validated (None: no fold was
    determined) and against the truth (None: no truth, a recorded session)."""

    in_sample: MetricSet
    cross_validated: MetricSet | None
    cross_validation: Folds
    truth: MetricSet | None

    def kind(self, name: str) -> MetricSet | None:
        """The errors of ``name`` (one of ``METRIC_KINDS``)."""
        if name not in METRIC_KINDS:
            raise KeyError(name)
        return getattr(self, name)

    def to_json(self) -> dict[str, Any]:
        def plain(entry: MetricSet | None) -> dict[str, list[float]] | None:
            return None if entry is None else entry.to_json()

        return {"in_sample": self.in_sample.to_json(), "cross_validated": plain(self.cross_validated),
                "cross_validation": self.cross_validation.to_json(), "truth": plain(self.truth)}

    @classmethod
    def from_fields(cls, f: Fields) -> Metrics:
        f.only(*METRIC_KINDS, "cross_validation")
        folds = Folds.from_fields(f.child("cross_validation"))
        entries = {kind: MetricSet.from_fields(f.child(kind)) if f.optional(kind) else None for kind in METRIC_KINDS}
        if entries["in_sample"] is None:
            raise f.fail("in_sample", "an object of mean and std per metric")
        if entries["cross_validated"] is None and folds.samples > 0:
            raise f.fail("cross_validated", f"an object of mean and std per metric ({folds.samples} samples)")
        return cls(entries["in_sample"], entries["cross_validated"], folds, entries["truth"])


@dataclass(frozen=True)
class FusedColumn:
    """Table 1's fused column: the captures both sources calibrated on (``samples``), the
    fused estimate's errors there, and each source's own errors on the same captures."""

    samples: int
    metrics: Metrics
    sources_on_the_same_samples: dict[str, Metrics]

    def to_json(self) -> dict[str, Any]:
        return {"samples": self.samples, "metrics": self.metrics.to_json(),
                "sources_on_the_same_samples": {name: m.to_json()
                                                for name, m in self.sources_on_the_same_samples.items()}}

    @classmethod
    def from_fields(cls, f: Fields) -> FusedColumn:
        f.only("samples", "metrics", "sources_on_the_same_samples")
        same = f.child("sources_on_the_same_samples")
        return cls(f.integer("samples", minimum=1), Metrics.from_fields(f.child("metrics")),
                   {name: Metrics.from_fields(same.child(name)) for name in same.data})


@dataclass(frozen=True)
class Baseline:
    """OpenCV's Shah solution on the same captures, in-sample, for comparison: its errors,
    or why it has none (OpenCV's closed form fails on some data)."""

    metrics: MetricSet | None
    failed: str | None = None

    def to_json(self) -> dict[str, Any]:
        return {"failed": self.failed} if self.metrics is None else self.metrics.to_json()

    @classmethod
    def from_fields(cls, f: Fields) -> Baseline:
        if "failed" in f.data:
            f.only("failed")
            return cls(None, f.text("failed"))
        return cls(MetricSet.from_fields(f))

    @classmethod
    def of(cls, values: dict[str, Any]) -> Baseline:
        """From the calibrate stage's dictionary: the metrics, or ``{failed: why}``."""
        return cls(None, str(values["failed"])) if "failed" in values else cls(MetricSet.of(values))
