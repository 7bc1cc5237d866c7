"""What ``speedplus facility DIR`` prints of a facility folder: its room, its robots (their
chains, joints, reach, rail and inverse kinematics), static mounts, camera, lights and
motion capture, the share of SO(3) and of the distance range the facility can present to
its camera, and what its rehearsal measured (docs/user-guide.md, "Your own facility")."""

from __future__ import annotations

import math
from pathlib import Path

from manifests.facility import FacilityError, StaticSpec, facility_digest
from manifests.rehearsal import REHEARSAL_FILE, read_rehearsal
from stages.common.robots.facility import Facility, Share, load_facility, presentable_share
from stages.common.target import load_target
from stages.common.targets import builtin_folder
from stages.common.workspace_target import SPEEDPLUS_RANGE_M, apparent_size_ratio


def mockup_range_m(target_folder: Path | None) -> tuple[float, float]:
    """SPEED+'s camera distances at the target's apparent size, for its mock-up (m)."""
    target = load_target(target_folder or builtin_folder())
    scale = apparent_size_ratio(target) * target.mockup_scale
    return SPEEDPLUS_RANGE_M[0] * scale, SPEEDPLUS_RANGE_M[1] * scale


def robot_rows(facility: Facility) -> list[tuple[str, str]]:
    rows = []
    for robot in facility.robots:
        spec, chain = robot.spec, robot.chain
        limits = ", ".join(f"{math.degrees(lo):.0f}..{math.degrees(hi):.0f}" if kind != "prismatic"
                           else f"{lo:.3g}..{hi:.3g} m"
                           for lo, hi, kind in zip(chain.lower, chain.upper, chain.kinds, strict=True))
        solver = (f"closed form ({robot.solver.closed_form.name})" if robot.solver.closed_form is not None
                  else "numerical (damped least squares, 16 starts, verified by forward kinematics)")
        rail = ("none" if spec.rail is None else f"{spec.rail.travel_m[0]:g} to {spec.rail.travel_m[1]:g} m along "
                f"({', '.join(f'{v:g}' for v in spec.rail.axis)})")
        rows += [(f"{spec.name}", f"carries the {spec.carries}; {chain.name} ({Path(chain.source).name}), "
                                  f"{spec.base_link} -> {spec.flange_link}, {chain.dof} joints"),
                 (f"{spec.name}: joints", f"{', '.join(chain.joint_names)}; limits (deg) {limits}"),
                 (f"{spec.name}: base", f"({', '.join(f'{v:g}' for v in spec.world_from_base.t)}) m, q "
                                        f"({', '.join(f'{v:g}' for v in spec.world_from_base.q)}); rail {rail}"),
                 (f"{spec.name}: reach", f"{robot.reach_m:.3f} m from the base origin; inverse kinematics {solver}; "
                                         f"{len(chain.capsules)} link capsules")]
    return rows


def share_rows(share: Share) -> list[tuple[str, str]]:
    low, high = share.interval
    rows = [("presentable", f"{share.share:.1%} of SO(3) x the distance range [95% interval {low:.1%}, {high:.1%}] "
                            f"({share.presented} of {share.samples} relative poses drawn)")]
    for (start, end), value in zip(share.bins_m, share.bin_shares, strict=True):
        rows.append((f"  at {start:.2f}-{end:.2f} m", "no draws" if math.isnan(value) else f"{value:.0%}"))
    if share.limits:
        rows.append(("limited by", limits_text(share)))
    return rows


def limits_text(share: Share) -> str:
    """What stopped the failed attempts, as shares of them."""
    total = sum(count for _, count in share.limits)
    return "; ".join(f"{why} ({count / total:.0%})" for why, count in share.limits)


def describe(folder: Path, target_folder: Path | None = None, samples: int = 96,
             distances_m: tuple[float, float] | None = None) -> tuple[str, list[tuple[str, str]]]:
    """A table's title and its (what, value) rows; an error naming the file and key (or the
    URDF element) when the folder cannot be used."""
    facility = load_facility(folder)
    spec = facility.spec
    distances = distances_m or mockup_range_m(target_folder)
    rows = [("room", f"{' x '.join(f'{v:g}' for v in spec.room_m)} m, {len(spec.obstacles)} obstacle mesh(es)"),
            *robot_rows(facility)]
    for static in spec.statics:
        assert isinstance(static, StaticSpec)
        rows.append((static.name, f"static mount carrying the {static.carries} at "
                                  f"({', '.join(f'{v:g}' for v in static.world_from_mount.t)}) m"))
    rows.append(("camera", "the configuration's [camera]" if spec.camera is None else
                 f"{spec.camera.sensor}, {spec.camera.size_px[0]} x {spec.camera.size_px[1]} px, pitch "
                 f"{spec.camera.pixel_pitch_m * 1e6:.3g} um"))
    rows.append(("lights", f"{len(spec.light_boxes)} light box(es), "
                           + ("a sun lamp" if spec.sun_lamp is not None else "no sun lamp")))
    rows.append(("motion capture", "none: robots only" if spec.motion_capture is None else
                 f"{len(spec.motion_capture.cameras)} cameras, marker sigma "
                 f"{spec.motion_capture.marker_sigma_m * 1e3:.2g} mm"))
    rows.append(("distances", f"{distances[0]:.3g}-{distances[1]:.3g} m camera to mock-up"
                              + ("" if distances_m else " (SPEED+'s, at the target's apparent size)")))
    share = presentable_share(facility, distances, samples=samples)
    if share.presented == 0:
        raise FacilityError(f"{facility.directory / 'facility.toml'}: the facility presents none of {share.samples} "
                            f"relative poses at {distances[0]:.3g}-{distances[1]:.3g} m; what stops it: "
                            f"{limits_text(share)}")
    rows += share_rows(share)
    rows.append(("rehearsal", rehearsal_text(facility.directory)))
    return f"facility {spec.name} ({folder})", rows


def rehearsal_text(directory: Path) -> str:
    """What ``DIR/rehearsal.json`` says the facility's labels can expect, and whether it was
    measured on the folder as it is now."""
    if not (directory / REHEARSAL_FILE).is_file():
        return "none yet: python -m bench honesty --facility DIR measures the labels' accuracy to expect"
    record = read_rehearsal(directory)
    low, high = record.interval_95
    current = ("measured on this folder" if record.facility_digest == facility_digest(directory)
               else "measured on another version of this folder: rehearse it again")
    target = record.target or "tango"
    return (f"{record.under_speedplus} of {record.labels} labels under the SPEED+ thresholds, {record.share:.0%} "
            f"[95% interval {low:.0%}, {high:.0%}], mean E_T {record.mean_e_t_mm:.3g} mm, inside 1.96 sigma "
            f"x/y/z {'/'.join(f'{v:.0%}' for v in record.inside_1_96_sigma)} ({record.profile} profile, target "
            f"{target}, builds {', '.join(map(str, record.seeds))}); {current}")
