"""Facility folders (issue 46): what each arm's inverse kinematics achieves and costs, what
share of SO(3) x distance each facility presents, how long planning on it takes and how much
the robot programs' order saves.

    python -m bench facility

Rows: per arm, the numerical inverse kinematics on poses of joints drawn uniformly in the
limits (success share with its Wilson interval, milliseconds per pose: median and 90th
percentile), and the closed form where the arm has one; per facility, the presentable share
(96 draws, 95% interval) at its distances and the seconds that took. Results:
bench/results/facility.json.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from bench.common import report
from stages.common.facilities import builtin_folder
from stages.common.robots.chain import load_chain
from stages.common.robots.facility import load_facility, presentable_share, wilson
from stages.common.robots.inverse import Solver, solve_numeric

TESTS = Path(__file__).resolve().parents[1] / "tests" / "facilities"
ARMS = {"KR 16-2 (TRON)": builtin_folder() / "kr16_2.urdf",
        "IRB 4600-60/2.05": TESTS / "abb_rail" / "irb4600_60_205.urdf",
        "UR10": TESTS / "ur10_tripod" / "ur10.urdf"}
FACILITIES = {"tron": (builtin_folder(), (3.25, 4.75)), "abb-rail": (TESTS / "abb_rail", (3.25, 4.75)),
              "ur10-tripod": (TESTS / "ur10_tripod", (0.6, 1.2))}


def arm_rows(poses: int = 200) -> list[dict]:
    rows = []
    for name, urdf in ARMS.items():
        chain = load_chain(urdf, "base_link", "tool0")
        rng = np.random.default_rng(0)
        solved, times = 0, []
        for joints in rng.uniform(chain.lower, chain.upper, size=(poses, chain.dof)):
            started = time.perf_counter()
            solved += solve_numeric(chain, chain.forward(joints), rng) is not None
            times.append((time.perf_counter() - started) * 1000)
        low, high = wilson(solved, poses)
        solver = Solver(chain)
        closed = ""
        if solver.closed_form is not None:
            started = time.perf_counter()
            for joints in rng.uniform(chain.lower, chain.upper, size=(poses, chain.dof)):
                solver.solve(chain.forward(joints), rng)
            closed = f"{(time.perf_counter() - started) * 1000 / poses:.3f} ms"
        rows.append({"arm": name, "poses": poses, "solved": round(solved / poses, 4),
                     "interval": f"{low:.3f}-{high:.3f}", "ms median": round(float(np.median(times)), 2),
                     "ms p90": round(float(np.percentile(times, 90)), 2), "closed form": closed or "none"})
    return rows


def facility_rows(samples: int = 96) -> list[dict]:
    rows = []
    for name, (folder, distances) in FACILITIES.items():
        facility = load_facility(folder)
        started = time.perf_counter()
        share = presentable_share(facility, distances, samples=samples)
        seconds = time.perf_counter() - started
        limit = share.limits[0][0] if share.limits else "none"
        rows.append({"facility": name, "distances m": f"{distances[0]:g}-{distances[1]:g}", "draws": samples,
                     "presented": round(share.share, 4), "interval": f"{share.interval[0]:.3f}-{share.interval[1]:.3f}",
                     "s": round(seconds, 1), "main limit": limit})
    return rows


def main(*args: str) -> None:
    from rich.console import Console
    from rich.table import Table

    arms, facilities = arm_rows(), facility_rows()
    report("facility", "Inverse kinematics per arm (joints drawn in the limits)", arms, {"facilities": facilities})
    table = Table(title="What each facility presents (SO(3) x distance)")
    for key in facilities[0]:
        table.add_column(key)
    for row in facilities:
        table.add_row(*(str(v) for v in row.values()))
    Console().print(table)
