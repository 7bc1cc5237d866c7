"""A ROS 2 bag's measurements as time series, and their values at a capture's stamp
(``stages/acquire/rosbag.py``): the joints of each arm, the rail, each /tf edge, each
motion-capture body.

A capture takes a value at its stamp only where the robots stood still: over the window
``[t - still_s, t + exposure_s]`` the series must have a message at or before its start and
one at or after its end, and every message from the one to the other must lie within the
tolerance of the first (joints in rad or m, poses by their translation in m and their
turn in rad). The value at ``t`` is then interpolated between the two messages about it.
A series that moved is refused naming the capture and what moved; one that does not
cover the window is a capture without that measurement.
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass, field

import numpy as np

from stages.common import geometry as g

NS = 1_000_000_000


def seconds(ns: int) -> str:
    """A stamp (ns) as seconds to the nanosecond, without a float's rounding."""
    return f"{'-' if ns < 0 else ''}{abs(ns) // NS}.{abs(ns) % NS:09d}"


@dataclass
class Series:
    """One measured quantity over the bag: header stamps (ns, non-decreasing), values
    (joint positions (J,) in rad or m, or poses (4, 4) in m), and the recorder's times."""

    name: str  # the topic, and the joint set or frame pair, as errors name it
    pose: bool
    stamps: list[int] = field(default_factory=list)
    values: list[np.ndarray] = field(default_factory=list)
    logged: list[int] = field(default_factory=list)

    def add(self, stamp: int, value: np.ndarray, logged: int) -> None:
        self.stamps.append(stamp)
        self.values.append(value)
        self.logged.append(logged)

    def clock_problem(self, jump_s: float) -> str | None:
        """Why this series' clock cannot be trusted: a stamp before the one before it, or a
        step of the stamps against the recorder's times of more than ``jump_s``."""
        if not self.stamps:
            return None
        stamps, logged = np.asarray(self.stamps, dtype=np.int64), np.asarray(self.logged, dtype=np.int64)
        back = np.flatnonzero(np.diff(stamps) < 0)
        if len(back):
            i = int(back[0])
            return (f"{self.name}: stamp {seconds(int(stamps[i + 1]))} s comes after {seconds(int(stamps[i]))} s: the "
                    "clock went back")
        lag = logged - stamps
        steps = np.flatnonzero(np.abs(np.diff(lag)) > jump_s * NS)
        if len(steps):
            i = int(steps[0])
            return (f"{self.name}: at stamp {seconds(int(stamps[i + 1]))} s the stamps stepped "
                    f"{(lag[i] - lag[i + 1]) / NS:+.3f} s against the recording's clock (more than clock_jump_s "
                    f"{jump_s:g})")
        return None

    def moved(self, first: int, last: int) -> tuple[float, float]:
        """How far the values ``first..last`` stray from the first: (largest joint or
        translation change, largest turn in rad; 0 for joints)."""
        reference = self.values[first]
        span = self.values[first:last + 1]
        if not self.pose:
            return float(np.max(np.abs(np.asarray(span) - reference))), 0.0
        shift = max(float(np.linalg.norm(v[:3, 3] - reference[:3, 3])) for v in span)
        turn = max(float(g.angular_distance(v[:3, :3], reference[:3, :3])) for v in span)
        return shift, turn

    def interpolate(self, stamp: int) -> np.ndarray:
        """The value at ``stamp``, linear between the messages about it (poses: their
        translation linear, their rotation along the geodesic)."""
        after = bisect.bisect_left(self.stamps, stamp)
        if after < len(self.stamps) and self.stamps[after] == stamp or after == 0:
            return self.values[min(after, len(self.values) - 1)]
        if after == len(self.stamps):
            return self.values[-1]
        a, b = self.values[after - 1], self.values[after]
        share = (stamp - self.stamps[after - 1]) / (self.stamps[after] - self.stamps[after - 1])
        if not self.pose:
            return a + share * (b - a)
        turn = g.rotvec_to_matrix(share * g.matrix_to_rotvec(a[:3, :3].T @ b[:3, :3]))
        return g.make_transform(a[:3, :3] @ turn, a[:3, 3] + share * (b[:3, 3] - a[:3, 3]))


@dataclass(frozen=True)
class Window:
    """Where a capture's measurements are taken: its stamp, and the window the robots
    stood still over (ns)."""

    stamp: int
    start: int
    end: int


def still_value(series: Series, window: Window, tolerance: float, tolerance_rad: float,
                max_gap: int) -> np.ndarray | str:
    """The series' value at the window's stamp where it stood still over the window; else
    why not, in words (beginning "moved" where it moved, "no message" where it does not
    cover the window with messages at most ``max_gap`` ns apart)."""
    first = bisect.bisect_right(series.stamps, window.start) - 1
    last = bisect.bisect_left(series.stamps, window.end)
    gaps = np.diff(series.stamps[max(first, 0):last + 1]) if first >= 0 and last < len(series.stamps) else [np.inf]
    if first < 0 or last >= len(series.stamps) or np.max(gaps, initial=0) > max_gap:
        return (f"no message of {series.name} covers [{seconds(window.start)}, {seconds(window.end)}] s (the "
                f"robots' stand still before and through the exposure) at most {max_gap / NS:g} s apart")
    shift, turn = series.moved(first, last)
    if shift > tolerance or turn > tolerance_rad:
        what = f"{shift:.3g} (tolerance {tolerance:g})" if shift > tolerance else \
            f"{turn:.3g} rad (tolerance {tolerance_rad:g})"
        return f"moved: {series.name} changed by {what} within [{seconds(window.start)}, {seconds(window.end)}] s"
    return series.interpolate(window.stamp)


def nearest_value(series: Series, stamp: int, max_gap: int) -> np.ndarray | None:
    """A body's pose at ``stamp`` between the messages about it, each within ``max_gap`` ns
    of it (one alone where the other is farther); None: not tracked then."""
    after = bisect.bisect_left(series.stamps, stamp)
    near = [i for i in (after - 1, after) if 0 <= i < len(series.stamps) and abs(series.stamps[i] - stamp) <= max_gap]
    if not near:
        return None
    if len(near) == 2:
        return series.interpolate(stamp)
    return series.values[near[0]]


class FrameTree:
    """/tf and /tf_static: each child frame's parent and the edge's series (dynamic) or
    pose (static), and the poses of frames below a root at a window's stamp. What is wrong
    with an edge (a second parent, a bad quaternion, static and moving at once) is kept, and
    said only where a mapped chain uses it: a lab's /tf carries edges nobody asked for."""

    def __init__(self) -> None:
        self.parent: dict[str, str] = {}
        self.static: dict[str, np.ndarray] = {}
        self.dynamic: dict[str, Series] = {}
        self.problems: dict[str, str] = {}

    def add(self, parent: str, child: str, pose: np.ndarray | str, stamp: int, logged: int, static: bool,
            topic: str) -> None:
        """Record one transform (``pose``: (4, 4), or what is wrong with it)."""
        known = self.parent.setdefault(child, parent)
        if known != parent:
            self.problems.setdefault(child, f"{topic}: frame {child} has two parents, {known} and {parent}")
        if isinstance(pose, str):
            self.problems.setdefault(child, pose)
            return
        if static:
            self.static[child] = pose
        else:
            self.dynamic.setdefault(child, Series(f"{topic} {parent} -> {child}", True)).add(stamp, pose, logged)
        if child in self.static and child in self.dynamic:
            self.problems.setdefault(child, f"frame {child} is on /tf_static and on /tf: fixed or moving?")

    def frames(self) -> set[str]:
        return set(self.parent) | set(self.parent.values())

    def chain(self, root: str, frame: str, jump_s: float = float("inf")) -> list[str] | str:
        """The frames from below ``root`` down to ``frame``, each edge's problems (and its
        clock's, against ``jump_s``) checked; else why not."""
        if frame not in self.frames():
            return f"frame {frame} is not in /tf or /tf_static"
        path, at = [], frame
        while at != root:
            if at not in self.parent:
                return f"frame {frame} is not below {root} in /tf (its root is {at})"
            if at in path:
                return f"/tf holds a loop through frame {at}"
            problem = self.problems.get(at) or (self.dynamic[at].clock_problem(jump_s) if at in self.dynamic
                                                else None)
            if problem:
                return problem
            path.append(at)
            at = self.parent[at]
        return path[::-1]

    def pose(self, chain: list[str], window: Window, tolerance_m: float, tolerance_rad: float,
             max_gap: int) -> np.ndarray | str:
        """``root_from_frame`` (4, 4) down ``chain`` at the window's stamp, every moving edge
        still over the window; else why not."""
        root_from = np.eye(4)
        for child in chain:
            if child in self.static:
                edge: np.ndarray | str = self.static[child]
            else:
                edge = still_value(self.dynamic[child], window, tolerance_m, tolerance_rad, max_gap)
            if isinstance(edge, str):
                return edge
            root_from = root_from @ edge
        return root_from

    def pose_near(self, chain: list[str], stamp: int, max_gap: int) -> np.ndarray | None:
        """``root_from_frame`` down ``chain`` from the messages within ``max_gap`` ns of
        ``stamp`` (a motion-capture body: None where it was not tracked then)."""
        root_from = np.eye(4)
        for child in chain:
            edge = self.static.get(child)
            if edge is None:
                edge = nearest_value(self.dynamic[child], stamp, max_gap)
            if edge is None:
                return None
            root_from = root_from @ edge
        return root_from
