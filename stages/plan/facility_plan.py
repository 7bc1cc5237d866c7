"""Planning on a facility folder (``facility.path``; docs/architecture.md section 11): the
robots' commands for a relative pose, found as ``stages.common.robots.facility`` finds
them (rail positions nearest first, inverse kinematics verified by forward kinematics,
every link clear of the room, the obstacles and the other robot), with the target held by
the target folder's fixture on the side away from the camera. TRON's own room, as
``[testbed]`` describes it, keeps its closed-form grid search (``reconfigure``).
"""

from __future__ import annotations

import math
from collections import Counter
from pathlib import Path

import numpy as np

from core.config import Config
from manifests import schema
from manifests.facility import StaticSpec
from speedplus.errors import InputError
from stages.common import geometry as g
from stages.common import layout
from stages.common.robots.facility import (
    Facility,
    Robot,
    load_facility,
    placements,
    presentable_share,
    presentation_points,
)
from stages.common.target import Target
from stages.plan.reconfigure import Reconfiguration

#: attitudes in the room tried for one relative pose before it is redrawn
ATTEMPTS = 8
#: joints the plan manifest records per robot
JOINTS = schema.JOINTS.list_size
#: the chance the plan accepts, at the share a facility presents, that some dataset pose
#: runs out of draws (``dataset_redraws``)
RUN_OUT = 0.01
#: relative poses drawn to measure that share
SHARE_SAMPLES = 96


def planned_facility(config: Config) -> Facility | None:
    """The configured facility folder, checked for what the plan records; None: TRON as
    ``[testbed]`` describes it."""
    if not config.facility.path:
        return None
    facility = load_facility(Path(config.facility.path))
    where = facility.directory / "facility.toml"
    for robot in facility.robots:
        if robot.chain.dof != JOINTS:
            raise InputError(f"{where}: robot {robot.spec.name!r} has {robot.chain.dof} moving joints; the plan "
                             f"records {JOINTS} per robot (speedplus facility still checks and measures it)")
    railed = [robot.spec.name for robot in facility.robots if robot.spec.rail is not None]
    if len(railed) > 1:
        raise InputError(f"{where}: robots {' and '.join(map(repr, railed))} both ride rails; the plan records one "
                         "rail position (rail_m), of the one robot on a rail")
    needs = {"lightbox": bool(facility.spec.light_boxes), "sunlamp": facility.spec.sun_lamp is not None}
    missing = [light for light in config.plan.lights if not needs.get(light, True)]
    if missing and (config.plan.n_dataset or config.plan.mode == "trajectory"):
        raise InputError(f"plan.lights: {', '.join(missing)} but {where} has no "
                         f"{' and no '.join('light boxes' if m == 'lightbox' else 'sun lamp' for m in missing)}; "
                         "set plan.lights to what the facility has")
    return facility


_POINTS: dict[tuple[Path, int], np.ndarray] = {}


def _points(facility: Facility, seed: int) -> np.ndarray:
    """Where the target's robot may present the target (``presentation_points``), once per
    facility and plan seed."""
    key = (facility.directory, seed)
    if key not in _POINTS:
        _POINTS[key] = presentation_points(facility, np.random.default_rng([seed, 0xFAC]))
    return _POINTS[key]


def camera_fixture(facility: Facility) -> np.ndarray:
    """(4, 4) the camera in its holder's flange (a robot's ``flange_from_tool``), or in its
    static mount (identity)."""
    return facility.fixture("camera")


def reconfigure_on(facility: Facility, cam_from_target: np.ndarray, mount: str, target: Target, seed: int,
                   rng: np.random.Generator, margin: float, limits: Counter[str],
                   spread_rail: bool = False) -> Reconfiguration | None:
    """Commands that realise ``cam_from_target`` (mock-up scale) with the target on fixture
    ``mount``, or None, counting in ``limits`` what stopped each attempt; ``spread_rail``:
    a rail position drawn within the arm's reach first (``Robot.reach``)."""
    flange_from_target = g.invert(layout.target_from_targetee(target, mount))
    candidates = placements(facility, cam_from_target, _points(facility, seed), rng, ATTEMPTS, flange_from_target)
    if not candidates:
        limits["the room cannot hold the camera at that distance"] += 1
    for world_from_cam, world_from_target in candidates:
        found = _attempt(facility, world_from_cam, world_from_target, flange_from_target, rng, margin, spread_rail)
        if isinstance(found, Reconfiguration):
            return found
        limits[found] += 1
    return None


def _attempt(facility: Facility, world_from_cam: np.ndarray, world_from_target: np.ndarray,
             flange_from_target: np.ndarray, rng: np.random.Generator, margin: float,
             spread_rail: bool = False) -> Reconfiguration | str:
    room = np.asarray(facility.spec.room_m)
    if not np.all((world_from_cam[:3, 3] > 0) & (world_from_cam[:3, 3] < room)):
        return "the camera would leave the room"
    held: dict[str, tuple[Robot, np.ndarray, float]] = {}
    for carried, pose, fixture in (("target", world_from_target, flange_from_target),
                                   ("camera", world_from_cam, camera_fixture(facility))):
        holder = facility.holder(carried)
        if isinstance(holder, StaticSpec):
            continue
        found = holder.reach(pose, rng, margin, fixture, spread_rail)
        if found is None:
            return f"{holder.spec.name} cannot reach the {carried}'s pose"
        held[carried] = (holder, *found)
    if not facility.clear(list(held.values())):
        return "a link would hit the room, an obstacle or a robot"
    camera, target = held.get("camera"), held.get("target")
    railed = [rail_m for robot, _, rail_m in held.values() if robot.spec.rail is not None]
    return Reconfiguration(
        rail_m=railed[0] if railed else 0.0,  # planned_facility allows one robot on a rail
        camera_joints_rad=None if camera is None else camera[1],
        target_joints_rad=None if target is None else target[1],
        world_from_camee=world_from_cam @ g.invert(camera_fixture(facility)),
        world_from_targetee=world_from_target @ g.invert(flange_from_target), margin_rad=margin)


def light_box_centres(facility: Facility) -> np.ndarray:
    """(B, 3) the facility's light boxes' centres in K, m."""
    return np.array([box.centre_m for box in facility.spec.light_boxes]).reshape(-1, 3)


def needed_redraws(share: float, count: int, run_out: float = RUN_OUT) -> int:
    """Redraws each of ``count`` poses may take for all of them to be drawn with probability
    ``1 - run_out`` where a draw succeeds with probability ``share``."""
    if share >= 1.0:
        return 0
    per_pose = 1.0 - (1.0 - run_out) ** (1.0 / max(count, 1))  # each pose's allowed chance of running out
    return max(0, math.ceil(math.log(per_pose) / math.log(1.0 - share)) - 1)


def dataset_redraws(config: Config, facility: Facility, distances_m: tuple[float, float],
                    count: int) -> tuple[int, str]:
    """How many redraws each of ``count`` dataset poses may take on a facility with a static
    mount (a UR10 round a tripod may present 1% of the poses): ``plan.max_redraws``, or as
    many as the share it presents needs for every pose to be drawn with probability
    ``1 - RUN_OUT`` (the share's 95% lower bound, measured here before anything is planned),
    so that the plan draws from what the facility presents instead of failing on the one
    pose that ran out. A facility that presents none is refused before planning, with what
    stops it. Facilities of two robots present most poses and keep ``plan.max_redraws``.
    Also says what it found (empty: nothing to say)."""
    plan = config.plan
    if count == 0 or not any(isinstance(facility.holder(role), StaticSpec) for role in ("camera", "target")):
        return plan.max_redraws, ""
    share = presentable_share(facility, distances_m, samples=SHARE_SAMPLES, seed=plan.seed)
    where = facility.directory / "facility.toml"
    if share.presented == 0:
        stops = "; ".join(f"{why} ({n})" for why, n in share.limits) or "nothing reached"
        raise InputError(f"{where}: presents none of {share.samples} relative poses drawn at "
                         f"{distances_m[0]:.3g}-{distances_m[1]:.3g} m (the mock-up's dataset range), so no dataset "
                         f"pose can be planned; what stops it: {stops}; change plan.dataset_range_m or the facility")
    needed = needed_redraws(share.interval[0], count)
    if needed <= plan.max_redraws:
        return plan.max_redraws, ""
    low, high = share.interval
    return needed, (f"{facility.spec.name} presents {share.share:.1%} [95% interval {low:.1%}, {high:.1%}] of "
                    f"{share.samples} relative poses drawn at {distances_m[0]:.3g}-{distances_m[1]:.3g} m: each "
                    f"dataset pose may take up to {needed} redraws (plan.max_redraws {plan.max_redraws}), enough for "
                    f"all {count} at {1 - RUN_OUT:.0%}")
