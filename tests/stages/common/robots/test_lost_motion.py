"""Which flank each joint rests on (stages/common/robots/lost_motion.py)."""

from stages.common.robots import lost_motion


def test_each_joints_last_move_follows_the_captures_times_not_the_rows_order():
    """The flank a joint rests on is set by its last move: the sign of its reading's change
    from the capture before in time, kept while it stands still; unknown (0) on a session's
    first capture, and everywhere in a session whose captures lack times."""
    def row(sample: str, time_s: float | None, joints: list[float], session: str = "calibration") -> dict:
        return {"sample_id": sample, "session": session, "capture_time_s": time_s,
                "kuka_camera_joints_rad": joints, "kuka_target_joints_rad": None}

    rows = [row("c", 20.0, [0.3, 0.2]), row("a", 0.0, [0.1, 0.1]), row("b", 10.0, [0.2, 0.1 + 1e-6]),
            row("x", None, [0.0, 0.0], "dataset"), row("y", 5.0, [0.1, 0.0], "dataset")]
    out = {r["sample_id"]: r for r in lost_motion.move_directions(rows)}
    assert out["a"]["camera_move_direction"] == [0.0, 0.0]
    assert out["b"]["camera_move_direction"] == [1.0, 0.0]  # the second joint stood still (noise)
    assert out["c"]["camera_move_direction"] == [1.0, 1.0]
    assert out["a"]["target_move_direction"] is None  # no readings: a static mount's
    assert out["y"]["camera_move_direction"] == [0.0, 0.0]  # a session with an untimed capture
    assert "camera_move_direction" not in rows[0]  # the caller's rows are left as they were


def test_the_target_arms_reading_at_the_capture_before_in_time_is_kept():
    """A fixture's play lags behind its tilt's last change: the target's joints before its
    last move, in time (failed captures included), none for the first."""
    rows = [{"sample_id": s, "session": "dataset", "capture_time_s": t, "kuka_camera_joints_rad": [0.0],
             "kuka_target_joints_rad": q, "fixture": f}
            for s, t, q, f in (("b", 9.0, [0.2], "plus_x"), ("a", 1.0, [0.1], "minus_x"), ("c", 12.0, [0.4], "plus_x"),
                               ("d", 15.0, [0.4 + 1e-6], "plus_x"), ("e", 20.0, [0.3], "plus_x"))]
    out = {r["sample_id"]: r for r in lost_motion.move_directions(rows)}
    assert out["a"][lost_motion.BEFORE_KEY] is None
    assert out["b"][lost_motion.BEFORE_KEY] == [0.1]  # across a change of mount: the adapter stays clamped
    assert out["c"][lost_motion.BEFORE_KEY] == [0.2]
    assert out["d"][lost_motion.BEFORE_KEY] == [0.2]  # the target stood still: its fixture keeps its lag
    assert out["e"][lost_motion.BEFORE_KEY] == [0.4 + 1e-6]
