"""SPEED (2019) and SPEED+ (2021) pose scores (docs/architecture.md section 8): Kisantal,
Sharma, Park, Izzo, Märtens and D'Amico, "Satellite Pose Estimation Challenge: Dataset,
Competition Design and Results", IEEE Transactions on Aerospace and Electronic Systems
56(5), 2020 (the SPEED score); Park, Märtens, Lecuyer, Izzo and D'Amico, "SPEED+:
Next-Generation Dataset for Spacecraft Pose Estimation across Domain Gap", IEEE Aerospace
Conference, 2022 (SPEED+ and its thresholds).

``e_q = 2 arccos |<q_pred, q_true>|`` (rad, sign-invariant: q and -q are one rotation),
``e_t = |t_true - t_pred| / |t_true|`` (translation error normalised by the true distance),
SPEED score ``e_q + e_t``; SPEED+ sets each term to zero when it is under its threshold
(strictly below, as the SPEED+ devkit: ``e_q < 0.169 deg``, ``e_t < 2.173e-3``), the
precision with which the testbed's labels are known.

``rotation_error`` is the same angle as ``geometry.quat_angular_distance`` but computed as
the devkits compute it (``arccos`` of the clipped dot product), so that a score here and
the devkit's score of the same prediction agree to the last bit; geometry's
``atan2`` form is the better-conditioned one for small angles and is used everywhere else.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

ROTATION_THRESHOLD_RAD = float(np.radians(0.169))
TRANSLATION_THRESHOLD = 2.173e-3


def rotation_error(q_pred: ArrayLike, q_true: ArrayLike) -> np.ndarray:
    """2 arccos |<q_pred, q_true>| (rad), (...,) for quaternions (..., 4); inputs normalised."""
    q_pred = np.asarray(q_pred, float)
    q_true = np.asarray(q_true, float)
    q_pred = q_pred / np.linalg.norm(q_pred, axis=-1, keepdims=True)
    q_true = q_true / np.linalg.norm(q_true, axis=-1, keepdims=True)
    dot = np.clip(np.abs(np.sum(q_pred * q_true, axis=-1)), 0.0, 1.0)
    return 2.0 * np.arccos(dot)


def translation_error(t_pred: ArrayLike, t_true: ArrayLike) -> np.ndarray:
    """|t_true - t_pred| / |t_true| (unitless), (...,) for translations (..., 3)."""
    t_pred = np.asarray(t_pred, float)
    t_true = np.asarray(t_true, float)
    return np.linalg.norm(t_true - t_pred, axis=-1) / np.linalg.norm(t_true, axis=-1)


def speed_score(err_q_rad: ArrayLike, err_t: ArrayLike) -> np.ndarray:
    return np.asarray(err_q_rad, float) + np.asarray(err_t, float)


def speedplus_score(err_q_rad: ArrayLike, err_t: ArrayLike) -> np.ndarray:
    err_q_rad, err_t = np.asarray(err_q_rad, float), np.asarray(err_t, float)
    return (np.where(err_q_rad < ROTATION_THRESHOLD_RAD, 0.0, err_q_rad)
            + np.where(err_t < TRANSLATION_THRESHOLD, 0.0, err_t))


def score(q_pred: ArrayLike, t_pred: ArrayLike, q_true: ArrayLike, t_true: ArrayLike) -> dict[str, np.ndarray]:
    """All four numbers per sample."""
    err_q = rotation_error(q_pred, q_true)
    err_t = translation_error(t_pred, t_true)
    return {"err_q_rad": err_q, "err_t_norm": err_t, "score_speed": speed_score(err_q, err_t),
            "score_speedplus": speedplus_score(err_q, err_t)}
