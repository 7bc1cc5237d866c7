"""``W/truth.json``: the hidden truth of the virtual testbed, what a real facility never
tells (docs/architecture.md section 5). Written by acquire's virtual backend; read only by
tests and benchmarks that judge the estimates, never by a stage after acquire."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from manifests.sidecars.base import Fields, Pose, read, save
from manifests.workspace import Workspace

TRUTH_VERSION = 2  # 2: the unmodelled errors' parameters
ARM_LENGTHS = ("a1", "a2", "b", "c1", "c2", "c3", "c4")
POSE_KEYS = ("camera_base_error", "target_base_error", "camee_from_cam", "cam_from_camee", "camee_from_camrb",
             "cam_from_camrb", "target_from_targetrb", "vicon_world_from_world")


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
class TruthRecord:
    """True arm models (stages.common.kinematics.ArmModel as JSON), joint zero offsets (6,)
    rad, rail scale, and true transforms named as everywhere else (m); the base errors are
    nominal-to-true corrections (true base = nominal base @ error)."""

    camera_arm: dict[str, Any]
    target_arm: dict[str, Any]
    camera_joint_offsets_rad: tuple[float, ...]
    target_joint_offsets_rad: tuple[float, ...]
    rail_scale: float
    poses: dict[str, Pose]  # every key of POSE_KEYS
    target_from_targetee: dict[str, Pose]  # per mount, before the fixture's sag
    unmodelled: dict[str, Any]  # stages.acquire.virtual.unmodelled.Unmodelled.to_json()

    def to_json(self) -> dict[str, Any]:
        pose = {key: self.poses[key].to_json() for key in POSE_KEYS}
        return {"version": TRUTH_VERSION, "camera_arm": self.camera_arm, "target_arm": self.target_arm,
                "camera_joint_offsets_rad": list(self.camera_joint_offsets_rad),
                "target_joint_offsets_rad": list(self.target_joint_offsets_rad),
                "camera_base_error": pose["camera_base_error"], "target_base_error": pose["target_base_error"],
                "rail_scale": self.rail_scale, "camee_from_cam": pose["camee_from_cam"],
                "cam_from_camee": pose["cam_from_camee"],
                "target_from_targetee": {m: p.to_json() for m, p in self.target_from_targetee.items()},
                "camee_from_camrb": pose["camee_from_camrb"], "cam_from_camrb": pose["cam_from_camrb"],
                "target_from_targetrb": pose["target_from_targetrb"],
                "vicon_world_from_world": pose["vicon_world_from_world"], "unmodelled": self.unmodelled}

    @classmethod
    def from_fields(cls, f: Fields) -> TruthRecord:
        f.only("version", "camera_arm", "target_arm", "camera_joint_offsets_rad", "target_joint_offsets_rad",
               "rail_scale", "target_from_targetee", "unmodelled", *POSE_KEYS)
        mounts = f.child("target_from_targetee")
        return cls(_arm(f, "camera_arm"), _arm(f, "target_arm"), f.vector("camera_joint_offsets_rad", 6),
                   f.vector("target_joint_offsets_rad", 6), f.number("rail_scale", positive=True),
                   {key: f.pose(key) for key in POSE_KEYS}, {m: mounts.pose(m) for m in mounts.data},
                   f.child("unmodelled").data)


def write_truth(workspace: Workspace, record: TruthRecord) -> None:
    save(workspace.truth_path, record.to_json())


def read_truth(workspace: Workspace) -> TruthRecord:
    return read(workspace.truth_path, TRUTH_VERSION, "acquire (virtual backend)", TruthRecord.from_fields)
