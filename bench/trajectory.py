"""Rendezvous sequences (plan.mode = trajectory): how far D'Amico's linear relative motion
(the model the planner uses) is from exact two-body propagation of both orbits, how well
the attitude integration keeps the invariants, and what planning the presets costs and
gives in each profile (frames placed, lights, eclipse, the testbed light's distance from
the true sun).

    python -m bench trajectory
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from bench.common import report
from pipeline.config import load_config
from stages.common.attitude import angular_momentum_eci, torque_free
from stages.common.orbits import Elements, RoeModel, relative_two_body
from stages.common.workspace_target import planned_target
from stages.plan.trajectory import chief_elements, mass_properties, preset_motion, sequence_rows


def model_error(config, target) -> list[dict]:
    """Per preset, chief eccentricity and duration: the largest RTN difference (m) between the
    linear model and two-body propagation, and as a share of the range."""
    rows = []
    masses, _ = mass_properties(config, target)
    base = chief_elements(config)
    period = 2 * np.pi / base.mean_motion_rad_s
    for preset in ("vbar_hold_spin", "approach_tumble"):
        roe_m, _ = preset_motion(config, target, preset, masses)
        for e in (0.0, 0.001, 0.01):
            chief = replace(base, e=e) if isinstance(base, Elements) else base
            for label, duration in (("default, 24 x 5 s", 120.0), ("paper, 240 x 5 s", 1200.0), ("one orbit", period)):
                times = np.linspace(0.0, duration, 241)
                exact = relative_two_body(chief, roe_m / chief.a_m, times)
                error = np.linalg.norm(RoeModel(chief, roe_m / chief.a_m).rtn_m(times) - exact, axis=1)
                distance = np.linalg.norm(exact, axis=1)
                rows.append({"preset": preset, "chief e": e, "span": label, "range m": f"{distance.min():.2f}-"
                             f"{distance.max():.2f}", "max error mm": 1000 * float(error.max()),
                             "error / range %": 100 * float((error / distance).max())})
    return rows


def invariants(config, target) -> list[dict]:
    rows = []
    masses, _ = mass_properties(config, target)
    for preset in ("vbar_hold_spin", "approach_tumble"):
        _, omega0 = preset_motion(config, target, preset, masses)
        times = np.arange(240) * 5.0
        started = time.perf_counter()
        quats, omegas = torque_free(masses.inertia_kgm2, np.array([1.0, 0, 0, 0]), omega0, times)
        seconds = time.perf_counter() - started
        momentum = angular_momentum_eci(masses.inertia_kgm2, quats, omegas)
        energy = 0.5 * np.einsum("ni,ij,nj->n", omegas, masses.inertia_kgm2, omegas)
        rows.append({"preset": preset, "frames": 240, "momentum drift (rel)": float(
            np.linalg.norm(momentum - momentum[0], axis=1).max() / np.linalg.norm(momentum[0])),
            "energy drift (rel)": float(np.abs(energy - energy[0]).max() / energy[0]),
            "integration s": seconds})
    return rows


def planning(target) -> list[dict]:
    rows = []
    for profile in ("smoke", "default", "paper"):
        config = load_config(profile)
        config = config.replace(plan=replace(config.plan, mode="trajectory"))
        for index, preset in enumerate(config.trajectory.presets):
            started = time.perf_counter()
            planned, _ = sequence_rows(config, target, index, preset, 0)
            seconds = time.perf_counter() - started
            lights = [r["light"] for r in planned]
            errors = np.degrees([r["light_from_sun_rad"] for r in planned])
            sunlamp = np.array([light == "sunlamp" for light in lights])
            changes = sum(a != b for a, b in zip(lights, lights[1:], strict=False))
            rows.append({"profile": profile, "preset": preset, "frames placed": len(planned),
                         "replans": planned[0]["redraws"],
                         "plan s": seconds, "sun lamp": int(sunlamp.sum()), "light boxes": int((~sunlamp).sum()),
                         "light changes": changes, "in eclipse": sum(r["in_eclipse"] for r in planned),
                         "sun lamp from sun deg (max)": float(errors[sunlamp].max()) if sunlamp.any() else float("nan"),
                         "boxes from sun deg (median)": float(np.median(errors[~sunlamp])) if (~sunlamp).any()
                         else float("nan")})
    return rows


def main() -> None:
    config = load_config("default")
    target = planned_target(config)
    report("trajectory_model", "trajectory: D'Amico's linear ROE model against two-body propagation (Tango presets)",
           model_error(config, target))
    report("trajectory_attitude", "trajectory: torque-free integration over 240 frames (mesh-shell inertia)",
           invariants(config, target))
    report("trajectory_plan", "trajectory: the presets planned per profile (Tango, default room)", planning(target))


if __name__ == "__main__":
    main()
