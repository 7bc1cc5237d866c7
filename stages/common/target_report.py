"""What ``speedplus target DIR`` prints of a target folder: its parts and looks, its size at
full scale and as the mock-up, its keypoints (declared, or chosen on the mesh), its views,
where the motion-capture markers go and the accuracy to expect of them, and the symmetries
that make its keypoints ambiguous (docs/user-guide.md, "Your own target (a target folder)")."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from core.config import Config
from stages.common.marker_fit import expected_accuracy
from stages.common.markers import markers
from stages.common.symmetry import ambiguities
from stages.common.target import load_target
from stages.common.workspace_target import SPEEDPLUS_RANGE_M, apparent_size_ratio


def describe(folder: Path, config: Config) -> tuple[str, list[tuple[str, str]]]:
    """A table's title and its (what, value) rows; an error naming the file and key when
    the folder cannot be used. ``config``: the default profile's (its motion capture and
    plan give the expected accuracy)."""
    target = load_target(folder)
    placed = markers(target)
    ambiguous = ambiguities(target)
    vertices = sum(len(p.vertices) for p in target.parts.values())
    triangles = sum(len(p.faces) for p in target.parts.values())
    rows = [("parts", ", ".join(f"{name} ({target.looks[name].synthetic} / {target.looks[name].mockup})"
                                if name in target.looks else name for name in target.parts)),
            ("mesh", f"{vertices} vertices, {triangles} triangles"),
            ("diameter", f"{target.diameter_m:.4g} m full scale, {target.diameter_m * target.mockup_scale:.4g} m "
                         f"mock-up (scale {target.mockup_scale:g}, {target.mockup_mass_kg:g} kg)"),
            ("body centre", f"({', '.join(f'{v:.4f}' for v in target.centre_m)}) m; bounding sphere "
                            f"{target.radius_m:.4g} m"),
            ("keypoints", f"{len(target.keypoints_m)}, "
                          + ("chosen on the mesh (farthest corners of its convex hull)" if target.keypoints_chosen
                             else "declared")),
            ("views", f"{target.view_names[0]} / {target.view_names[1]}: the camera's side of the plane "
                      f"through the centre normal to ({', '.join(f'{v:.3f}' for v in target.view_axis)})"),
            ("motion-capture markers", f"{len(placed.centres_m)} "
             + (f"chosen on parts {', '.join(dict.fromkeys(placed.parts))} for the best fit over the whole target"
                if placed.chosen else "declared")
             + "; centres on the mock-up, body frame (mm): "
             + "; ".join("(" + ", ".join(f"{v * 1000:.1f}" for v in c) + ")" for c in placed.centres_m)),
            ("motion capture to expect", _expected_mocap(target, placed, config)),
            ("symmetries", "; ".join(
                f"{a.symmetry} maps the mesh onto itself and moves keypoints "
                f"({', '.join(f'{i}<->{j}' for i, j in a.swapped)}"
                + (f"{', ' if a.swapped else ''}{', '.join(map(str, a.unmatched))} onto none" if a.unmatched else "")
                + ")" for a in ambiguous)
             + (": a pose and the pose so turned look the same, and no model of the images can tell them apart; "
                "declare it in [symmetries] (BOP's metrics then score them alike; the SPEED score does not), or give "
                "the mock-up a feature that breaks it" if ambiguous
                else "none moves a keypoint (half and quarter turns about the body axes, and the declared ones)")),
            ("digest", target.digest[:16])]
    return f"target {target.name} ({folder})", rows


def _expected_mocap(target: Any, placed: Any, config: Config) -> str:
    """``speedplus target``'s motion-capture accuracy at the plan's default range, with the
    default profile's motion capture (``stages.common.marker_fit.expected_accuracy``)."""
    v = config.virtual
    ranges = tuple(r * apparent_size_ratio(target) * target.mockup_scale for r in SPEEDPLUS_RANGE_M)
    accuracy = expected_accuracy(placed.centres_m, placed.normals, np.zeros(3),
                                 v.vicon_marker_sigma_m * v.vicon_model_noise_factor, np.asarray(v.camera_markers_m),
                                 v.vicon_marker_sigma_m, config.fuse.vicon_scale_sigma,
                                 float(np.mean(config.plan.calibration_distance_m)), ranges)
    untracked = (f"; from {accuracy.untracked_share:.0%} of attitudes fewer than three markers are seen"
                 if accuracy.untracked_share > 0 else "")
    return (f"{accuracy.total_m[0] * 1000:.2f}-{accuracy.total_m[1] * 1000:.2f} mm (3D RMS of the target's origin) at "
            f"{ranges[0]:.2f}-{ranges[1]:.2f} m, the plan's default range before the room's limit: its markers' fit "
            f"{accuracy.fit_position_m * 1000:.2f} mm and {accuracy.fit_rotation_rad * 1000:.2f} mrad (median over "
            f"attitudes{untracked}), the camera body's pointing {accuracy.pointing_rad * 1000:.2f} mrad, the wand's "
            f"scale; with the default profile's marker noise, {v.vicon_marker_sigma_m * 1000:.2f} mm "
            f"(x{v.vicon_model_noise_factor:g} on the mock-up)")
