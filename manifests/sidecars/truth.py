"""``W/truth.json``: the hidden truth of the virtual testbed, what a real facility never
tells (docs/architecture.md section 5). Written by acquire's virtual backend; read only by
tests and benchmarks that judge the estimates, never by a stage after acquire."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from manifests.sidecars.base import Fields, Pose, read, save
from manifests.workspace import Workspace

TRUTH_VERSION = 3  # 2: the unmodelled errors' parameters; 3: a facility folder's robots (``facility``)
ARM_LENGTHS = ("a1", "a2", "b", "c1", "c2", "c3", "c4")
POSE_KEYS = ("camera_base_error", "target_base_error", "camee_from_cam", "cam_from_camee", "camee_from_camrb",
             "cam_from_camrb", "target_from_targetrb", "vicon_world_from_world")
#: TRON's arms' truth: null on a facility folder, whose robots' truth is under ``facility``
TRON_KEYS = ("camera_arm", "target_arm", "camera_joint_offsets_rad", "target_joint_offsets_rad",
             "camera_base_error", "target_base_error", "rail_scale")
HOLDER_KEYS = ("robot", "joint_offsets_rad", "joint_origin_errors", "base_error", "rail_scale",
               "stiffness_nm_per_rad")


def _arm(f: Fields, name: str) -> dict[str, Any]:
    arm = f.child(name)
    arm.only("name", "source", *ARM_LENGTHS, "offsets", "signs", "lower", "upper")
    arm.text("name"), arm.text("source")
    for key in ARM_LENGTHS:
        arm.number(key)
    for key in ("offsets", "signs", "lower", "upper"):
        arm.vector(key, 6)
    return arm.data


@dataclass(frozen=True)
class HolderTruth:
    """What truly holds the camera or the target on a facility folder
    (``stages.acquire.virtual.rig.Holder``): its robot's name (None: a static mount), each
    joint's encoder zero offset (J,) rad and origin error (true origin = URDF origin @ error),
    the base error, the rail scale, and the joints' stiffness (N m/rad; None: rigid)."""

    robot: str | None
    joint_offsets_rad: tuple[float, ...]
    joint_origin_errors: tuple[Pose, ...]
    base_error: Pose
    rail_scale: float
    stiffness_nm_per_rad: tuple[float, ...] | None

    def to_json(self) -> dict[str, Any]:
        return {"robot": self.robot, "joint_offsets_rad": list(self.joint_offsets_rad),
                "joint_origin_errors": [p.to_json() for p in self.joint_origin_errors],
                "base_error": self.base_error.to_json(), "rail_scale": self.rail_scale,
                "stiffness_nm_per_rad": None if self.stiffness_nm_per_rad is None else list(self.stiffness_nm_per_rad)}

    @classmethod
    def from_fields(cls, f: Fields) -> HolderTruth:
        f.only(*HOLDER_KEYS)
        offsets = f.vector("joint_offsets_rad")
        errors = f.raw("joint_origin_errors")
        if not isinstance(errors, list) or len(errors) != len(offsets) + (1 if offsets else 0):
            raise f.fail("joint_origin_errors", "one pose per joint and one for the flange")
        listed = Fields({str(i): e for i, e in enumerate(errors)}, f.where, f"{f.key('joint_origin_errors')}.")
        stiffness = f.vector("stiffness_nm_per_rad", len(offsets)) if f.optional("stiffness_nm_per_rad") else None
        return cls(f.text("robot") if f.optional("robot") else None, offsets,
                   tuple(listed.pose(str(i)) for i in range(len(errors))), f.pose("base_error"),
                   f.number("rail_scale", positive=True), stiffness)


@dataclass(frozen=True)
class TruthRecord:
    """True arm models (stages.common.kinematics.ArmModel as JSON), joint zero offsets (6,)
    rad, rail scale, and true transforms named as everywhere else (m); the base errors are
    nominal-to-true corrections (true base = nominal base @ error). On a facility folder
    the TRON arms' keys are None and ``facility`` holds what truly holds the camera and the
    target (``HolderTruth`` by ``camera`` and ``target``)."""

    camera_arm: dict[str, Any] | None
    target_arm: dict[str, Any] | None
    camera_joint_offsets_rad: tuple[float, ...] | None
    target_joint_offsets_rad: tuple[float, ...] | None
    rail_scale: float | None
    poses: dict[str, Pose | None]  # every key of POSE_KEYS (the base errors None on a facility)
    target_from_targetee: dict[str, Pose]  # per mount, before the fixture's sag
    unmodelled: dict[str, Any]  # stages.acquire.virtual.unmodelled.Unmodelled.to_json()
    facility: dict[str, HolderTruth] | None = None

    def to_json(self) -> dict[str, Any]:
        pose = {key: None if self.poses[key] is None else self.poses[key].to_json() for key in POSE_KEYS}
        return {"version": TRUTH_VERSION, "camera_arm": self.camera_arm, "target_arm": self.target_arm,
                "camera_joint_offsets_rad": _listed(self.camera_joint_offsets_rad),
                "target_joint_offsets_rad": _listed(self.target_joint_offsets_rad),
                "camera_base_error": pose["camera_base_error"], "target_base_error": pose["target_base_error"],
                "rail_scale": self.rail_scale, "camee_from_cam": pose["camee_from_cam"],
                "cam_from_camee": pose["cam_from_camee"],
                "target_from_targetee": {m: p.to_json() for m, p in self.target_from_targetee.items()},
                "camee_from_camrb": pose["camee_from_camrb"], "cam_from_camrb": pose["cam_from_camrb"],
                "target_from_targetrb": pose["target_from_targetrb"],
                "vicon_world_from_world": pose["vicon_world_from_world"], "unmodelled": self.unmodelled,
                "facility": None if self.facility is None else {k: h.to_json() for k, h in self.facility.items()}}

    @classmethod
    def from_fields(cls, f: Fields) -> TruthRecord:
        f.only("version", "camera_arm", "target_arm", "camera_joint_offsets_rad", "target_joint_offsets_rad",
               "rail_scale", "target_from_targetee", "unmodelled", "facility", *POSE_KEYS)
        mounts = f.child("target_from_targetee")
        facility = None
        if f.optional("facility"):
            holders = f.child("facility")
            holders.only("camera", "target")
            facility = {k: HolderTruth.from_fields(holders.child(k)) for k in ("camera", "target")}
            present = [key for key in TRON_KEYS if f.optional(key)]
            if present:
                raise f.fail(present[0], "null on a facility folder (its robots' truth is under facility)")
            tron = (None,) * 5
        else:
            tron = (_arm(f, "camera_arm"), _arm(f, "target_arm"), f.vector("camera_joint_offsets_rad", 6),
                    f.vector("target_joint_offsets_rad", 6), f.number("rail_scale", positive=True))
        poses = {key: None if facility is not None and key.endswith("base_error") else f.pose(key)
                 for key in POSE_KEYS}
        return cls(*tron, poses, {m: mounts.pose(m) for m in mounts.data}, f.child("unmodelled").data, facility)


def _listed(values: tuple[float, ...] | None) -> list[float] | None:
    return None if values is None else list(values)


def write_truth(workspace: Workspace, record: TruthRecord) -> None:
    save(workspace.truth_path, record.to_json())


def read_truth(workspace: Workspace) -> TruthRecord:
    return read(workspace.truth_path, TRUTH_VERSION, "acquire (virtual backend)", TruthRecord.from_fields)
