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
