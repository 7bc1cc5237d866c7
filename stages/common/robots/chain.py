"""A robot arm read from its URDF: the serial chain between two named links, its forward
kinematics and Jacobian, its joint limits and a capsule per link for collision checks
(docs/architecture.md section 11).

The URDF is read by ``stages.common.robots.urdf`` (joint origins, axes, limits, masses and
collision shapes, typed; pytransform3d's ``UrdfTransformManager`` gives a transform graph,
one pose per query, where a planner needs batches). The kinematics are evaluated here, in
numpy, over batches of joint vectors.

Frames: ``base_from_flange`` (..., 4, 4) maps flange coordinates into the base link's
frame; joint values are in the URDF's units (rad, m for a prismatic joint), which for a
URDF written to match its controller (ROS-Industrial's convention) are the controller's.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from speedplus.errors import FileError
from stages.common.robots.urdf import Robot, read_urdf

#: joint types a serial arm may have between base and flange (URDF names)
MOVING = ("revolute", "continuous", "prismatic")
#: a capsule's radius where the URDF gives a link no collision geometry, m
DEFAULT_LINK_RADIUS_M = 0.06


@dataclass(frozen=True)
class Capsule:
    """A segment (a, b, m, in the frame of the joint that moves it) swept by a sphere."""

    joint: int  # the index of the moving joint whose frame holds it; -1: the base link's
    a_m: tuple[float, float, float]
    b_m: tuple[float, float, float]
    radius_m: float


@dataclass(frozen=True)
class LinkMass:
    """A link's mass (the URDF's ``<inertial>``) at its centre (m, in the frame of the joint
    that moves it)."""

    joint: int  # the index of the moving joint whose frame holds it; -1: the base link's
    mass_kg: float
    centre_m: tuple[float, float, float]


@dataclass(frozen=True)
class SerialChain:
    """The moving joints between base and flange, each after the fixed transforms before it."""

    name: str
    source: str  # the URDF file
    joint_names: tuple[str, ...]
    kinds: tuple[str, ...]  # revolute | continuous | prismatic
    #: (J + 1, 4, 4): the fixed transform before each moving joint (a joint's origin, and any
    #: fixed joints before it); the last: from the last moving joint to the flange
    origins: np.ndarray
    axes: np.ndarray  # (J, 3) unit axes in each joint's frame
    lower: np.ndarray  # (J,) rad or m
    upper: np.ndarray  # (J,)
    capsules: tuple[Capsule, ...]
    velocity: np.ndarray | None = None  # (J,) rad/s or m/s, the URDF's <limit velocity>; NaN where absent
    masses: tuple[LinkMass, ...] = ()  # the moving links' <inertial> masses; none where the URDF gives none

    @property
    def dof(self) -> int:
        return len(self.joint_names)

    def frames(self, joints: np.ndarray) -> np.ndarray:
        """(..., J + 1, 4, 4): each moving joint's frame after its motion, then the flange, in
        the base frame, for joints (..., J)."""
        joints = np.asarray(joints, dtype=np.float64)
        motions = self.motions(joints)
        current = np.broadcast_to(np.eye(4), joints.shape[:-1] + (4, 4))
        out = []
        for index in range(self.dof):
            current = current @ self.origins[index] @ motions[..., index, :, :]
            out.append(current)
        out.append(current @ self.origins[-1])
        return np.stack(out, axis=-3)

    def forward(self, joints: np.ndarray) -> np.ndarray:
        """``base_from_flange`` (..., 4, 4) for joints (..., J)."""
        return self.frames(joints)[..., -1, :, :]

    def motion(self, index: int, value: np.ndarray) -> np.ndarray:
        """(..., 4, 4) joint ``index``'s motion by ``value`` (...) rad or m, alone: what
        ``motions`` gives for that joint (the arms' fit calls it a joint at a time, with
        another value per parameter row)."""
        cross, squared, prismatic = self._rodrigues
        return _screw_motions(np.asarray(value, dtype=np.float64), cross[index], squared[index], self.axes[index],
                              prismatic[index])

    def motions(self, joints: np.ndarray) -> np.ndarray:
        """(..., J, 4, 4) every joint's motion by ``joints`` (..., J) rad or m, in one pass
        (the inverse kinematics calls it for every start at every step: a joint at a time
        cost it a third of its time in NumPy's calls)."""
        cross, squared, prismatic = self._rodrigues
        return _screw_motions(np.asarray(joints, dtype=np.float64), cross, squared, self.axes, prismatic)

    @property
    def prismatic(self) -> np.ndarray:
        """(J,) bool: which joints are prismatic."""
        return self._rodrigues[2]

    @property
    def _rodrigues(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The axes' cross-product matrices K (J, 3, 3), K^2 (J, 3, 3), and which joints are
        prismatic (J,) bool: made once per chain."""
        made = self.__dict__.get("_rodrigues_made")
        if made is None:
            cross = np.array([[[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]] for a in self.axes])
            made = cross.reshape(-1, 3, 3), cross.reshape(-1, 3, 3) @ cross.reshape(-1, 3, 3), \
                np.array([kind == "prismatic" for kind in self.kinds], bool)
            object.__setattr__(self, "_rodrigues_made", made)
        return made

    def jacobian(self, joints: np.ndarray) -> np.ndarray:
        """(6, J) geometric Jacobian at one joint vector (J,): rows linear (m) then angular
        (rad) velocity of the flange in the base frame per unit joint rate."""
        frames = self.frames(np.asarray(joints, dtype=np.float64))
        flange = frames[-1, :3, 3]
        columns = []
        for index in range(self.dof):
            axis_base = frames[index, :3, :3] @ self.axes[index]
            if self.kinds[index] == "prismatic":
                columns.append(np.concatenate([axis_base, np.zeros(3)]))
            else:
                columns.append(np.concatenate([np.cross(axis_base, flange - frames[index, :3, 3]), axis_base]))
        return np.stack(columns, axis=1)

    def gravity_torques(self, joints: np.ndarray, gravity_in_base: np.ndarray) -> np.ndarray:
        """(N, J) N m: the generalised gravity force on each joint of the links' own masses,
        ``tau_j = sum_k J_j(c_k)^T m_k g`` (the potential's ``-dU/dq``, as ``statics``), at
        joints (N, J) with gravity's acceleration ``gravity_in_base`` (N, 3) m/s^2 in the
        base frame. Zero where the URDF gives no masses."""
        joints = np.asarray(joints, dtype=np.float64)
        out = np.zeros(joints.shape)
        moving = [m for m in self.masses if m.joint >= 0]
        if not moving:
            return out
        frames = self.frames(joints)  # (N, J + 1, 4, 4)
        for mass in moving:
            held = frames[:, mass.joint]
            centre = held[:, :3, :3] @ np.asarray(mass.centre_m) + held[:, :3, 3]  # (N, 3)
            force = mass.mass_kg * np.asarray(gravity_in_base, float)  # (N, 3)
            for index in range(mass.joint + 1):
                axis = frames[:, index, :3, :3] @ self.axes[index]
                if self.kinds[index] == "prismatic":
                    out[:, index] += np.einsum("ni,ni->n", axis, force)
                else:
                    lever = np.cross(axis, centre - frames[:, index, :3, 3])
                    out[:, index] += np.einsum("ni,ni->n", lever, force)
        return out

    def within_limits(self, joints: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """(...) whether every joint of (..., J) is inside its limits less ``margin``."""
        joints = np.asarray(joints, dtype=np.float64)
        return np.all((joints >= self.lower + margin) & (joints <= self.upper - margin), axis=-1)

    @property
    def reach_bound_m(self) -> float:
        """An upper bound on the flange's distance from the base origin (m): the links'
        lengths and the prismatic joints' travel added up (the triangle inequality)."""
        links = float(np.linalg.norm(self.origins[:, :3, 3], axis=1).sum())
        prismatic = sum(max(abs(lo), abs(hi)) for lo, hi, kind in zip(self.lower, self.upper, self.kinds, strict=True)
                        if kind == "prismatic")
        return links + float(prismatic)

    def reach_m(self, samples: int = 4000, seed: int = 0) -> float:
        """Farthest flange distance from the base over joints drawn within the limits."""
        rng = np.random.default_rng(seed)
        joints = rng.uniform(self.lower, self.upper, size=(samples, self.dof))
        return float(np.linalg.norm(self.forward(joints)[:, :3, 3], axis=-1).max())

    def capsules_in_base(self, joints: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every link capsule at joints (..., J): ends a, b (..., C, 3) in the base frame, radii (C,)."""
        frames = self.frames(joints)
        base = np.broadcast_to(np.eye(4), frames.shape[:-3] + (4, 4))
        held = [base if capsule.joint < 0 else frames[..., capsule.joint, :, :] for capsule in self.capsules]
        def moved(frame: np.ndarray, point: tuple[float, float, float]) -> np.ndarray:
            return frame[..., :3, :3] @ np.asarray(point) + frame[..., :3, 3]

        ends_a = np.stack([moved(frame, c.a_m) for frame, c in zip(held, self.capsules, strict=True)], -2)
        ends_b = np.stack([moved(frame, c.b_m) for frame, c in zip(held, self.capsules, strict=True)], -2)
        return ends_a, ends_b, np.array([c.radius_m for c in self.capsules])


def load_chain(urdf_path: Path, base_link: str, flange_link: str) -> SerialChain:
    """The serial chain from ``base_link`` to ``flange_link`` of a URDF file
    (``stages.common.robots.urdf``); errors name the file and the element (or the line and
    column of an XML error)."""
    path = Path(urdf_path)
    return _chain(path, read_urdf(path), base_link, flange_link)


def _chain(path: Path, robot: Robot, base_link: str, flange_link: str) -> SerialChain:
    links = {link.name: link for link in robot.links}
    for role, name in (("base_link", base_link), ("flange_link", flange_link)):
        if name not in links:
            raise FileError(path, f"no <link name=\"{name}\"> (the facility's {role}); links: "
                                  f"{', '.join(sorted(links)) or 'none'}")
    by_child = {joint.child: joint for joint in robot.joints}
    path_joints = []
    link = flange_link
    while link != base_link:
        joint = by_child.get(link)
        if joint is not None and (joint.parent not in links or any(j is joint for j in path_joints)):
            why = (f"names <parent link=\"{joint.parent}\">, which the file does not hold" if joint.parent not in links
                   else "closes a loop of joints: a serial chain has none")
            raise FileError(path, f"<joint name=\"{joint.name}\"> {why}")
        if joint is None:
            raise FileError(path, f"<link name=\"{flange_link}\"> does not hang below <link name=\"{base_link}\">: "
                                  "no serial chain joins them")
        path_joints.append(joint)
        link = joint.parent
    path_joints.reverse()
    return _assemble(path, robot.name, path_joints, links)


def _assemble(path: Path, name: str, joints: list, links: dict) -> SerialChain:
    origins, axes, kinds, names, lower, upper, velocity = [], [], [], [], [], [], []
    pending = np.eye(4)
    capsules: list[Capsule] = list(_link_capsules(links[joints[0].parent], -1, pending) if joints else [])
    masses: list[LinkMass] = []
    for joint in joints:
        origin = np.eye(4) if joint.origin is None else np.asarray(joint.origin, float)
        pending = pending @ origin
        if joint.type == "fixed":
            capsules += _link_capsules(links[joint.child], len(names) - 1, pending)
            masses += _link_mass(path, links[joint.child], len(names) - 1, pending)
            continue
        if joint.type not in MOVING:
            raise FileError(path, f"<joint name=\"{joint.name}\"> is {joint.type!r}; a serial arm's joints are "
                                  f"{', '.join(MOVING)} or fixed")
        axis = np.asarray(joint.axis if joint.axis is not None else (1.0, 0.0, 0.0), float)
        if np.linalg.norm(axis) < 1e-9:
            raise FileError(path, f"<joint name=\"{joint.name}\">: <axis> is zero")
        low, high = _limits(path, joint)
        origins.append(pending)
        pending = np.eye(4)
        axes.append(axis / np.linalg.norm(axis))
        kinds.append(joint.type)
        names.append(joint.name)
        lower.append(low)
        upper.append(high)
        speed = getattr(joint.limit, "velocity", None) if joint.limit is not None else None
        velocity.append(float(speed) if speed else float("nan"))
        capsules += _link_capsules(links[joint.child], len(names) - 1, np.eye(4))
        masses += _link_mass(path, links[joint.child], len(names) - 1, np.eye(4))
    if not names:
        raise FileError(path, "no moving joint between the base and flange links")
    origins.append(pending)
    chain = SerialChain(name, str(path), tuple(names), tuple(kinds), np.stack(origins), np.stack(axes),
                        np.array(lower), np.array(upper), (), np.array(velocity), tuple(masses))
    covered = {capsule.joint for capsule in capsules}
    return SerialChain(**{**chain.__dict__, "capsules": (*capsules, *_segment_capsules(chain, covered))})


def _limits(path: Path, joint: object) -> tuple[float, float]:
    if joint.type == "continuous":
        return -2 * np.pi, 2 * np.pi
    limit = joint.limit
    if limit is None or limit.lower is None or limit.upper is None:
        raise FileError(path, f"<joint name=\"{joint.name}\">: a {joint.type} joint needs <limit lower upper>")
    if not limit.upper > limit.lower:
        raise FileError(path, f"<joint name=\"{joint.name}\">: <limit> upper {limit.upper} is not above lower "
                              f"{limit.lower}")
    return float(limit.lower), float(limit.upper)


def _link_mass(path: Path, link: object, joint: int, link_in_joint: np.ndarray) -> list[LinkMass]:
    """The link's ``<inertial>`` mass at its centre in the frame of ``joint``; none without one."""
    inertial = getattr(link, "inertial", None)
    if inertial is None or not inertial.mass:
        return []
    if not np.isfinite(inertial.mass) or inertial.mass < 0:
        raise FileError(path, f"<link name=\"{link.name}\">: <mass value> {inertial.mass} is not a mass in kg")
    pose = link_in_joint @ (np.eye(4) if inertial.origin is None else np.asarray(inertial.origin, float))
    return [LinkMass(joint, float(inertial.mass), _point(pose[:3, 3]))]


def _link_capsules(link: object, joint: int, link_in_joint: np.ndarray) -> list[Capsule]:
    """A bounding capsule per collision element of a link (a box or mesh: its longest axis;
    a mesh without a size is left to the joint segments)."""
    out = []
    for collision in link.collisions or []:
        pose = link_in_joint @ (np.eye(4) if collision.origin is None else np.asarray(collision.origin, float))
        shape = collision.geometry
        if shape.cylinder is not None:
            radius, half = shape.cylinder[0], shape.cylinder[1] / 2
            a, b = np.array([0, 0, -half]), np.array([0, 0, half])
        elif shape.sphere is not None:
            a = b = np.zeros(3)
            radius = shape.sphere
        elif shape.box is not None:
            size = np.asarray(shape.box, float)
            long = int(np.argmax(size))
            a, b = np.zeros(3), np.zeros(3)
            a[long], b[long] = -size[long] / 2, size[long] / 2
            radius = float(np.linalg.norm(np.delete(size, long)) / 2)
        else:
            continue
        ends = pose[:3, :3] @ np.stack([a, b]).T + pose[:3, 3:]
        out.append(Capsule(joint, _point(ends[:, 0]), _point(ends[:, 1]), float(radius)))
    return out


def _segment_capsules(chain: SerialChain, covered: set[int]) -> tuple[Capsule, ...]:
    """Where a link has no collision geometry of its own (``covered``: the moving joints whose
    links have some): one capsule from its joint to the next (or to the flange), of
    ``DEFAULT_LINK_RADIUS_M``."""
    capsules = []
    for index in range(chain.dof):
        end = chain.origins[index + 1][:3, 3]
        if index not in covered and np.linalg.norm(end) > 1e-6:
            capsules.append(Capsule(index, (0.0, 0.0, 0.0), _point(end), DEFAULT_LINK_RADIUS_M))
    return tuple(capsules)


def _point(values: np.ndarray) -> tuple[float, float, float]:
    return float(values[0]), float(values[1]), float(values[2])


def _screw_motions(values: np.ndarray, cross: np.ndarray, squared: np.ndarray, axes: np.ndarray,
                   prismatic: np.ndarray | bool) -> np.ndarray:
    """(..., 4, 4) the motions by ``values`` (...) rad or m of joints whose axes' cross-product
    matrices ``K`` and ``K^2`` (..., 3, 3), unit axes (..., 3) and kinds (``prismatic``, ...)
    broadcast with them: Rodrigues' rotation ``I + sin K + (1 - cos) K^2`` about the axis,
    or a translation along it."""
    out = np.zeros(values.shape + (4, 4))
    out[..., 3, 3] = 1.0
    out[..., :3, :3] = (np.eye(3) + np.sin(values)[..., None, None] * cross
                        + (1.0 - np.cos(values))[..., None, None] * squared)
    if np.any(prismatic):
        sliding = np.broadcast_to(prismatic, values.shape)
        out[sliding, :3, :3] = np.eye(3)
        out[..., :3, 3] = np.where(sliding[..., None], values[..., None] * axes, 0.0)
    return out
