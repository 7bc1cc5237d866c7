"""A facility robot's URDF with its identified errors written back (ROS ``robot_calibration``'s
way): the URDF a controller, MoveIt or a planner loads to move the arm as it truly is.

Each moving joint's ``<origin>`` becomes ``origin @ E_k @ M_k(z_k)`` (``errors.py``: the
frame error, then the encoder's zero offset as a turn about, or a shift along, the joint's
axis), so that the URDF's forward kinematics of the controller's readings is the calibrated
arm's. The flange's frame error (mostly the hand-eye offset's, so zero, but a compliant
fixture can keep some of it) goes on the fixed joint before the flange link; where the
flange link hangs straight off the last moving joint there is none, and the error is kept
in the comment at the top with what a URDF cannot hold: the rail's scale and the joints'
compliance.
"""

from __future__ import annotations

import xml.etree.ElementTree as ElementTree
from pathlib import Path

import numpy as np

from manifests.sidecars.arm_fit import RobotCorrection
from stages.common import geometry as g
from stages.common.rwhe import transform_from_vector


def _origin_matrix(joint: ElementTree.Element) -> np.ndarray:
    from scipy.spatial.transform import Rotation
    origin = joint.find("origin")
    if origin is None:
        return np.eye(4)
    xyz = [float(v) for v in origin.get("xyz", "0 0 0").split()]
    rpy = [float(v) for v in origin.get("rpy", "0 0 0").split()]
    return g.make_transform(Rotation.from_euler("xyz", rpy).as_matrix(), xyz)


def _set_origin(joint: ElementTree.Element, pose: np.ndarray) -> None:
    from scipy.spatial.transform import Rotation
    origin = joint.find("origin")
    if origin is None:
        origin = ElementTree.SubElement(joint, "origin")
    rpy = Rotation.from_matrix(pose[:3, :3]).as_euler("xyz")
    origin.set("xyz", " ".join(repr(float(v)) for v in pose[:3, 3]))
    origin.set("rpy", " ".join(repr(float(v)) for v in rpy))


def _motion(joint: ElementTree.Element, value: float) -> np.ndarray:
    axis_element = joint.find("axis")
    axis = np.array([float(v) for v in (axis_element.get("xyz") if axis_element is not None else "1 0 0").split()])
    axis = axis / np.linalg.norm(axis)
    if joint.get("type") == "prismatic":
        return g.make_transform(np.eye(3), value * axis)
    return g.make_transform(g.rotvec_to_matrix(value * axis), np.zeros(3))


def calibrated_urdf(urdf: Path, flange_link: str, correction: RobotCorrection, note: str) -> str:
    """The text of ``urdf`` with ``correction`` written into its joints (the chain ends at
    ``flange_link``); ``note`` says where the values came from."""
    tree = ElementTree.parse(urdf)
    robot = tree.getroot()
    joints = {joint.get("name"): joint for joint in robot.findall("joint")}
    for index, name in enumerate(correction.joints):
        joint = joints[name]
        error = transform_from_vector(np.asarray(correction.frame_errors[index], float))
        _set_origin(joint, _origin_matrix(joint) @ error @ _motion(joint, correction.zero_offsets[index]))
    flange = np.asarray(correction.frame_errors[-1], float)
    last_fixed = _last_fixed_joint(robot, flange_link, set(correction.joints))
    unplaced = ""
    if np.any(flange):
        if last_fixed is not None:
            _set_origin(last_fixed, _origin_matrix(last_fixed) @ transform_from_vector(flange))
        else:
            unplaced = ("flange frame error (rotation vector rad, translation m, after the last joint) "
                        + ", ".join(repr(float(v)) for v in flange))
    kept = [unplaced, f"rail scale error {correction.rail_scale_error!r}" if correction.rail_scale_error is not None
            else "",
            "joint compliance (rad/(N m)) " + ", ".join(f"{j} {c!r}" for j, c in
                                                     zip(correction.joints, correction.compliance_rad_per_nm,
                                                         strict=True)),
            "joint lost motion (rad, backlash plus hysteresis) " + ", ".join(
                f"{j} {c!r}" for j, c in zip(correction.joints, correction.lost_motion_rad, strict=True))]
    comment = ElementTree.Comment(
        f" {note}. Joint zero offsets and frame errors are folded into the joints' origins; not expressible in "
        f"URDF: {'; '.join(k for k in kept if k)} ")
    robot.insert(0, comment)
    ElementTree.indent(tree)
    return '<?xml version="1.0"?>\n' + ElementTree.tostring(robot, encoding="unicode") + "\n"


def _last_fixed_joint(robot: ElementTree.Element, flange_link: str, moving: set[str]) -> ElementTree.Element | None:
    """The fixed joint nearest the flange link after the chain's last moving joint, or None."""
    by_child = {joint.find("child").get("link"): joint for joint in robot.findall("joint")
                if joint.find("child") is not None}
    joint = by_child.get(flange_link)
    if joint is None or joint.get("name") in moving:
        return None
    return joint
