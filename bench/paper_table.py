"""Table 2 of a workspace cell by cell beside the TRON paper's (Park et al., "Robotic
Testbed for Rendezvous and Optical Navigation", Table 2: mean SPEED score of the pretrained
CNN on synthetic and simulated images, per view and light).

    python -m bench paper_table WORKSPACE

For each model and crop of the workspace's ``scores``, per configuration (view x light) and
overall: the twins' and the testbed images' mean SPEED score with its 95% interval (as
``evaluate`` writes them), their medians and failure shares, and the gap (testbed minus
twin, image by image on the same labels) with its paired, stratified bootstrap interval
(``stages.evaluate.intervals``). Then, for the first model and its oracle crop, which of the
paper's orderings hold within the intervals: each pair of configurations whose paper gaps
differ, and whether this run's paired gap difference has the paper's sign with an interval
that excludes zero. Saved to bench/results/paper_table.json.
"""

from __future__ import annotations

import itertools
from collections import defaultdict
from typing import Any

import numpy as np

from bench.common import report
from manifests import Workspace, read_manifest
from stages.evaluate.intervals import failed, mean_interval, paired_interval, seed_means

#: the paper's Table 2 (synthetic, simulated): view, light -> mean SPEED score
PAPER = {("solar_panel", "lightbox"): (0.140, 0.810), ("solar_panel", "sunlamp"): (0.170, 1.007),
         ("rear_panel", "lightbox"): (0.121, 1.568), ("rear_panel", "sunlamp"): (0.114, 2.062)}


def _pairs(rows: list[dict[str, Any]]) -> dict[tuple[str, str], dict[str, dict[str, dict[str, Any]]]]:
    """(model, crop) -> sample_id -> {"synthetic": row, "testbed": row}, of prediction rows."""
    out: dict[tuple[str, str], dict[str, dict[str, dict[str, Any]]]] = defaultdict(lambda: defaultdict(dict))
    for row in rows:
        out[(row["model"], row["crop"])][row["sample_id"]]["synthetic" if row["domain"] == "synthetic"
                                                             else "testbed"] = row
    return out


def _cell(pairs: list[dict[str, dict[str, Any]]], name: str) -> dict[str, Any]:
    """One configuration's twins, testbed and paired gap figures."""
    strata = [f"{pair['testbed']['view']}/{pair['testbed']['light']}" for pair in pairs]
    out: dict[str, Any] = {"images": len(pairs)}
    values = {}
    for domain in ("synthetic", "testbed"):
        rows = [pair[domain] for pair in pairs]
        values[domain] = seed_means(rows, "speed")
        interval = mean_interval(values[domain], strata, f"{name}/{domain}")
        miss = failed([r["err_q_rad"] for r in rows], [r["err_t_norm"] for r in rows])
        out[domain] = (f"{interval.value:.3f} [{interval.low:.3f}, {interval.high:.3f}] med "
                       f"{np.median(values[domain]):.3f} fail {100 * miss.mean():.0f}%")
    gap = paired_interval(values["testbed"], values["synthetic"], strata, f"{name}/gap")
    out["gap"] = f"{gap.value:+.3f} [{gap.low:+.3f}, {gap.high:+.3f}]"
    out["_values"] = values
    out["_strata"] = strata
    return out


def _orderings(cells: dict[tuple[str, str], dict[str, Any]], name: str) -> list[dict[str, Any]]:
    """Each pair of configurations whose paper gaps differ: this run's difference of their
    mean gaps (an unpaired, per-configuration bootstrap of the two means)."""
    rows = []
    rng = np.random.default_rng(44)
    for first, second in itertools.combinations(PAPER, 2):
        paper = (PAPER[first][1] - PAPER[first][0]) - (PAPER[second][1] - PAPER[second][0])
        gaps = [cells[key]["_values"]["testbed"] - cells[key]["_values"]["synthetic"] for key in (first, second)]
        draws = np.array([rng.choice(gaps[0], len(gaps[0])).mean() - rng.choice(gaps[1], len(gaps[1])).mean()
                          for _ in range(4000)])
        here = gaps[0].mean() - gaps[1].mean()
        low, high = np.quantile(draws, [0.025, 0.975])
        holds = "yes" if (low > 0 if paper > 0 else high < 0) else ("opposite" if (high < 0 if paper > 0 else low > 0)
                                                                    else "not shown")
        rows.append({"comparison": f"gap {'/'.join(first)} - {'/'.join(second)}", "paper": round(paper, 3),
                     "here": f"{here:+.3f} [{low:+.3f}, {high:+.3f}]", "paper's sign holds": holds, "of": name})
    return rows


def main(*args: str) -> None:
    if not args:
        raise SystemExit("usage: python -m bench paper_table WORKSPACE")
    workspace = Workspace(args[0])
    rows = read_manifest(workspace, "predictions").to_pylist()
    table, orderings = [], []
    for (model, crop), by_sample in sorted(_pairs(rows).items()):
        complete = [pair for _, pair in sorted(by_sample.items()) if len(pair) == 2]
        cells = {}
        for key in [*PAPER, ("all", "all")]:
            chosen = [pair for pair in complete if key == ("all", "all")
                      or (pair["testbed"]["view"], pair["testbed"]["light"]) == key]
            if not chosen:
                continue
            cells[key] = _cell(chosen, f"{model}/{crop}/{'/'.join(key)}")
            paper = PAPER.get(key, (None, None))
            table.append({"model": model, "crop": crop, "view": key[0], "light": key[1],
                          "paper synthetic": paper[0], "paper simulated": paper[1],
                          **{k: v for k, v in cells[key].items() if not k.startswith("_")}})
        if all(key in cells for key in PAPER):
            orderings += _orderings(cells, f"{model}/{crop}")
    report("paper_table", f"Table 2 of {workspace.location} beside the paper's (mean SPEED [95%], median, "
                          "failures: rotation > 10 deg or translation > 10%)", table)
    report("paper_table_orderings", "the paper's gap orderings, checked (yes: this run shows the paper's sign "
                                    "with 95% confidence)", orderings)
