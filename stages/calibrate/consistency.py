"""Do the detections fit the declared pattern and the robot's motion? Checked before any
solve, so that inconsistent data is refused with a reason instead of calibrated.

Screw congruence (Chen 1991): with ``A_i X_f = Z B_i``, two captures i, j on the same
fixture give ``A_i A_j^-1 = Z (B_i B_j^-1) Z^-1``: the camera's motion between them is the
robot's motion seen from another frame, so both have the same rotation angle and the same
pitch (translation along the rotation axis), whatever ``Z`` and ``X_f`` are. Per image,
the median mismatch over its pairs flags a bad detection (a flipped corner order, another
sub-grid of a larger board); over all pairs, the ratio of pitches measures a wrong square
size or length unit, and ``B^-1`` fitting better than ``B`` a pose file read the wrong way
round.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from stages.common import geometry as g
from stages.common.patterns import PatternSpec
from stages.common.rwhe import motion_rotations, procrustes

#: pairs whose robot rotation is smaller than this say little about the pitch (axis ill-defined)
MIN_PITCH_ANGLE_RAD = np.radians(10.0)
#: near a half turn a rotation vector's sign is ambiguous, and so are its axis and pitch
MAX_AXIS_ANGLE_RAD = np.radians(170.0)
#: pairs that turn less than this keep the length of their translation to within
#: angle x |t_Z| (0.5 deg, 0.2 m: 1.7 mm, under the 10 mm pitch floor)
MAX_STILL_ANGLE_RAD = np.radians(0.5)
MIN_TRAVEL_M = 0.01


def screw(motions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation angle (...) in rad and pitch (...) in m of rigid motions (..., 4, 4)."""
    rotvec = g.matrix_to_rotvec(motions[..., :3, :3])
    angle = np.linalg.norm(rotvec, axis=-1)
    axis = rotvec / np.maximum(angle, 1e-12)[..., None]
    return angle, np.sum(axis * motions[..., :3, 3], axis=-1)


@dataclass(frozen=True)
class Pairs:
    """Screw invariants of every pair (N, N) of camera motions (``a``) and robot motions (``b``)."""

    angle_a: np.ndarray
    angle_b: np.ndarray
    pitch_a: np.ndarray
    pitch_b: np.ndarray
    valid: np.ndarray  # bool: i != j, same fixture
    #: length (m) of each motion's translation: for a pair that does not turn,
    #: ``t_A = R_Z t_B`` keeps it (a grid of positions in one orientation has mostly such pairs)
    travel_a: np.ndarray
    travel_b: np.ndarray

    @classmethod
    def of(cls, a: np.ndarray, b: np.ndarray, fixtures: list[str]) -> Pairs:
        inv_a = np.stack([g.invert(m) for m in a])
        inv_b = np.stack([g.invert(m) for m in b])
        motion_a, motion_b = a[:, None] @ inv_a[None], b[:, None] @ inv_b[None]
        angle_a, pitch_a = screw(motion_a)
        angle_b, pitch_b = screw(motion_b)
        names = np.array(fixtures)
        valid = (names[:, None] == names[None]) & ~np.eye(len(a), dtype=bool)
        return cls(angle_a, angle_b, pitch_a, pitch_b, valid, np.linalg.norm(motion_a[..., :3, 3], axis=-1),
                   np.linalg.norm(motion_b[..., :3, 3], axis=-1))

    def angle_scores(self) -> np.ndarray:
        """Per image (N,): median |angle mismatch| (rad) over its pairs."""
        mismatch = np.where(self.valid, np.abs(self.angle_a - self.angle_b), np.nan)
        return _row_medians(mismatch)

    def axis_pairs(self) -> np.ndarray:
        """(N, N) bool: valid pairs whose robot turn defines an axis (10-170 deg)."""
        return self.valid & (self.angle_b >= MIN_PITCH_ANGLE_RAD) & (self.angle_b <= MAX_AXIS_ANGLE_RAD)

    def pitch_scores(self) -> np.ndarray:
        """Per image (N,): median |pitch mismatch| (m) over its pairs with an axis."""
        return _row_medians(np.where(self.axis_pairs(), np.abs(self.pitch_a - self.pitch_b), np.nan))

    def travel_pairs(self) -> np.ndarray:
        """(N, N) bool: valid pairs that barely turn (at most ``MAX_STILL_ANGLE_RAD``) but
        move at least ``MIN_TRAVEL_M``: their translations have one length for both."""
        return self.valid & (self.angle_b <= MAX_STILL_ANGLE_RAD) & (self.travel_b >= MIN_TRAVEL_M)

    def travel_scores(self) -> np.ndarray:
        """Per image (N,): median |travel mismatch| (m) over its pairs that do not turn."""
        # at least 3 such pairs: one or two say as much about the other image as about this one
        return _row_medians(np.where(self.travel_pairs(), np.abs(self.travel_a - self.travel_b), np.nan), 3)

    def scale(self, keep: np.ndarray) -> tuple[float | None, float, float]:
        """Ratio of camera to robot lengths, the median over the kept images' pairs of the
        ratio of their pitches (pairs that turn, robot pitch at least 1 cm) and of their
        travels (pairs that do not): a median, so that one image paired with a wrong pose
        does not pass for a scale. Also the RMS robot length it rests on (m), and the
        median's standard error: robust (MAD), over as many draws as kept images, since
        the pairs of n images carry about n images' errors. Uncalibrated arms err by
        millimetres, which on centimetre pitches is several percent per pair. None and NaN
        when the lengths are too small to tell."""
        axis = self.axis_pairs() & keep[:, None] & keep[None] & (np.abs(self.pitch_b) >= MIN_TRAVEL_M)
        still = self.travel_pairs() & keep[:, None] & keep[None]
        ratio = np.concatenate([self.pitch_a[axis] / self.pitch_b[axis], self.travel_a[still] / self.travel_b[still]])
        length = np.concatenate([self.pitch_b[axis], self.travel_b[still]])
        spread = float(np.sqrt(np.mean(length**2))) if length.size else 0.0
        if length.size < 6 or spread < 0.02:
            return None, spread, float("nan")
        median = float(np.median(ratio))
        mad = float(np.median(np.abs(ratio - median)))
        # a median's standard error is sqrt(pi / 2) times the mean's; 1.4826 MAD is a sigma
        return median, spread, float(np.sqrt(np.pi / 2) * 1.4826 * mad / np.sqrt(max(int(keep.sum()), 1)))


def rotation_fit(a: np.ndarray, b: np.ndarray, fixtures: list[str]) -> float:
    """How well one camera-side rotation maps the robot's motions onto the camera's: the
    median |log(R_Ai R_Aj^T) - R_Z log(R_Bi R_Bj^T)| (rad) over pairs on one fixture that
    turn by 10-170 deg, R_Z by orthogonal Procrustes (Park and Martin 1994). Screw
    invariants cannot tell ``B`` from ``B^-1``; this can. NaN with fewer than 3 pairs."""
    alphas, betas = motion_rotations(a, b, fixtures, MIN_PITCH_ANGLE_RAD, MAX_AXIS_ANGLE_RAD)
    if len(alphas) < 3:
        return float("nan")
    rotation = procrustes(alphas, betas)
    return float(np.median(np.linalg.norm(alphas - betas @ rotation.T, axis=1)))


def _row_medians(values: np.ndarray, min_count: int = 1) -> np.ndarray:
    out = np.full(len(values), np.nan)
    for i, row in enumerate(values):
        row = row[np.isfinite(row)]
        if row.size >= min_count:
            out[i] = np.median(row)
    return out


def robust_flags(scores: np.ndarray, floor: float, k: float) -> tuple[np.ndarray, float]:
    """Scores (N,) beyond max(floor, median + k robust sigmas), and that threshold."""
    finite = scores[np.isfinite(scores)]
    if not finite.size:
        return np.zeros(len(scores), bool), floor
    median = float(np.median(finite))
    mad = 1.4826 * float(np.median(np.abs(finite - median)))
    limit = max(floor, median + k * mad)
    return np.nan_to_num(scores, nan=0.0) > limit, limit


# ------------------------------------------------------------------- chessboard ordering
def choose_orderings(options: list[list[np.ndarray | None]], b: np.ndarray, fixtures: list[str],
                     max_iterations: int = 10) -> tuple[np.ndarray, np.ndarray]:
    """Which corner labelling of each image agrees with the robot's motion.

    ``options[i][r]`` is image i's PnP pose (4, 4) under labelling r (0: as detected), or
    None. Image 0 keeps its labelling (the gauge); every other image takes the labelling
    whose camera motions best match the robot's rotation angles, first against image 0,
    then against all the others until nothing changes. Returns the labelling (N,) and each
    image's margin (N,): the second-best score over the best (rad), small when the choice
    cannot be decided."""
    n, count = len(options), len(options[0])
    inverse_b = np.stack([g.invert(m) for m in b])
    angle_b = screw(b[:, None] @ inverse_b[None])[0]
    same = (np.array(fixtures)[:, None] == np.array(fixtures)[None]) & ~np.eye(n, dtype=bool)

    def score(i: int, r: int, labels: np.ndarray, among: np.ndarray) -> float:
        pose = options[i][r]
        if pose is None:
            return np.inf
        js = [j for j in np.flatnonzero(among & same[i]) if options[j][labels[j]] is not None]
        if not js:
            return np.inf
        motions = pose[None] @ np.stack([g.invert(options[j][labels[j]]) for j in js])
        return float(np.median(np.abs(screw(motions)[0] - angle_b[i, js])))

    labels = np.zeros(n, dtype=int)
    seed = np.zeros(n, dtype=bool)
    seed[0] = True
    for i in range(1, n):
        if same[i, 0]:
            labels[i] = int(np.argmin([score(i, r, labels, seed) for r in range(count)]))
    everyone = np.ones(n, dtype=bool)
    for _ in range(max_iterations):
        new = labels.copy()
        for i in range(1, n):
            new[i] = int(np.argmin([score(i, r, labels, everyone) for r in range(count)]))
        if np.array_equal(new, labels):
            break
        labels = new
    margins = np.zeros(n)
    for i in range(n):
        scores = sorted(score(i, r, labels, everyone) for r in range(count))
        margins[i] = scores[1] - scores[0] if len(scores) > 1 else np.inf
    return labels, margins


# -------------------------------------------------------------- does the board go on?
def board_continues(image: np.ndarray, pixels: np.ndarray, spec: PatternSpec) -> list[str]:
    """Sides of a detected chessboard grid (N, 2) beyond which the checkerboard goes on.

    The detected inner corners fix a homography from grid units (one square) to pixels.
    A board of the declared size has one row of squares beyond its outermost inner corners,
    then its margin; if the squares one further out still alternate like the board's own
    (at least half its contrast), the printed board is larger than ``spec.size``."""
    w, h = spec.size
    grid = np.stack(np.meshgrid(np.arange(w), np.arange(h)), -1).reshape(-1, 2).astype(np.float32)
    homography, _ = cv2.findHomography(grid, pixels.astype(np.float32))
    if homography is None:
        return []
    grey = image.astype(np.float32)

    def contrast(cells: list[tuple[int, int]]) -> float | None:
        centres = np.array(cells, np.float32) + 0.5
        offsets = np.array([[0, 0], [0.2, 0.2], [-0.2, 0.2], [0.2, -0.2], [-0.2, -0.2]], np.float32)
        points = (centres[:, None] + offsets[None]).reshape(-1, 1, 2)
        projected = cv2.perspectiveTransform(points, homography).reshape(len(cells), -1, 2)
        if (projected < 0).any() or (projected[..., 0] > grey.shape[1] - 1).any() or \
                (projected[..., 1] > grey.shape[0] - 1).any():
            return None
        values = cv2.remap(grey, projected[..., 0].astype(np.float32), projected[..., 1].astype(np.float32),
                           cv2.INTER_LINEAR).mean(axis=1)
        parity = np.array([(i + j) % 2 for i, j in cells])
        if parity.min() == parity.max():
            return None
        return float(values[parity == 0].mean() - values[parity == 1].mean())

    inside = contrast([(i, j) for i in range(-1, w) for j in range(-1, h)])
    if inside is None or abs(inside) < 1e-6:
        return []
    rings = {"left": [(-2, j) for j in range(-1, h)], "right": [(w, j) for j in range(-1, h)],
             "top": [(i, -2) for i in range(-1, w)], "bottom": [(i, h) for i in range(-1, w)]}
    out = []
    for side, cells in rings.items():
        value = contrast(cells)
        if value is not None and value / inside > 0.5:
            out.append(side)
    return out
