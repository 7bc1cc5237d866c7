"""Whether the image can support a decoded pose: the target, drawn at that pose, must lie
in the crop the model saw and be about the crop's size.

A keypoint model's crop is ``CROP_MARGIN`` times a box of the target (the label's, or the
one its own passes found), so any pose it supports puts the target's keypoints inside
that crop at roughly the box's size. A pose that does not has been made by the decoding,
not seen: EPnP on scattered keypoints when RANSAC finds no consensus, at 34 times the
distance (``reference_augmented`` on img000044 of a default run). Such a pose is refused
and the image scored as one without a pose: the worst case, ``e_q = pi`` and ``e_t = 1``
(a miss is a miss; dropping it would reward a model for refusing). That bounds each
image's share of a mean at ``(pi + 1) / n``, where an absurd pose had none.

The bounds: the projected box's centre inside the crop (a square of ``CROP_MARGIN`` times
the box's larger side), and its larger side within ``SIZE_RATIO`` of the box's. A model
of whole images (``full``) saw the whole image: the target's centre must be in it, and no
size is implied.
"""

from __future__ import annotations

import numpy as np

from stages.common import geometry as g
from stages.common.keypoint_pnp import PnPSolution
from stages.common.model_contract import CROP_MARGIN
from stages.common.model_input import points_box

#: the projected target's box's larger side over the crop box's, outside which a pose is
#: refused: a target half the box's size or twice it is not what the crop showed
SIZE_RATIO = (0.5, 2.0)


def refusal(solution: PnPSolution, keypoints_m: np.ndarray, box: np.ndarray | None, camera_matrix: np.ndarray,
            dist: np.ndarray, width: int, height: int) -> str | None:
    """Why the image cannot support ``solution`` (None: it can). ``keypoints_m`` (K, 3) of
    the target; ``box`` (x_min, y_min, x_max, y_max) [px] the crop was made around (None:
    the whole image of ``width`` x ``height`` px)."""
    if not (np.all(np.isfinite(solution.t)) and solution.t[2] > 0):
        return "the target behind the camera"
    points = g.project(g.transform_from_qt(solution.q, solution.t), keypoints_m, camera_matrix, dist)
    if not np.all(np.isfinite(points)):
        return "the target does not project"
    drawn = points_box(points)
    centre = (drawn[:2] + drawn[2:]) / 2
    if box is None:
        if not (0 <= centre[0] <= width and 0 <= centre[1] <= height):
            return "the target's centre outside the image"
        return None
    side = max(float(np.max(box[2:] - box[:2])), 1.0)
    if np.any(np.abs(centre - (box[:2] + box[2:]) / 2) > CROP_MARGIN * side / 2):
        return "the target's centre outside the crop"
    ratio = float(np.max(drawn[2:] - drawn[:2])) / side
    if not SIZE_RATIO[0] <= ratio <= SIZE_RATIO[1]:
        return f"the target {ratio:.2f} times the crop box's size (outside {SIZE_RATIO[0]}-{SIZE_RATIO[1]})"
    return None
