"""What labels a facility can expect, before it buys or books robot time (issue 46, part 4):
its folder rehearsed on the virtual testbed.

    python -m bench honesty --facility DIR [SEEDS] [ROOT] [SET...] [--target DIR] [--profile P]
        (default: seeds 71-74, ROOT data/rehearsal/<facility name>, profile default)

Each seed (``virtual.seed``) is another build of the same facility: other true arms, drawn
per joint of its URDFs (``stages/acquire/virtual/rig.py``), other bases, rail scale, fixture
sag, motion-capture errors where it has motion capture, and noise. For each, the facility's
plan is acquired on the virtual testbed built from its folder (its room, lights and motion
capture), then calibrated, fused and labelled, and the labels are set against the truth:

(b) mean E_T and E_R of the labels, and their share under the SPEED+ thresholds (E_R under
    0.169 deg and E_T under 2.173 mm per m of range; the testbed labels' own figures in the
    SPEED+ paper, Park et al. 2022) with a 95% Wilson interval over the facility's labels;
(c) the fused labels against each source on the dataset captures (robots, and motion
    capture where the facility has it);
(d) the sigmas' coverage: the share of true errors inside 1.96 sigma per camera axis and
    rms(error / sigma), pooled over the seeds.

One seed's labels share one calibration, so their errors are correlated: the pooled row's
interval is over labels and is narrower than one over facilities would be; the per-seed
rows show the spread between builds.

The pooled figures are written beside the folder, ``DIR/rehearsal.json``
(``manifests/rehearsal.py``): the facility's card, which ``speedplus facility DIR`` shows. A
folder that keeps a card of another profile, settings or target keeps it; the run's card then
goes to ``bench/results/`` (``keep_or_replace``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from bench import common
from bench.arm_accuracy import arm_accuracy, describe
from bench.common import report
from bench.honesty import (
    AXES,
    better_source,
    dataset,
    pooled_against_sources,
    run_facility,
    sigma_coverage,
    under_speedplus,
)
from manifests.facility import facility_digest, read_facility_spec
from manifests.rehearsal import REHEARSAL_FILE, RehearsalRecord, read_rehearsal, write_rehearsal
from manifests.sidecars import read_calibration
from manifests.sidecars.base import SidecarError, save
from stages.common.robots.facility import wilson
from stages.common.target import load_target

REHEARSAL_SEEDS = (71, 72, 73, 74)  # chosen with the commit that builds the rehearsal, before any was run


def _coverage_columns(normalised: np.ndarray) -> dict[str, float]:
    inside, rms = sigma_coverage(normalised)
    return {**{f"(d) inside 1.96 sigma {a}": round(float(inside[i]), 3) for i, a in enumerate(AXES)},
            **{f"(d) rms(err/sigma) {a}": round(float(rms[i]), 3) for i, a in enumerate(AXES)}}


def _share(under: np.ndarray) -> str:
    low, high = wilson(int(under.sum()), len(under))
    return f"{under.mean():.0%} [{low:.0%}, {high:.0%}]"


def rehearsal_row(seed: int, data: dict[str, Any], calibration_mm: dict[str, float], arms: str = "-"
                  ) -> dict[str, Any]:
    """One build's figures: (b) the labels against the truth, (c) against each source and
    each arm's own accuracy (``bench/arm_accuracy.py``, in words), (d) sigmas."""
    sources = f"{np.mean(data['kuka']) * 1000:.3f}" + (f"/{np.mean(data['vicon']) * 1000:.3f}"
                                                       if len(data["vicon"]) else "/-")
    return {
        "seed": seed, "labels": len(data["rotation"]),
        "(b) mean E_T label (mm)": round(float(np.mean(data["fused"]) * 1000), 3),
        "(b) mean E_R label (deg)": round(float(np.degrees(np.mean(data["rotation"]))), 4),
        "(b) max E_R label (deg)": round(float(np.degrees(np.max(data["rotation"]))), 4),
        "(b) under SPEED+ thresholds [95%]": _share(under_speedplus(data)),
        "(c) cal E_T vs truth, fused/robots/mocap (mm)": "/".join(
            f"{calibration_mm[s]:.3f}" if s in calibration_mm else "-" for s in ("fused", "kuka", "vicon")),
        "(c) dataset E_T robots/mocap (mm)": sources,
        "(c) labels against the better source, two-source captures": better_source(data),
        "(c) each arm's flange vs truth, dataset, registered (bench/arm_accuracy.py)": arms,
        **_coverage_columns(data["axis_error"] / data["axis_sigma"]),
    }


def calibration_vs_truth_mm(ws: Any) -> dict[str, float]:
    """Mean E_T (mm) of the calibration against the truth, fused and per source measured."""
    calibration = read_calibration(ws)
    out = {}
    if calibration.fused is not None and calibration.fused.metrics.truth is not None:  # two sources
        out["fused"] = calibration.fused.metrics.truth.E_T_m[0] * 1000
    for name in ("kuka", "vicon"):
        source = calibration.source(name)
        if source is not None and source.metrics.truth is not None:
            out[name] = source.metrics.truth.E_T_m[0] * 1000
    return out


def pooled(columns: list[str], data: list[dict[str, Any]]) -> dict[str, Any]:
    """The row over every seed's labels (``dataset``'s of each seed)."""
    under = np.concatenate([under_speedplus(d) for d in data])
    row = dict.fromkeys(columns, "")
    row.update({"seed": "pooled", "labels": len(under),
                "(b) mean E_T label (mm)": round(float(np.mean(np.concatenate([d["fused"] for d in data]))) * 1000, 3),
                "(b) under SPEED+ thresholds [95%]": _share(under),
                "(c) labels against the better source, two-source captures": pooled_against_sources(data),
                **_coverage_columns(np.concatenate([d["axis_error"] / d["axis_sigma"] for d in data]))})
    return row


def card(facility: Path, profile: str, settings: list[str], target: Path | None, seeds: list[str],
         data: list[dict[str, Any]]) -> RehearsalRecord:
    """The pooled figures as the facility's card (``DIR/rehearsal.json``)."""
    under = np.concatenate([under_speedplus(d) for d in data])
    inside, rms = sigma_coverage(np.concatenate([d["axis_error"] / d["axis_sigma"] for d in data]))
    return RehearsalRecord(
        facility_digest(facility), profile, tuple(settings), None if target is None else load_target(target).name,
        tuple(int(s) for s in seeds), int(len(under)), int(under.sum()), wilson(int(under.sum()), len(under)),
        round(float(np.mean(np.concatenate([d["fused"] for d in data]))) * 1000, 4),
        tuple(round(float(v), 4) for v in inside), tuple(round(float(v), 4) for v in rms))


def kept_card(facility: Path) -> RehearsalRecord | None:
    """The card the folder keeps (None: none), read before any build: a malformed one is
    refused, naming the file and key, before minutes of captures rather than after them."""
    if not (facility / REHEARSAL_FILE).exists():
        return None
    try:
        return read_rehearsal(facility)
    except SidecarError as error:
        raise SystemExit(f"{error}\n(move it aside, or mend it, and run the bench again: nothing was built)") from None


def keep_or_replace(facility: Path, record: RehearsalRecord, kept: RehearsalRecord | None) -> str:
    """Write ``record`` as the facility's card (``DIR/rehearsal.json``) unless the folder
    keeps a card ``kept`` (``kept_card``) of another profile, settings or target (the tests
    hold a folder's labels to the card it keeps: a default-profile run must not replace a
    smoke card); then beside the bench's results instead. Says where it went."""
    path = facility / REHEARSAL_FILE
    if kept is not None and (kept.profile, kept.settings, kept.target) != (record.profile, record.settings,
                                                                       record.target):
        common.RESULTS.mkdir(parents=True, exist_ok=True)
        elsewhere = common.RESULTS / f"rehearsal_card_{facility.name}_{record.profile}.json"
        save(elsewhere, record.to_json())
        return (f"{path} is the card of another rehearsal ({kept.profile} profile, settings {list(kept.settings)}, "
                f"target {kept.target}): kept; this one's card is {elsewhere}")
    write_rehearsal(facility, record)  # the facility's card, beside its folder
    return f"the facility's card: {path}"


def main(facility: Path, positional: list[str], targets: list[Path], profile: str = "default") -> None:
    name = read_facility_spec(facility).name
    seeds = positional[0].split(",") if positional else [str(s) for s in REHEARSAL_SEEDS]
    root = Path(positional[1]) if len(positional) > 1 else Path("data/rehearsal") / name
    settings = positional[2:]
    target = targets[0] if targets else None
    kept = kept_card(facility)
    rows, data = [], []
    for seed in (int(s) for s in seeds):
        ws = run_facility(root / f"seed{seed}", seed, settings, target, facility=facility, profile=profile)
        data.append(dataset(ws))
        rows.append(rehearsal_row(seed, data[-1], calibration_vs_truth_mm(ws), describe(arm_accuracy(ws))))
    rows.append(pooled(list(rows[0]), data))
    record = card(facility, profile, settings, target, seeds, data)
    print(keep_or_replace(facility, record, kept))
    report(f"rehearsal_{name}", f"what labels {name} can expect: its folder ({facility}) rehearsed on the virtual "
           f"testbed, {profile} profile{'' if target is None else f', target {target}'}", rows,
           {"facility": str(facility), "settings": list(settings), "profile": profile,
            "target": None if target is None else str(target), "record": record.to_json()})
