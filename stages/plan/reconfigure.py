"""Testbed reconfiguration: world poses of both flanges and the rail position that realise
a relative pose ``cam_from_target``, reachable by both arms.

Free choices (the relative pose fixes only 6 of the 13 degrees of freedom): where the
target robot presents the model, the direction of the line of sight in the room, the
camera's roll about that line, and where the rail puts the camera robot. A grid of these
is evaluated at once: the rules that need no joints first, then closed-form inverse
kinematics for the candidates they leave; the candidate whose joints stay farthest from
their limits wins. Rules that every returned candidate obeys:

- both arms reach their flange poses within joint limits (with a margin);
- the rail position lies on the rail;
- the camera and both flanges keep a clearance from the walls, floor and ceiling;
- the target robot's base and the model's fixture are on the far side of the model as
  seen from the camera (dataset session), so the arm never stands in the line of sight.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from core.config import TestbedConfig
from stages.common import geometry as g
from stages.common import layout
from stages.common.kinematics import ArmModel, arm_model, limit_margin, solve
from stages.common.target import Target
from stages.plan.config import PlanConfig


@dataclass(frozen=True)
class Reconfiguration:
    """Commands for one sample (metres, radians, frame K)."""

    rail_m: float
    camera_joints_rad: np.ndarray  # (6,)
    target_joints_rad: np.ndarray  # (6,)
    world_from_camee: np.ndarray  # (4, 4)
    world_from_targetee: np.ndarray  # (4, 4)
    margin_rad: float


def _frame_from_direction(direction: np.ndarray) -> np.ndarray:
    """Orthonormal columns (..., 3, 3) whose first column is ``direction`` (..., 3)."""
    first = direction / np.linalg.norm(direction, axis=-1, keepdims=True)
    helper = np.where(np.abs(first[..., 2:3]) < 0.9, [0.0, 0.0, 1.0], [1.0, 0.0, 0.0])
    second = np.cross(first, helper)
    second /= np.linalg.norm(second, axis=-1, keepdims=True)
    return np.stack([first, second, np.cross(first, second)], axis=-1)


def _sight_directions(plan: PlanConfig) -> np.ndarray:
    """Unit vectors (S, 3) in K from the camera towards the model: the camera is further
    along +x (down the rail) and above the model."""
    elevation, azimuth = np.meshgrid(plan.sight_elevations_rad, plan.sight_azimuths_rad, indexing="ij")
    elevation, azimuth = elevation.ravel(), azimuth.ravel()
    return np.stack([-np.cos(elevation) * np.cos(azimuth), -np.cos(elevation) * np.sin(azimuth),
                     -np.sin(elevation)], axis=-1)


def _orientations(sight_cam: np.ndarray, plan: PlanConfig, testbed: TestbedConfig,
                  previous: Reconfiguration | None) -> tuple[np.ndarray, np.ndarray]:
    """Candidate lines of sight in K (S, 3) and camera attitudes ``world_from_cam`` (S, R, 3, 3)
    that map the model's direction in the camera frame (``sight_cam``, (3,)) onto each, rolled
    about it; after a ``previous`` frame, one more: the camera keeps its attitude and the
    target robot turns the model."""
    sights = _sight_directions(plan)  # (S, 3)
    rolls = np.linspace(0.0, 2 * np.pi, plan.camera_roll_candidates, endpoint=False)  # (R,)
    frame_cam = _frame_from_direction(sight_cam)  # (3, 3)
    frame_world = _frame_from_direction(sights)  # (S, 3, 3)
    roll_rotation = g.axis_angle_matrix("x", rolls)  # (R, 3, 3)
    world_from_cam_rotation = frame_world[:, None] @ roll_rotation[None] @ frame_cam.T  # (S, R, 3, 3)
    if previous is not None:
        kept = (previous.world_from_camee @ layout.camee_from_cam(testbed))[:3, :3]
        sights = np.concatenate([sights, (kept @ sight_cam)[None]])
        world_from_cam_rotation = np.concatenate([world_from_cam_rotation,
                                                  np.broadcast_to(kept, (1, len(rolls), 3, 3))])
    return sights, world_from_cam_rotation


def _move(previous: Reconfiguration, camera_joints: np.ndarray, target_joints: np.ndarray,
          rail: np.ndarray) -> np.ndarray:
    """Each candidate's move from the previous frame's commands (P, S, R, O): the largest
    joint change of either arm (rad) plus the rail's travel (m)."""
    camera = np.max(np.abs(np.nan_to_num(camera_joints) - previous.camera_joints_rad), axis=-1)
    target = np.max(np.abs(np.nan_to_num(target_joints) - previous.target_joints_rad), axis=-1)[..., None]
    return np.maximum(camera, target) + np.abs(rail - previous.rail_m)


def _camera_arm(arm: ArmModel, world_from_camee: np.ndarray, plan: PlanConfig, testbed: TestbedConfig,
                wanted: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The camera arm's joints (..., O, 6) and whether they reach (..., O) flange poses
    ``world_from_camee`` (..., 4, 4) from each of the plan's rail offsets (O,), on the rail,
    and those rail positions (..., O) in m. Only the candidates where ``wanted`` (...) holds
    are solved (the others: NaN joints, not reached): a caller's rules rule out the rest."""
    offsets = np.asarray(plan.rail_offsets_m)  # (O,)
    rail = world_from_camee[..., None, 0, 3] + offsets - testbed.rail_origin_m[0]
    on_rail = (rail >= 0.0) & (rail <= testbed.rail_length_m)
    base_camera = layout.world_from_camera_base(testbed, np.clip(rail, 0.0, testbed.rail_length_m))
    camera_joints, camera_ok = _solve_where(arm, g.invert(base_camera) @ world_from_camee[..., None, :, :],
                                            on_rail & wanted[..., None], plan.joint_limit_margin_rad)
    return camera_joints, camera_ok & on_rail, rail


def _solve_where(arm: ArmModel, base_from_flange: np.ndarray, where: np.ndarray, margin: float
                 ) -> tuple[np.ndarray, np.ndarray]:
    """``kinematics.solve`` of the flange poses (..., 4, 4) where ``where`` (...) holds: joints
    (..., 6), NaN elsewhere, and reachability (...), False elsewhere. A candidate that a
    cheaper rule (the room, the rail, the far side, the other arm) already refused is never
    solved; the callers still apply every rule to what comes back. The closed form works
    pose by pose, so a solved candidate's joints are those of solving them all."""
    joints = np.full(where.shape + (len(arm.lower),), np.nan)
    reachable = np.zeros(where.shape, bool)
    if where.any():
        joints[where], reachable[where] = solve(arm, base_from_flange[where], margin)
    return joints, reachable


def _in_room(world_from_frame: np.ndarray, plan: PlanConfig, testbed: TestbedConfig) -> np.ndarray:
    """Whether frames (..., 4, 4) keep ``plan.wall_clearance_m`` from the room's walls (...)."""
    points, clearance = world_from_frame[..., :3, 3], plan.wall_clearance_m
    return np.all((points >= clearance) & (points <= np.asarray(testbed.room_m) - clearance), axis=-1)


def reconfigure(cam_from_target: np.ndarray, mount: str, plan: PlanConfig, testbed: TestbedConfig,
                target: Target, require_far_side: bool, previous: Reconfiguration | None = None
                ) -> Reconfiguration | None:
    """The best robot/rail commands realising ``cam_from_target`` (4, 4, mock-up scale), or
    None when no candidate is reachable; ``require_far_side``: the target robot's base and
    flange behind the target's body centre, seen from the camera. Best: farthest from the
    joint limits, or, after a ``previous`` frame of a sequence, the smallest move from it
    (the largest joint change, rad, plus the rail's, m), so that a sequence flows."""
    arm = arm_model(testbed.robot_model)
    distance = np.linalg.norm(cam_from_target[:3, 3])
    presentation = np.asarray(testbed.target_presentation_m, dtype=float)  # (P, 3)
    sights, world_from_cam_rotation = _orientations(cam_from_target[:3, 3] / distance, plan, testbed, previous)

    origin = presentation[:, None, None, :]  # (P, 1, 1, 3): the model's origin in K
    camera_position = origin - distance * sights[None, :, None, :]  # (P, S, 1, 3)
    world_from_cam = g.make_transform(world_from_cam_rotation[None], camera_position)  # (P, S, R, 4, 4)
    world_from_target = world_from_cam @ cam_from_target
    world_from_targetee = world_from_target @ layout.target_from_targetee(target, mount)
    world_from_camee = world_from_cam @ g.invert(layout.camee_from_cam(testbed))

    base_target = layout.world_from_target_base(testbed)
    # the rules that need no joints first: the arms solve only what they leave (P, S, R)
    placed = (_in_room(world_from_cam, plan, testbed) & _in_room(world_from_camee, plan, testbed)
              & _in_room(world_from_targetee, plan, testbed))
    if require_far_side:
        sight = sights[None, :, None, :]
        centre = g.apply(world_from_target, (target.centre_m * target.mockup_scale)[None])[..., 0, :]
        base_behind = np.einsum("...i,...i->...", base_target[:3, 3] - centre, sight) > 0
        fixture_behind = np.einsum("...i,...i->...", world_from_targetee[..., :3, 3] - centre, sight) > 0
        placed &= base_behind & fixture_behind
    target_joints, target_ok = _solve_where(arm, g.invert(base_target) @ world_from_targetee, placed,
                                            plan.joint_limit_margin_rad)
    camera_joints, camera_ok, rail = _camera_arm(arm, world_from_camee, plan, testbed, target_ok)
    ok = camera_ok & (target_ok & placed)[..., None]
    if not ok.any():
        return None
    margin = np.minimum(limit_margin(arm, np.nan_to_num(camera_joints)),
                        limit_margin(arm, np.nan_to_num(target_joints))[..., None])
    score = margin if previous is None else -_move(previous, camera_joints, target_joints, rail)
    best = np.unravel_index(np.argmax(np.where(ok, score, -np.inf)), ok.shape)
    p, s, r, o = (int(i) for i in best)
    return Reconfiguration(
        rail_m=float(rail[p, s, r, o]),
        camera_joints_rad=camera_joints[p, s, r, o],
        target_joints_rad=target_joints[p, s, r],
        world_from_camee=world_from_camee[p, s, r],
        world_from_targetee=world_from_targetee[p, s, r],
        margin_rad=float(margin[p, s, r, o]),
    )


def reconfigure_camera(cam_from_target: np.ndarray, held: Reconfiguration, mount: str, plan: PlanConfig,
                       testbed: TestbedConfig, target: Target) -> tuple[int, Reconfiguration] | None:
    """The target arm ``held`` where it is (its joints and flange pose, the model on
    ``mount``) and the camera arm and rail brought to the first of the candidate relative
    poses ``cam_from_target`` (N, 4, 4, mock-up scale) they reach, the camera inside the
    room and the target robot's base beyond the model's centre, seen from the camera (as
    for the ordinary calibration poses, the flange's side is not checked: the board lies on
    the model's top, the fixtures hold its sides): (that candidate's index, its commands),
    or None when none is reached.
    Of its rail offsets, the one farthest from the joint limits."""
    arm = arm_model(testbed.robot_model)
    world_from_target = held.world_from_targetee @ g.invert(layout.target_from_targetee(target, mount))
    world_from_cam = world_from_target @ g.invert(cam_from_target)  # (N, 4, 4)
    world_from_camee = world_from_cam @ g.invert(layout.camee_from_cam(testbed))
    centre = g.apply(world_from_target, (target.centre_m * target.mockup_scale)[None])[0]
    sight = centre - world_from_cam[:, :3, 3]
    base_behind = (layout.world_from_target_base(testbed)[:3, 3] - centre) @ sight.T > 0  # (N,)
    placed = _in_room(world_from_cam, plan, testbed) & _in_room(world_from_camee, plan, testbed) & base_behind
    camera_joints, camera_ok, rail = _camera_arm(arm, world_from_camee, plan, testbed, placed)  # (N, O, ...)
    ok = camera_ok & placed[:, None]
    if not ok.any():
        return None
    first = int(np.argmax(ok.any(axis=1)))
    margin = np.where(ok[first], limit_margin(arm, np.nan_to_num(camera_joints[first])), -np.inf)
    o = int(np.argmax(margin))
    return first, Reconfiguration(
        rail_m=float(rail[first, o]), camera_joints_rad=camera_joints[first, o],
        target_joints_rad=held.target_joints_rad, world_from_camee=world_from_camee[first],
        world_from_targetee=held.world_from_targetee,
        margin_rad=float(min(margin[o], limit_margin(arm, held.target_joints_rad))))
