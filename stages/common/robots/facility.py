"""A facility as the planner sees it: the folder's robots as serial chains placed in the
room (frame K), on their rails, with their inverse kinematics and link capsules; static
mounts; the room and its obstacles (docs/architecture.md section 11). ``present`` finds
joints and rail positions that put the camera and the target at given poses in K, clear
of the room, the obstacles and each other; ``presentable_share`` measures how much of
SO(3) x the distance range a facility can show a camera.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import numpy as np

from manifests.facility import FacilityError, FacilitySpec, RobotSpec, StaticSpec, read_facility_spec
from speedplus.errors import FileError
from stages.common import geometry as g
from stages.common.facilities import builtin_folder
from stages.common.robots.chain import SerialChain, load_chain
from stages.common.robots.collision import capsules_clear, clear_of_box, inside_box
from stages.common.robots.inverse import Solver

#: links keep this far from walls, floor, ceiling and obstacles, and from the other robot (m)
CLEARANCE_M = 0.05
#: rail positions tried for one flange pose: the nearest to the pose, then steps of this
#: share of the arm's reach either side
RAIL_STEPS = (0.0, -0.25, 0.25, -0.5, 0.5, -0.75, 0.75)


def pose_matrix(pose: object) -> np.ndarray:
    """(4, 4) of a format's Pose (q w-first, t m)."""
    return g.transform_from_qt(pose.q, pose.t)


@dataclass(frozen=True)
class Robot:
    """One arm of the facility, placed in K, on its rail if it has one."""

    spec: RobotSpec
    chain: SerialChain
    solver: Solver
    reach_m: float  # farthest flange from the base origin over the joint ranges

    @property
    def rail_travel_m(self) -> tuple[float, float]:
        return (0.0, 0.0) if self.spec.rail is None else self.spec.rail.travel_m

    def world_from_base(self, rail_m: float = 0.0) -> np.ndarray:
        """(4, 4) the base in K with the rail at ``rail_m`` (m)."""
        world_from_base = pose_matrix(self.spec.world_from_base)
        if self.spec.rail is not None:
            world_from_base[:3, 3] += rail_m * np.asarray(self.spec.rail.axis)
        return world_from_base

    def world_from_tool(self, joints: np.ndarray, rail_m: float = 0.0) -> np.ndarray:
        """(4, 4) what the robot carries (camera frame, target origin) in K."""
        return self.world_from_base(rail_m) @ self.chain.forward(joints) @ pose_matrix(self.spec.flange_from_tool)

    def capsules(self, joints: np.ndarray, rail_m: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Link capsules in K: ends a, b (C, 3) and radii (C,)."""
        a, b, radius = self.chain.capsules_in_base(joints)
        base = self.world_from_base(rail_m)
        return g.apply(base, a), g.apply(base, b), radius

    def reach(self, world_from_tool: np.ndarray, rng: np.random.Generator, margin: float = 0.0,
              flange_from_tool: np.ndarray | None = None, spread_rail: bool = False) -> tuple[np.ndarray, float] | None:
        """(joints (J,), rail m) that put the carried frame at ``world_from_tool`` (4, 4), held
        at ``flange_from_tool`` (default: the folder's), or None. ``spread_rail``: first try a
        rail position drawn uniformly within the arm's reach of the pose (a calibration that
        moves the rail, and so can measure its scale), then the nearest ones."""
        mount = pose_matrix(self.spec.flange_from_tool) if flange_from_tool is None else flange_from_tool
        world_from_flange = world_from_tool @ g.invert(mount)
        for rail_m in self._rail_candidates(world_from_flange[:3, 3], rng if spread_rail else None):
            base_from_flange = g.invert(self.world_from_base(rail_m)) @ world_from_flange
            if np.linalg.norm(base_from_flange[:3, 3]) > self.chain.reach_bound_m:
                continue  # out of any reach: no inverse to try
            joints = self.solver.solve(base_from_flange, rng, margin=margin)
            if joints is not None:
                return joints, rail_m
        return None

    def _rail_candidates(self, flange_world: np.ndarray, rng: np.random.Generator | None = None) -> list[float]:
        if self.spec.rail is None:
            return [0.0]
        low, high = self.spec.rail.travel_m
        base = np.asarray(self.spec.world_from_base.t)
        along = float((flange_world - base) @ np.asarray(self.spec.rail.axis))
        nearest = float(np.clip(along, low, high))
        start = float(np.clip(along - self.reach_m, low, high))
        end = float(np.clip(along + self.reach_m, low, high))
        drawn = [] if rng is None else [float(rng.uniform(start, end))]
        candidates = drawn + [float(np.clip(nearest + step * self.reach_m, low, high)) for step in RAIL_STEPS]
        return list(dict.fromkeys(round(c, 6) for c in candidates))


@dataclass(frozen=True)
class Facility:
    """The folder, read and checked, with its robots' kinematics."""

    directory: Path
    spec: FacilitySpec
    robots: tuple[Robot, ...]
    obstacles: tuple[tuple[np.ndarray, np.ndarray], ...]  # axis-aligned boxes (low, high) in K, m

    def holder(self, carried: str) -> Robot | StaticSpec:
        """The robot (or static mount) that carries the camera (or the target)."""
        holder = self.spec.carrier("camera" if carried == "camera" else "target")
        return next((robot for robot in self.robots if robot.spec is holder), holder)

    def fixture(self, carried: str) -> np.ndarray:
        """(4, 4) the carried frame (camera, target origin) in its holder's flange: the robot's
        ``flange_from_tool``, or identity on a static mount."""
        holder = self.holder(carried)
        return np.eye(4) if isinstance(holder, StaticSpec) else pose_matrix(holder.spec.flange_from_tool)

    def clear(self, placed: list[tuple[Robot, np.ndarray, float]]) -> bool:
        """Whether robots at (joints, rail) stay in the room, off the obstacles and off each other."""
        room_low, room_high = np.zeros(3), np.asarray(self.spec.room_m)
        capsules = [robot.capsules(joints, rail_m) for robot, joints, rail_m in placed]
        for (robot, _, _), (a, b, radius) in zip(placed, capsules, strict=True):
            # the base and its first joint's link stand on the mount (floor, ceiling, carriage)
            moving = np.array([capsule.joint >= 1 for capsule in robot.chain.capsules])
            if not inside_box(a[moving], b[moving], radius[moving], room_low, room_high, CLEARANCE_M):
                return False
            if not all(clear_of_box(a, b, radius + CLEARANCE_M, low, high) for low, high in self.obstacles):
                return False
        for first in range(len(capsules)):
            for second in range(first + 1, len(capsules)):
                if not capsules_clear(*capsules[first], *capsules[second], CLEARANCE_M):
                    return False
        return True


def load_facility(directory: Path | None = None) -> Facility:
    """The facility folder ``directory`` (None: the built-in TRON), read and checked."""
    return _load(Path(directory or builtin_folder()).resolve())


@cache
def _load(directory: Path) -> Facility:
    spec = read_facility_spec(directory)
    robots = []
    for index, robot in enumerate(spec.robots):
        try:
            chain = load_chain(directory / robot.urdf, robot.base_link, robot.flange_link)
        except FileError as error:
            raise FacilityError(f"{directory / 'facility.toml'}: key robot[{index}].urdf: {error}") from None
        robots.append(Robot(robot, chain, Solver(chain), chain.reach_m()))
    return Facility(directory, spec, tuple(robots), tuple(_obstacle_box(directory / name) for name in spec.obstacles))


def _obstacle_box(path: Path) -> tuple[np.ndarray, np.ndarray]:
    import trimesh

    try:
        mesh = trimesh.load(path, force="mesh")
    except Exception as error:  # trimesh raises what its loaders meet
        raise FacilityError(f"{path}: not a mesh trimesh reads ({type(error).__name__}: {error})") from None
    low, high = np.asarray(mesh.bounds[0], float), np.asarray(mesh.bounds[1], float)
    return low, high


@dataclass(frozen=True)
class Presentation:
    """Where each robot goes for one capture: name -> (joints, rail m)."""

    commands: dict[str, tuple[np.ndarray, float]]


def present(facility: Facility, world_from_cam: np.ndarray, world_from_target: np.ndarray,
            rng: np.random.Generator, margin: float = 0.0) -> Presentation | None:
    """Joints and rail positions that put the camera and the target at these poses in K,
    the target held by its fixture on the side away from the camera (``mount_away``), every
    link clear; None where the facility cannot (``attempt`` says why)."""
    outcome = attempt(facility, world_from_cam, world_from_target, rng, margin)
    return outcome if isinstance(outcome, Presentation) else None


def attempt(facility: Facility, world_from_cam: np.ndarray, world_from_target: np.ndarray,
            rng: np.random.Generator, margin: float = 0.0) -> Presentation | str:
    """``present``'s answer, or what stopped it: the camera outside the room, a robot that
    cannot reach (within its limits, on its rail), a static mount elsewhere, a collision."""
    if not inside_box(world_from_cam[None, :3, 3], world_from_cam[None, :3, 3], np.zeros(1), np.zeros(3),
                      np.asarray(facility.spec.room_m), CLEARANCE_M):
        return "the camera would leave the room"
    commands, placed = {}, []
    for carried, pose in (("target", world_from_target), ("camera", world_from_cam)):
        holder = facility.holder(carried)
        if isinstance(holder, StaticSpec):
            if not np.allclose(pose, pose_matrix(holder.world_from_mount), atol=1e-9):
                return f"{holder.name} holds the {carried} elsewhere"
            continue
        mount = mount_away(holder, g.invert(world_from_target) @ world_from_cam) if carried == "target" else None
        found = holder.reach(pose, rng, margin, mount)
        if found is None:
            return f"{holder.spec.name} cannot reach the {carried}'s pose"
        commands[holder.spec.name] = found
        placed.append((holder, *found))
    return Presentation(commands) if facility.clear(placed) else "a link would hit the room, an obstacle or a robot"


def mount_away(robot: Robot, target_from_cam: np.ndarray) -> np.ndarray:
    """``flange_from_tool`` (4, 4) of the fixture on the target's side away from the camera:
    the folder's, or the same turned half round the target's origin (about an axis across
    the fixture's), as TRON's two fixtures do (stages/common/layout.py)."""
    flange_from_target = pose_matrix(robot.spec.flange_from_tool)
    flange_in_target = g.invert(flange_from_target)[:3, 3]
    if float(flange_in_target @ target_from_cam[:3, 3]) < 0.0 or np.linalg.norm(flange_in_target) < 1e-9:
        return flange_from_target
    across = np.cross(flange_in_target, [0.0, 0.0, 1.0])
    if np.linalg.norm(across) < 1e-6 * np.linalg.norm(flange_in_target):
        across = np.cross(flange_in_target, [1.0, 0.0, 0.0])
    half_turn = g.make_transform(g.rotvec_to_matrix(np.pi * across / np.linalg.norm(across)), np.zeros(3))
    return flange_from_target @ g.invert(half_turn)


@dataclass(frozen=True)
class Share:
    """How much of SO(3) x the distance range the facility presents: a Monte-Carlo share
    with its 95% Wilson interval, over all distances and per distance bin."""

    samples: int
    presented: int
    interval: tuple[float, float]
    bins_m: tuple[tuple[float, float], ...]
    bin_shares: tuple[float, ...]
    #: what stopped the attempts that failed, most frequent first: (why, attempts)
    limits: tuple[tuple[str, int], ...] = ()

    @property
    def share(self) -> float:
        return self.presented / self.samples


def wilson(successes: int, trials: int, z: float = 1.96) -> tuple[float, float]:
    """95% Wilson score interval of a binomial share (Wilson, JASA 22(158), 1927)."""
    if trials == 0:
        return 0.0, 1.0
    p = successes / trials
    centre = (p + z * z / (2 * trials)) / (1 + z * z / trials)
    half = z * math.sqrt(p * (1 - p) / trials + z * z / (4 * trials * trials)) / (1 + z * z / trials)
    # at 0 or all successes the bound is exactly 0 or 1, which rounding would leave a hair inside
    low = 0.0 if successes == 0 else max(0.0, centre - half)
    high = 1.0 if successes == trials else min(1.0, centre + half)
    return low, high


def presentable_share(facility: Facility, distances_m: tuple[float, float], samples: int = 96,
                      attempts: int = 8, seed: int = 0, bins: int = 4) -> Share:
    """Draw ``samples`` relative poses (the target's attitude uniform on SO(3) in the camera
    frame, its origin on the boresight at a distance uniform in ``distances_m``, m) and count
    those the facility presents: a static target fixes the camera's pose; a target on a robot
    is tried at ``attempts`` attitudes in K, each at a point its robot reaches."""
    rng = np.random.default_rng(seed)
    points = presentation_points(facility, rng)
    low, high = distances_m
    edges = np.linspace(low, high, bins + 1)
    hits, counts = np.zeros(bins, int), np.zeros(bins, int)
    limits: Counter[str] = Counter()
    for quat in g.random_quats(rng, samples):
        distance = rng.uniform(low, high)
        cam_from_target = g.make_transform(g.quat_to_matrix(quat), [0.0, 0.0, distance])
        index = min(int(np.searchsorted(edges, distance, side="right")) - 1, bins - 1)
        counts[index] += 1
        candidates = placements(facility, cam_from_target, points, rng, attempts)
        if not candidates:
            limits["the room cannot hold the camera at that distance"] += 1
        for placement in candidates:
            outcome = attempt(facility, *placement, rng)
            if isinstance(outcome, Presentation):
                hits[index] += 1
                break
            limits[outcome] += 1
    presented = int(hits.sum())
    return Share(samples, presented, wilson(presented, samples),
                 tuple((float(edges[i]), float(edges[i + 1])) for i in range(bins)),
                 tuple(float(h / c) if c else float("nan") for h, c in zip(hits, counts, strict=True)),
                 tuple(limits.most_common()))


def placements(facility: Facility, cam_from_target: np.ndarray, points: np.ndarray, rng: np.random.Generator,
               attempts: int, mount_from_target: np.ndarray | None = None) -> list[tuple[np.ndarray, np.ndarray]]:
    """(world_from_cam, world_from_target) candidates for one relative pose; a static
    target sits at ``mount_from_target`` (4, 4; its fixture, default none) on its mount."""
    target_holder, camera_holder = facility.holder("target"), facility.holder("camera")
    if isinstance(target_holder, StaticSpec):
        world_from_target = pose_matrix(target_holder.world_from_mount) @ (
            np.eye(4) if mount_from_target is None else mount_from_target)
        return [(world_from_target @ g.invert(cam_from_target), world_from_target)]
    if isinstance(camera_holder, StaticSpec):
        world_from_cam = pose_matrix(camera_holder.world_from_mount)
        return [(world_from_cam, world_from_cam @ cam_from_target)]
    away = g.invert(cam_from_target)[:3, 3]  # the camera in the target frame
    room = np.asarray(facility.spec.room_m)
    out = []
    for _ in range(attempts):
        point = points[rng.integers(len(points))]
        direction = _direction_in_room(point, np.linalg.norm(away), room, rng)
        if direction is None:
            continue
        roll = g.rotvec_to_matrix(direction * rng.uniform(-np.pi, np.pi))
        world_from_target = g.make_transform(roll @ _aligning(away / np.linalg.norm(away), direction), point)
        out.append((world_from_target @ g.invert(cam_from_target), world_from_target))
    return out


def _direction_in_room(point: np.ndarray, distance: float, room: np.ndarray, rng: np.random.Generator,
                       draws: int = 64) -> np.ndarray | None:
    """A unit direction, uniform over those that keep ``point + distance * direction`` inside
    the room with the clearance; None when ``draws`` draws find none."""
    directions = rng.normal(size=(draws, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    ends = point + distance * directions
    inside = np.all((ends >= CLEARANCE_M) & (ends <= room - CLEARANCE_M), axis=1)
    return directions[int(np.argmax(inside))] if inside.any() else None


def _aligning(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(3, 3) the smallest rotation taking unit vector a to unit vector b."""
    axis = np.cross(a, b)
    sine, cosine = np.linalg.norm(axis), float(a @ b)
    if sine < 1e-12:
        if cosine > 0:
            return np.eye(3)
        other = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
        return g.rotvec_to_matrix(np.pi * other / np.linalg.norm(other))
    return g.rotvec_to_matrix(axis / sine * math.atan2(sine, cosine))


def presentation_points(facility: Facility, rng: np.random.Generator, count: int = 64) -> np.ndarray:
    """(N, 3) points in K where the target's robot holds the target, drawn over its joint
    ranges (rail too) and kept where they are a metre clear of the walls, floor and ceiling
    (or half the room's side, where that is less)."""
    holder = facility.holder("target")
    if isinstance(holder, StaticSpec):
        return np.asarray([holder.world_from_mount.t])
    room = np.asarray(facility.spec.room_m)
    clearance = np.minimum(1.0, room / 4)
    points = []
    for _ in range(50):
        joints = rng.uniform(holder.chain.lower, holder.chain.upper, size=(256, holder.chain.dof))
        rail = rng.uniform(*holder.rail_travel_m, size=256) if holder.spec.rail is not None else np.zeros(256)
        world_from_tool = (pose_matrix(holder.spec.world_from_base) @ holder.chain.forward(joints)
                           @ pose_matrix(holder.spec.flange_from_tool))
        if holder.spec.rail is not None:
            world_from_tool[:, :3, 3] += rail[:, None] * np.asarray(holder.spec.rail.axis)
        found = world_from_tool[:, :3, 3]
        points += list(found[np.all((found >= clearance) & (found <= room - clearance), axis=1)])
        if len(points) >= count:
            break
    if not points:
        raise FacilityError(f"{facility.directory / 'facility.toml'}: robot {holder.spec.name!r} never holds the "
                            "target a metre clear of the room's walls, floor and ceiling; check world_from_base_t")
    return np.asarray(points[:count])


def presented_share(rows: list[dict], name: str) -> str:
    """What share of the relative poses drawn for the dataset (uniform on SO(3) and over the
    range) the facility ``name`` presented, with its 95% Wilson interval, and the views it showed."""
    dataset = [row for row in rows if row["session"] == "dataset"]
    drawn = len(dataset) + sum(row["redraws"] for row in dataset)
    if not dataset:
        return f"{name}: no dataset samples"
    sequences = {row["sequence_id"]: row["redraws"] for row in dataset if row.get("sequence_id") is not None}
    if sequences:  # a sequence is held whole or re-planned whole (stages/plan/trajectory.py)
        return (f"{name} held every frame of {len(sequences)} sequence(s), {len(dataset)} frames, after "
                f"{sum(sequences.values())} re-plan(s) of their initial attitude")
    low, high = wilson(len(dataset), drawn)
    views = Counter(row["view"] for row in dataset)
    return (f"{name} presented {len(dataset)} of {drawn} dataset poses drawn, "
            f"{len(dataset) / drawn:.1%} [95% interval {low:.1%}, {high:.1%}] of SO(3) x the range; the dataset "
            f"is uniform over that share; views {', '.join(f'{v} {n}' for v, n in sorted(views.items()))}")
