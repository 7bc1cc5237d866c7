"""What each measurement source measures in a ``captures`` row: ``B_i`` of the RWHE
problem ``A_i X_f = Z B_i`` (``camee_from_targetee`` for the robots, ``camrb_from_targetrb``
for motion capture), and the robots' up direction at the target flange. Shared by
calibrate, which estimates the offsets, and fuse, which applies them."""

from __future__ import annotations

from typing import Any

import numpy as np

from stages.common import geometry as g


def measured_b(row: dict[str, Any], source: str) -> np.ndarray | None:
    """``B_i`` of a capture for a source (4, 4), or None when the source did not measure it."""
    if source == "kuka":
        world_from_camee = g.transform_from_qt(row["kuka_world_from_camee_q"], row["kuka_world_from_camee_t"])
        world_from_targetee = g.transform_from_qt(row["kuka_world_from_targetee_q"],
                                                  row["kuka_world_from_targetee_t"])
        return g.invert(world_from_camee) @ world_from_targetee
    if row["vicon_world_from_camrb_q"] is None or row["vicon_world_from_targetrb_q"] is None:
        return None
    world_from_camrb = g.transform_from_qt(row["vicon_world_from_camrb_q"], row["vicon_world_from_camrb_t"])
    world_from_targetrb = g.transform_from_qt(row["vicon_world_from_targetrb_q"], row["vicon_world_from_targetrb_t"])
    return g.invert(world_from_camrb) @ world_from_targetrb


def up_targetee(row: dict[str, Any], world_up: np.ndarray) -> np.ndarray:
    """The up direction (3,) in the target flange frame at a capture, from the robots' telemetry."""
    return g.quat_to_matrix(row["kuka_world_from_targetee_q"]).T @ np.asarray(world_up, float)
