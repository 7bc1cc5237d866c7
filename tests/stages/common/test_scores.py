"""SPEED / SPEED+ scores: hand-computed cases, thresholds, q and -q, normalisation."""

import numpy as np
import pytest

from stages.common import geometry as g
from stages.common.scores import (
    ROTATION_THRESHOLD_RAD,
    TRANSLATION_THRESHOLD,
    rotation_error,
    score,
    speedplus_score,
    translation_error,
)


def test_hand_computed_case():
    q_true = np.array([1.0, 0.0, 0.0, 0.0])
    q_pred = g.rotvec_to_quat([0.0, 0.0, np.radians(10.0)])  # 10 degrees about z
    t_true, t_pred = np.array([0.0, 0.0, 10.0]), np.array([0.3, 0.4, 10.0])  # 0.5 m off at 10 m
    result = score(q_pred, t_pred, q_true, t_true)
    assert result["err_q_rad"] == pytest.approx(np.radians(10.0))
    assert result["err_t_norm"] == pytest.approx(0.05)
    assert result["score_speed"] == pytest.approx(np.radians(10.0) + 0.05)
    assert result["score_speedplus"] == pytest.approx(np.radians(10.0) + 0.05)


def test_q_and_minus_q_are_the_same_rotation():
    rng = np.random.default_rng(0)
    q = g.random_quats(rng, 100)
    other = g.random_quats(rng, 100)
    np.testing.assert_allclose(rotation_error(q, -q), 0.0, atol=1e-7)
    np.testing.assert_allclose(rotation_error(-q, other), rotation_error(q, other), atol=1e-12)
    np.testing.assert_allclose(rotation_error(q, other), g.quat_angular_distance(q, other), atol=1e-7)


def test_translation_error_is_normalised_by_the_true_distance():
    assert translation_error([0.0, 0.0, 21.0], [0.0, 0.0, 20.0]) == pytest.approx(0.05)
    assert translation_error([0.0, 0.0, 6.0], [0.0, 0.0, 5.0]) == pytest.approx(0.2)
    # the predicted distance does not normalise
    assert translation_error([0.0, 0.0, 5.0], [0.0, 0.0, 6.0]) == pytest.approx(1 / 6)


def test_speedplus_thresholds_are_strict():
    below_q, below_t = np.nextafter(ROTATION_THRESHOLD_RAD, 0), np.nextafter(TRANSLATION_THRESHOLD, 0)
    assert speedplus_score(below_q, below_t) == 0.0
    at = speedplus_score(ROTATION_THRESHOLD_RAD, TRANSLATION_THRESHOLD)
    assert at == pytest.approx(ROTATION_THRESHOLD_RAD + TRANSLATION_THRESHOLD)  # at the threshold: counted
    assert speedplus_score(below_q, 0.01) == pytest.approx(0.01)
    assert speedplus_score(0.02, below_t) == pytest.approx(0.02)
    assert np.isclose(ROTATION_THRESHOLD_RAD, np.radians(0.169), rtol=1e-12)


def test_perfect_prediction_scores_zero():
    q = g.random_quats(np.random.default_rng(1), 5)
    t = np.array([[0.1, -0.2, 8.0]] * 5)
    result = score(q, t, q, t)
    assert np.all(result["score_speed"] < 1e-7) and np.all(result["score_speedplus"] == 0)
