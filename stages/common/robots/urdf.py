"""The part of a URDF file (ROS's Unified Robot Description Format, wiki.ros.org/urdf/XML)
that a serial chain needs: links with their ``<inertial>`` mass and ``<collision>`` shapes,
and joints with their type, parent, child, ``<origin>``, ``<axis>`` and ``<limit>``.

Read with the standard library's ElementTree, strictly in what it reads (``<visual>``,
``<inertia>``, ``<dynamics>`` and ``<mimic>`` are not): a number that does not parse, or a
shape without its size, is an error naming the file, the element and the attribute, where
a lenient reader would guess.
Why not yourdfpy (docs/architecture.md section 11): importing it imports trimesh and
networkx (0.65 s), for what is a walk over a few dozen elements; a fresh `speedplus
calibrate` of the smoke profile took 5.4 instead of 5.7 user CPU-s without it. The tests
keep yourdfpy as the independent reader whose forward kinematics and shapes the chain must
reproduce (tests/stages/common/robots/test_chain.py, test_facility.py).

Conventions, from the URDF specification: ``<origin xyz rpy>`` is the child frame in the
parent's, its rotation ``Rz(yaw) Ry(pitch) Rx(roll)`` (fixed axes x, y, z), both defaulting
to zero; ``<axis xyz>`` is in the joint's frame, default (1, 0, 0); ``<limit>`` gives
``lower``, ``upper`` (rad or m) and ``velocity`` (rad/s or m/s), each absent where it is not
written (the chain says which joint needs which).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from xml.etree import ElementTree

import numpy as np

from speedplus.errors import FileError


@dataclass(frozen=True)
class Limit:
    lower: float | None
    upper: float | None
    velocity: float | None


@dataclass(frozen=True)
class Shape:
    """One ``<geometry>``: at most one of box size (3,), cylinder (radius, length), sphere radius."""

    box: np.ndarray | None = None
    cylinder: tuple[float, float] | None = None
    sphere: float | None = None


@dataclass(frozen=True)
class Collision:
    origin: np.ndarray  # (4, 4) the shape in its link's frame
    geometry: Shape


@dataclass(frozen=True)
class Inertial:
    mass: float
    origin: np.ndarray  # (4, 4) the centre of mass in its link's frame


@dataclass(frozen=True)
class Link:
    name: str
    inertial: Inertial | None
    collisions: list[Collision] = field(default_factory=list)


@dataclass(frozen=True)
class Joint:
    name: str
    type: str
    parent: str
    child: str
    origin: np.ndarray  # (4, 4) the joint's frame in its parent link's
    axis: np.ndarray  # (3,) in the joint's frame, as written (not normalised)
    limit: Limit | None


@dataclass(frozen=True)
class Robot:
    name: str
    links: list[Link]
    joints: list[Joint]


def read_urdf(path: Path) -> Robot:
    """The links and joints of the URDF file ``path``; a FileError names the line and column
    of an XML error, or the element and attribute of a value that is not what URDF says."""
    try:
        root = ElementTree.parse(path).getroot()
    except ElementTree.ParseError as error:
        line, column = error.position
        raise FileError(path, f"line {line}, column {column + 1}: not valid XML ({error})") from None
    except OSError as error:
        raise FileError(path, f"cannot be read ({error.strerror or error})") from None
    if root.tag != "robot":
        raise FileError(path, f"the root element is <{root.tag}>, not <robot>")
    reader = _Reader(path)
    return Robot(root.get("name") or path.stem, [reader.link(e) for e in root.findall("link")],
                 [reader.joint(e) for e in root.findall("joint")])


class _Reader:
    def __init__(self, path: Path) -> None:
        self.path = path

    def _fail(self, where: str, why: str) -> FileError:
        return FileError(self.path, f"{where}: {why}")

    def _name(self, element: ElementTree.Element) -> str:
        name = element.get("name")
        if not name:
            raise self._fail(f"<{element.tag}>", "has no name")
        return name

    def _numbers(self, element: ElementTree.Element, attribute: str, count: int, where: str,
                 default: tuple[float, ...] | None = None) -> np.ndarray | None:
        text = element.get(attribute)
        if text is None:
            return None if default is None else np.array(default, float)
        try:
            values = np.array([float(word) for word in text.split()], float)
        except ValueError:
            values = np.zeros(0)
        if len(values) != count or not np.all(np.isfinite(values)):
            raise self._fail(where, f"<{element.tag} {attribute}=\"{text}\"> is not {count} finite number(s)")
        return values

    def _origin(self, parent: ElementTree.Element, where: str) -> np.ndarray:
        """(4, 4) the ``<origin>`` under ``parent``; identity where there is none."""
        element = parent.find("origin")
        pose = np.eye(4)
        if element is None:
            return pose
        xyz = self._numbers(element, "xyz", 3, where, (0.0, 0.0, 0.0))
        roll, pitch, yaw = self._numbers(element, "rpy", 3, where, (0.0, 0.0, 0.0))
        pose[:3, :3] = _rz(yaw) @ _ry(pitch) @ _rx(roll)
        pose[:3, 3] = xyz
        return pose

    def link(self, element: ElementTree.Element) -> Link:
        name = self._name(element)
        where = f"<link name=\"{name}\">"
        inertial = None
        found = element.find("inertial")
        if found is not None and found.find("mass") is not None:
            mass, = self._numbers(found.find("mass"), "value", 1, where, (0.0,))
            inertial = Inertial(float(mass), self._origin(found, where))
        collisions = [Collision(self._origin(c, where), self._shape(c.find("geometry"), where))
                      for c in element.findall("collision")]
        return Link(name, inertial, collisions)

    def _shape(self, geometry: ElementTree.Element | None, where: str) -> Shape:
        """The ``<geometry>``'s one shape (its first child, as URDF has one); sizes required
        and positive. A mesh has no size without loading it: an empty shape."""
        if geometry is None or len(geometry) == 0:
            raise self._fail(where, "a <collision> has no <geometry> shape")
        shape = geometry[0]
        sizes = {"box": ("size", 3), "cylinder": ("radius", 1), "sphere": ("radius", 1)}
        if shape.tag not in sizes:
            return Shape()
        values = {attribute: self._numbers(shape, attribute, count, where)
                  for attribute, count in [sizes[shape.tag]] + ([("length", 1)] if shape.tag == "cylinder" else [])}
        for attribute, value in values.items():
            if value is None or np.any(value <= 0):
                raise self._fail(where, f"<{shape.tag} {attribute}> must be given, positive (m)")
        if shape.tag == "box":
            return Shape(box=values["size"])
        if shape.tag == "cylinder":
            return Shape(cylinder=(float(values["radius"][0]), float(values["length"][0])))
        return Shape(sphere=float(values["radius"][0]))

    def joint(self, element: ElementTree.Element) -> Joint:
        name = self._name(element)
        where = f"<joint name=\"{name}\">"
        kind = element.get("type")
        if not kind:
            raise self._fail(where, "has no type")
        ends = {}
        for tag in ("parent", "child"):
            found = element.find(tag)
            if found is None or not found.get("link"):
                raise self._fail(where, f"has no <{tag} link>")
            ends[tag] = found.get("link")
        axis_element = element.find("axis")
        axis = (np.array([1.0, 0.0, 0.0]) if axis_element is None
                else self._numbers(axis_element, "xyz", 3, where, (1.0, 0.0, 0.0)))
        limit = None
        found = element.find("limit")
        if found is not None:
            lower, upper, velocity = (None if found.get(key) is None else float(self._numbers(found, key, 1, where)[0])
                                      for key in ("lower", "upper", "velocity"))
            limit = Limit(lower, upper, velocity)
        return Joint(name, kind, ends["parent"], ends["child"], self._origin(element, where), axis, limit)


def _rx(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _ry(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _rz(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
