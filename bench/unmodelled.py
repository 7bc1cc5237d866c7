"""What the robots' calibration makes of each unmodelled error source, over many facilities,
in seconds: a render-free facility (docs/architecture.md section 5). Each facility's
robots move through the default profile's plan with its timeline; the calibration
session's PnP poses are the truth plus PnP-sized noise (0.05 mm, 0.026 deg: what the
rendered board gives on the default profile) instead of rendered images; ``calibrate``'s
own solvers (``stages.common.rwhe``, ``stages.calibrate.arm_models``) fit the robots; the fit
predicts the dataset captures. No motion capture, no fusion: ``bench honesty`` and
``bench budget`` run the whole pipeline.

It answers two questions cheaply, on facilities the models were not developed on:
which unmodelled source costs the robots what, and what the estimator's physical models
(joint compliance, fixture anisotropy) buy.

    python -m bench unmodelled [SEEDS] [ROWS]
        (default seeds 21-28; about 4 s per facility and row; ROWS: the rows to measure, by
        their first column, comma-separated: none, a source of virtual.unmodelled, all,
        uncovered (all errors, and no calibration pose at a dataset pose's target-arm
        configuration: plan.calibration_cover = 0); default every row, the physical
        models' switches included)
"""

from __future__ import annotations

import sys
from typing import Any

import numpy as np

from bench.common import report
from core.config import UNMODELLED_SOURCES, Config, parse_override, with_overrides
from pipeline.config import load_config
from stages.acquire.virtual import robots
from stages.acquire.virtual.timeline import timeline
from stages.acquire.virtual.truth import draw_truth
from stages.calibrate.arm_models import arms_model
from stages.common import arms, rwhe
from stages.common import geometry as g
from stages.common.geometry import pose_columns
from stages.common.robots import identification, lost_motion
from stages.common.workspace_target import planned_target
from stages.plan.stage import plan_sample, planned_samples

PNP_SIGMA_M, PNP_SIGMA_RAD = 0.05e-3, np.radians(0.026)
SPEEDPLUS_ROTATION_DEG = 0.169


def facility(seed: int, sources: list[str], settings: tuple[str, ...] = ()) -> tuple[Config, dict[str, Any]]:
    """The true relative poses and the robots' telemetry of both sessions of one facility."""
    listed = ", ".join(f'"{s}"' for s in sources)
    overrides = [f"virtual.seed={seed}", f"virtual.unmodelled=[{listed}]", *settings]
    config = with_overrides(load_config("default"), [parse_override(o) for o in overrides])
    truth = draw_truth(config)
    rows = [plan_sample(config, *item) for item in planned_samples(config)]
    moments = timeline(config, rows, truth.unmodelled.start_direction)
    sessions = {}
    for session in ("calibration", "dataset"):
        chosen = [r for r in rows if r["session"] == session]
        states = [robots.move(config, truth, r, np.random.default_rng([seed, index, 7]), moments[r["sample_id"]])
                  for index, r in enumerate(chosen)]
        true = np.stack([g.invert(s.world_from_cam) @ s.world_from_target for s in states])
        captures = lost_motion.move_directions([
            {**pose_columns("kuka_world_from_targetee", s.kuka_world_from_targetee), "session": session,
             "capture_time_s": moments[r["sample_id"]].time_s, "kuka_camera_joints_rad": s.camera_joints_rad,
             "kuka_target_joints_rad": s.target_joints_rad, "kuka_rail_m": s.rail_m, "fixture": r["mount"]}
            for s, r in zip(states, chosen, strict=True)])
        sessions[session] = (captures, true)
    return config, sessions


def robots_only(config: Config, sessions: dict[str, Any], rng: np.random.Generator) -> dict[str, float]:
    """Calibrate the robots on the calibration session; their errors on both sessions."""
    world_up = np.asarray(config.calibrate.world_up, float)
    captures, true = sessions["calibration"]
    noise = np.stack([g.make_transform(g.rotvec_to_matrix(rng.normal(0, PNP_SIGMA_RAD / np.sqrt(3), 3)),
                                       rng.normal(0, PNP_SIGMA_M / np.sqrt(3), 3)) for _ in true])
    payload = arms.Payload.of(planned_target(config))
    model = arms_model(config, payload)
    a, fixtures, readings = true @ noise, [x["fixture"] for x in captures], model.readings(captures)
    b, up = identification.corrected_b(model.holders, np.zeros(model.size), readings, world_up)
    start = rwhe.frobenius(a, b, fixtures, rwhe.shah(a, b, fixtures), up)
    fitted = model.fit(a, readings, fixtures, start, True)
    out = {}
    for session, (captures, true) in sessions.items():
        readings = model.readings(captures)
        b, up = fitted.corrected_b(readings)
        predicted = fitted.offsets.predict(b, [x["fixture"] for x in captures], up, fitted.up_before(readings))
        rotation = np.degrees(g.angular_distance(predicted[:, :3, :3], true[:, :3, :3]))
        out[f"{session} E_T (mm)"] = float(np.linalg.norm(predicted[:, :3, 3] - true[:, :3, 3], axis=1).mean() * 1000)
        out[f"{session} E_R (deg)"] = float(rotation.mean())
    out["dataset under 0.169 deg"] = float(np.mean(rotation < SPEEDPLUS_ROTATION_DEG))
    return out


def mean_over(seeds: list[int], sources: list[str], settings: tuple[str, ...] = ()) -> dict[str, float]:
    results = [robots_only(*facility(seed, sources, settings), np.random.default_rng(seed)) for seed in seeds]
    return {key: float(np.mean([r[key] for r in results])) for key in results[0]}


def main(seeds: str = "21,22,23,24,25,26,27,28", rows: str = "") -> None:
    chosen = [int(s) for s in seeds.split(",")]
    every = list(UNMODELLED_SOURCES)
    wanted = set(rows.split(",")) if rows else {"none", *every, "all", "uncovered"}
    unknown = sorted(wanted - {"none", *every, "all", "uncovered"})
    if unknown:
        raise SystemExit(f"bench unmodelled: unknown row {unknown[0]!r}; rows: none, {', '.join(every)}, all, "
                         "uncovered")
    table = [{"unmodelled errors on": "none", "calibrate": "as shipped", **mean_over(chosen, [])}] \
        if "none" in wanted else []
    table += [{"unmodelled errors on": s, "calibrate": "as shipped", **mean_over(chosen, [s])}
              for s in every if s in wanted]
    if "all" in wanted:
        table.append({"unmodelled errors on": "all", "calibrate": "as shipped", **mean_over(chosen, every)})
    if "uncovered" in wanted:  # no calibration pose at a dataset pose's target-arm configuration
        table.append({"unmodelled errors on": "all", "calibrate": "as shipped; plan.calibration_cover = 0",
                      **mean_over(chosen, every, ("plan.calibration_cover=0",))})
    if not rows:
        for switch in ("joint_compliance", "fixture_anisotropy"):
            table.append({"unmodelled errors on": "all", "calibrate": f"{switch} off",
                          **mean_over(chosen, every, (f'calibrate.{switch}="off"',))})
    report("unmodelled", f"robots-only errors over render-free facilities (seeds {seeds})", table)


if __name__ == "__main__":
    main(*sys.argv[1:])
