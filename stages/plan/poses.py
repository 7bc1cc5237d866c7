"""Relative poses to capture: the calibration session (camera looking at the ChArUco
board) and the dataset session (SO(3)-uniform orientations, SPEED+-like distances).

All poses are ``cam_from_target`` (4, 4) at mock-up scale, metres, OpenCV camera frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from core.config import CameraConfig, TestbedConfig
from speedplus.errors import InputError
from stages.common import geometry as g
from stages.common import layout
from stages.common.kinematics import arm_model
from stages.common.patterns import board_pattern
from stages.common.target import Target
from stages.common.workspace_target import SPEEDPLUS_RANGE_M, apparent_size_ratio
from stages.plan.config import PlanConfig

#: Draws of a pose that fails a visibility rule before the configuration is declared impossible.
_MAX_VISIBILITY_DRAWS = 1000


class PlanningError(InputError):
    """The configuration asks for poses that cannot be produced."""


def _inside(pixels: np.ndarray, camera: CameraConfig, margin_px: float) -> np.ndarray:
    return ((pixels[..., 0] >= margin_px) & (pixels[..., 0] <= camera.width_px - 1 - margin_px)
            & (pixels[..., 1] >= margin_px) & (pixels[..., 1] <= camera.height_px - 1 - margin_px))


def calibration_pose(rng: np.random.Generator, plan: PlanConfig, testbed: TestbedConfig,
                     camera: CameraConfig, target: Target) -> np.ndarray:
    """A camera pose looking at the board: distance in ``calibration_distance_m``, boresight
    tilted from the board normal by an angle uniform in [0, max tilt], free roll.

    Redrawn until ``calibration_min_corner_fraction`` of the inner corners are in the image.
    """
    target_from_board = layout.target_from_board(testbed, target)
    corners_target = g.apply(target_from_board, board_pattern(testbed, target).object_points())
    centre_board = layout.board_centre(testbed)
    for _ in range(_MAX_VISIBILITY_DRAWS):
        tilt = rng.uniform(0.0, plan.calibration_max_tilt_rad)
        azimuth = rng.uniform(0.0, 2 * np.pi)
        distance = rng.uniform(*plan.calibration_distance_m)
        jitter_radius = plan.calibration_aim_jitter_m * np.sqrt(rng.uniform())
        jitter_angle = rng.uniform(0.0, 2 * np.pi)
        roll = rng.uniform(0.0, 2 * np.pi)
        aim_board = centre_board + jitter_radius * np.array([np.cos(jitter_angle), np.sin(jitter_angle), 0.0])
        # board z points into the board, so the camera sits on the -z side, looking along +z
        outward = np.array([np.sin(tilt) * np.cos(azimuth), np.sin(tilt) * np.sin(azimuth), -np.cos(tilt)])
        position_board = aim_board + distance * outward
        board_from_cam_rotation = g.look_at_rotation(-outward, [0.0, 1.0, 0.0] if tilt < 1.5 else [1.0, 0, 0])
        board_from_cam_rotation = board_from_cam_rotation @ g.axis_angle_matrix("z", roll)
        target_from_cam = target_from_board @ g.make_transform(board_from_cam_rotation, position_board)
        cam_from_target = g.invert(target_from_cam)
        pixels = g.project(cam_from_target, corners_target, camera.camera_matrix(), camera.dist_coeffs())
        in_front = g.apply(cam_from_target, corners_target)[:, 2] > 0
        if np.mean(_inside(pixels, camera, 0.0) & in_front) >= plan.calibration_min_corner_fraction:
            return cam_from_target
    raise PlanningError(
        f"plan.calibration_min_corner_fraction={plan.calibration_min_corner_fraction}: no pose in "
        f"{_MAX_VISIBILITY_DRAWS} draws shows that much of the board; lower it, or the distance/tilt")


def dataset_position(rng: np.random.Generator, plan: PlanConfig, target: Target,
                     camera: CameraConfig, chosen: DatasetRange) -> np.ndarray:
    """Target position in the camera frame (3,), mock-up scale: the full-scale range uniform
    in ``chosen`` (``dataset_range``) and the body's bounding sphere inside the image (with margin)."""
    k = camera.camera_matrix()
    radius = target.radius_m
    low, high = chosen.low_m, chosen.high_m
    for _ in range(_MAX_VISIBILITY_DRAWS):
        distance = rng.uniform(low, high)
        # pinhole radius of the sphere, plus 5% for the lens distortion at the edges
        radius_px = 1.05 * k[0, 0] * np.tan(np.arcsin(min(radius / distance, 1.0)))
        low_u, high_u = plan.image_margin_px + radius_px, camera.width_px - 1 - plan.image_margin_px - radius_px
        low_v, high_v = plan.image_margin_px + radius_px, camera.height_px - 1 - plan.image_margin_px - radius_px
        if low_u > high_u or low_v > high_v:
            continue
        pixel = np.array([rng.uniform(low_u, high_u), rng.uniform(low_v, high_v), 1.0])
        ray = np.linalg.solve(k, pixel)
        centre_cam = distance * ray / np.linalg.norm(ray)
        return centre_cam * target.mockup_scale
    raise PlanningError(
        f"plan.dataset_range_m={list(plan.dataset_range_m)}, plan.dataset_range_diameters="
        f"{list(plan.dataset_range_diameters)}: the target ({target.diameter_m:.3g} m across) does not fit in a "
        f"{camera.width_px}x{camera.height_px} image at {chosen.describe(target)}; "
        + ("the room holds no farther: make the mock-up smaller ([mockup] scale in target.toml)"
           if chosen.origin == "room" else "increase the range"))




@dataclass(frozen=True)
class DatasetRange:
    """The full-scale distance range (m) the plan draws in, and how it was chosen."""

    low_m: float
    high_m: float
    #: "metres" (plan.dataset_range_m as set), "speedplus" (SPEED+'s apparent size) or
    #: "room" (SPEED+'s, shrunk to the farthest the room holds)
    origin: str

    def describe(self, target: Target) -> str:
        """The range in metres (full scale and mock-up) and in the target's diameters."""
        scale, diameter = target.mockup_scale, target.diameter_m
        why = {"metres": "plan.dataset_range_m", "speedplus": "SPEED+'s apparent size",
               "room": "SPEED+'s apparent size does not fit the room: its ratio, at the farthest the room holds"}
        return (f"dataset range {self.low_m:.3g}-{self.high_m:.3g} m full scale = {self.low_m / diameter:.3g}-"
                f"{self.high_m / diameter:.3g} diameters of {target.name} ({diameter:.3g} m); the mock-up "
                f"{self.low_m * scale:.3g}-{self.high_m * scale:.3g} m from the camera ({why[self.origin]})")


def room_reach_m(testbed: TestbedConfig, plan: PlanConfig) -> float:
    """The farthest mock-up distance (m) the room gives a camera on the rail robot from the
    nearest presentation point: along the rail (K's x), to the far wall's clearance or the
    rail's end plus the arm's reach, whichever is nearer. An upper bound: the planner's
    reachability decides each pose."""
    rail_end = testbed.rail_origin_m[0] + testbed.rail_length_m + arm_model(testbed.robot_model).reach_m
    far = min(testbed.room_m[0] - plan.wall_clearance_m, rail_end)
    return far - min(p[0] for p in testbed.target_presentation_m)


def dataset_range(plan: PlanConfig, target: Target, testbed: TestbedConfig, room: bool = True) -> DatasetRange:
    """Where the plan draws distances: ``plan.dataset_range_m`` when set, else SPEED+'s range
    at the same apparent size (scaled by the target's diameter over Tango's; Tango's own is
    SPEED+'s to the bit), shrunk at its ratio when TRON's room cannot hold it (``room``; a
    facility folder's poses are checked one by one instead); then narrowed by
    ``plan.dataset_range_diameters``."""
    origin = "metres"
    if plan.dataset_range_m:
        low, high = plan.dataset_range_m
    else:
        ratio = apparent_size_ratio(target)
        low, high, origin = SPEEDPLUS_RANGE_M[0] * ratio, SPEEDPLUS_RANGE_M[1] * ratio, "speedplus"
        farthest = room_reach_m(testbed, plan) / target.mockup_scale if room else np.inf
        if high > farthest:
            low, high, origin = farthest * SPEEDPLUS_RANGE_M[0] / SPEEDPLUS_RANGE_M[1], farthest, "room"
    low = max(low, plan.dataset_range_diameters[0] * target.diameter_m)
    high = min(high, plan.dataset_range_diameters[1] * target.diameter_m)
    if low > high:
        raise PlanningError(f"plan.dataset_range_m={list(plan.dataset_range_m)} and plan.dataset_range_diameters="
                            f"{list(plan.dataset_range_diameters)} (x {target.diameter_m:.3g} m, the target's "
                            "diameter) do not overlap; open one of them")
    return DatasetRange(low, high, origin)


def dataset_pose(rng: np.random.Generator, plan: PlanConfig, target: Target, camera: CameraConfig,
                 view: str | None, chosen: DatasetRange) -> np.ndarray:
    """``cam_from_target`` (4, 4), mock-up scale: orientation uniform on SO(3) given that
    the camera sees ``view`` (None: either); the body centre placed by ``dataset_position``,
    every keypoint inside the image."""
    centre_cam = dataset_position(rng, plan, target, camera, chosen)
    centre_target = target.centre_m * target.mockup_scale
    keypoints = target.keypoints_m * target.mockup_scale
    for _ in range(_MAX_VISIBILITY_DRAWS):
        rotation = g.quat_to_matrix(g.random_quats(rng, 1)[0])
        cam_from_target = g.make_transform(rotation, centre_cam - rotation @ centre_target)
        camera_in_target = g.invert(cam_from_target)[:3, 3]
        if view is not None and target.view_of(camera_in_target, target.mockup_scale) != view:
            continue  # conditioning on the side keeps SO(3)-uniformity within each half
        pixels = g.project(cam_from_target, keypoints, camera.camera_matrix(), camera.dist_coeffs())
        if np.all(_inside(pixels, camera, plan.image_margin_px)):
            return cam_from_target
    raise PlanningError(f"no {view} pose with the model inside the image; check plan.image_margin_px")


def dataset_configuration(index: int, plan: PlanConfig, views: tuple[str, str]) -> tuple[str, str]:
    """(view, light) of the index-th dataset sample: cycling through the target's ``views``
    x light keeps the configurations balanced (counts differ by at most one) for any
    session length."""
    configurations = [(view, light) for view in views for light in plan.lights]
    return configurations[index % len(configurations)]


def facing_boxes(testbed: TestbedConfig, model_position: np.ndarray, camera_position: np.ndarray) -> list[int]:
    """Light boxes on the camera's side of the model (in K): those that light what the camera sees."""
    centres = np.asarray(testbed.light_box_centres_m)
    towards_camera = camera_position - model_position
    return [i for i, c in enumerate(centres) if np.dot(c - model_position, towards_camera) > 0]


def light_boxes(rng: np.random.Generator, plan: PlanConfig, light: str, candidates: list[int]) -> list[int]:
    """Active light boxes for ``lightbox``: a uniform subset of the configured size of the
    candidates (of all boxes when fewer face the camera's side); none otherwise."""
    if light != "lightbox":
        return []
    low, high = plan.light_boxes_per_sample
    count = int(rng.integers(low, high + 1))
    pool = candidates if len(candidates) >= count else list(range(plan.n_light_boxes))
    return sorted(int(i) for i in rng.choice(pool, size=count, replace=False))


def mount_away_from(cam_from_target: np.ndarray) -> str:
    """The fixture on the side of the model away from the camera (so the target robot is
    never between camera and model)."""
    camera_in_target = g.invert(cam_from_target)[:3, 3]
    return "minus_x" if camera_in_target[0] > 0 else "plus_x"
