"""Two facilities besides TRON, rehearsed as a lab would (issue 46, parts 4 and 7): plan,
acquire on the virtual testbed built from the folder, calibrate, fuse and label on the smoke
profile. Each run's robot telemetry is the URDFs' kinematics of its encoders (yourdfpy's, not
our chain's), its sources are the folder's (motion capture only where the folder has it), its
calibration leaves the URDF arms' kinematics alone, and its labels meet the SPEED+ thresholds
at the rate the facility's rehearsal (``python -m bench honesty --facility``) predicts in the
card it keeps beside the folder (``DIR/rehearsal.json``, made on the folder as it is)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from scipy.stats import binom

from bench.honesty import dataset, under_speedplus
from bench.targets import cubesat3u
from manifests import Workspace
from manifests.facility import facility_digest
from manifests.rehearsal import read_rehearsal
from manifests.sidecars import read_calibration, read_session
from stages.common import geometry as g
from stages.common.robots.facility import load_facility, pose_matrix
from tests.conftest import speedplus

FACILITIES = Path(__file__).resolve().parents[2] / "facilities"
#: the --set overrides each facility's rehearsal was made with (its rehearsal.json says so too)
SETTINGS = {"abb_rail": [], "ur10_tripod": ['plan.lights=["lightbox"]', "plan.dataset_range_m=[1.3, 1.8]"]}


@pytest.fixture(scope="module", params=sorted(SETTINGS))
def rehearsed(request, tmp_path_factory):
    folder = request.param
    root = tmp_path_factory.mktemp(folder)
    args = [a for setting in SETTINGS[folder] for a in ("--set", setting)]
    if folder == "ur10_tripod":
        args += ["--target", str(cubesat3u(root / "cubesat3u"))]  # as the rehearsal has it
    workspace = root / "w"
    result = speedplus("run", "-w", str(workspace), "--profile", "smoke", "--until", "label",
                       "--facility", str(FACILITIES / folder), *args)
    assert result.returncode == 0, result.stderr
    return folder, workspace


def _rows(workspace: Path, name: str) -> dict[str, dict]:
    return {row["sample_id"]: row for row in pq.read_table(workspace / "manifests" / name).to_pylist()}


def _yourdfpy(robot, joints: list[float], rail_m: float) -> np.ndarray:
    import yourdfpy

    urdf = yourdfpy.URDF.load(str(robot.chain.source), load_meshes=False, build_collision_scene_graph=False)
    urdf.update_cfg(dict(zip(robot.chain.joint_names, joints, strict=True)))
    return robot.world_from_base(rail_m) @ urdf.get_transform(robot.spec.flange_link, robot.spec.base_link)


def test_the_telemetry_is_the_urdfs_kinematics_of_the_encoders(rehearsed):
    folder, workspace = rehearsed
    facility = load_facility(FACILITIES / folder)
    captures = _rows(workspace, "captures")
    assert len(captures) == 24 and all(row["status"] == "ok" for row in captures.values())
    for row in captures.values():
        for carried, flange in (("camera", "camee"), ("target", "targetee")):
            reported = g.transform_from_qt(row[f"kuka_world_from_{flange}_q"], row[f"kuka_world_from_{flange}_t"])
            holder = facility.holder(carried)
            if hasattr(holder, "chain"):
                rail = row["kuka_rail_m"] if holder.spec.rail is not None else 0.0
                expected = _yourdfpy(holder, row[f"kuka_{carried}_joints_rad"], rail)
            else:  # the tripod: where the folder stands it
                assert row[f"kuka_{carried}_joints_rad"] is None
                expected = pose_matrix(holder.world_from_mount)
            np.testing.assert_allclose(reported, expected, atol=1e-9)


def test_the_sources_and_the_calibration_are_the_facilitys(rehearsed):
    folder, workspace = rehearsed
    ws = Workspace(workspace)
    has_mocap = load_facility(FACILITIES / folder).spec.motion_capture is not None
    assert read_session(ws).sources == (("kuka", "vicon") if has_mocap else ("kuka",))
    calibration = read_calibration(ws)
    assert (calibration.vicon is not None) == has_mocap
    assert not calibration.kuka.arm_kinematics.estimated and "URDF" in calibration.kuka.arm_kinematics.why
    assert calibration.kuka.metrics.truth.E_T_m[0] < 0.01  # mm-level, not a wrong frame


def test_the_labels_meet_the_thresholds_at_the_rehearsed_rate(rehearsed):
    """The share of labels under the SPEED+ thresholds is what the committed rehearsal of the
    same folder predicts: inside the binomial range (two-sided, 1% each side) of the ends of
    its 95% interval."""
    folder, workspace = rehearsed
    under = under_speedplus(dataset(Workspace(workspace)))  # as the rehearsal counts them
    record = read_rehearsal(FACILITIES / folder)
    assert record.facility_digest == facility_digest(FACILITIES / folder), "the folder changed: rehearse it again"
    assert record.profile == "smoke" and list(record.settings) == SETTINGS[folder]
    assert record.target == (None if folder == "abb_rail" else "cubesat3u")
    low, high = record.interval_95
    seen, count = int(np.sum(under)), len(under)
    assert count == 8
    assert binom.cdf(seen, count, low) > 0.01  # not fewer than the interval's low end allows
    assert binom.sf(seen - 1, count, high) > 0.01  # not more than its high end allows


def test_the_report_and_status_say_what_share_the_facility_presented(rehearsed):
    from pipeline.config import load_config
    from stages.report.stage import facility_sentence

    folder, workspace = rehearsed
    config = load_config(None, workspace / "config.toml")
    name = load_facility(FACILITIES / folder).spec.name
    sentence = facility_sentence(config, Workspace(workspace))
    assert f"{name} presented 8 of " in sentence and "of SO(3) x the range" in sentence
    status = " ".join(speedplus("status", "-w", str(workspace)).stdout.replace("│", " ").split())
    assert sentence.strip().rstrip(".").split(";")[0] in status


def test_the_truth_is_the_facilitys_robots(rehearsed):
    """truth.json records what truly holds the camera and the target on the facility (no TRON
    arm): the robot by name (none for the tripod), an error per URDF joint origin and flange,
    and the base error; read back through its format."""
    from manifests.sidecars import read_truth

    folder, workspace = rehearsed
    truth = read_truth(Workspace(workspace))
    assert truth.camera_arm is None and truth.facility is not None
    facility = load_facility(FACILITIES / folder)
    for carried in ("camera", "target"):
        holder, stored = facility.holder(carried), truth.facility[carried]
        if hasattr(holder, "chain"):
            assert stored.robot == holder.spec.name and len(stored.joint_offsets_rad) == holder.chain.dof
            assert len(stored.joint_origin_errors) == holder.chain.dof + 1
            assert 0 < np.abs(stored.joint_offsets_rad).max() < 0.01
        else:
            assert stored.robot is None and not stored.joint_offsets_rad


def test_the_rehearsal_bench_the_docs_cite_runs(rehearsed, tmp_path, monkeypatch):
    """``python -m bench honesty --facility DIR`` (docs/accuracy.md, the user guide) on a kept
    smoke acquisition of the folder: recalibrated with this code, its card written beside a
    copy of the folder (never over the committed one), its rows against the truth."""
    import json
    import shutil

    import bench.common
    from bench import honesty

    folder, workspace = rehearsed
    if folder != "abb_rail":
        pytest.skip("one facility is enough to run the bench")
    copy = tmp_path / folder
    shutil.copytree(FACILITIES / folder, copy)
    (copy / "rehearsal.json").unlink(missing_ok=True)  # the card read back is the one this run writes
    shutil.copytree(workspace, tmp_path / "root" / "seed71")
    monkeypatch.setattr(bench.common, "RESULTS", tmp_path / "results")
    honesty.main("--facility", str(copy), "71", str(tmp_path / "root"), "--profile", "smoke")
    rows = json.loads((tmp_path / "results" / "rehearsal_abb-rail.json").read_text())["rows"]
    assert [row["seed"] for row in rows] == [71, "pooled"] and rows[0]["labels"] == 8
    assert 0 < rows[0]["(b) mean E_T label (mm)"] < 50
    record = read_rehearsal(copy)
    assert record.labels == 8 and record.profile == "smoke" and 0 <= record.under_speedplus <= 8
