"""Each calibrated arm's absolute accuracy on the dataset captures, as industry measures it
(issue 57, part 7): the arm's model predicts its flange from the controller's readings, and
the truth says where the flange was.

A laser tracker's accuracy test (ISO 9283; ABB's and KUKA's absolute-accuracy figures,
about 0.5 mm over the workspace) first registers the tracker's frame to the robot's base and
the tool's frame to the flange, by a best fit over the measured poses, and reports what is
left. So here: for each robot, the constant transforms ``G`` (world side) and ``H`` (flange
side) minimise the distance between ``G world_from_flange(model) H`` and the true
``world_from_flange`` over the session's captures, and the residuals are the arm's error. A
hand-eye calibration cannot see ``G`` and ``H`` either (one robot's base goes with the
other's, a flange's frame with the hand-eye offset), so nothing the calibration is
responsible for is registered away.

Against the labels' error at 3-5 m (``bench honesty``'s "robots on the dataset") this leaves
out the lever: the camera arm's pointing error times the range, which is what the arm's
accuracy costs a label, and which no arm's 0.5 mm keeps under 0.5 mm at 4 m.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.optimize import least_squares

from manifests import Workspace, read_manifest
from manifests.sidecars import read_calibration
from pipeline.config import load_config
from stages.common import arms
from stages.common import geometry as g
from stages.common.robots import identification, lost_motion
from stages.common.robots.errors import configured_holders
from stages.common.rwhe import transform_from_vector
from stages.common.workspace_target import workspace_target

#: the lever (m) that weighs a rotation residual against a position one in the registration
LEVER_M = 1.0


def registered_errors(model: np.ndarray, true: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Position (N,) m and rotation (N,) rad errors of poses ``model`` (N, 4, 4) against
    ``true`` (N, 4, 4) after the best rigid registration on both sides, ``G model H``."""
    start = true[0] @ g.invert(model[0])

    def moved(x: np.ndarray) -> np.ndarray:
        return transform_from_vector(x[:6]) @ start @ model @ transform_from_vector(x[6:])

    def residuals(x: np.ndarray) -> np.ndarray:
        poses = moved(x)
        turn = g.matrix_to_rotvec(np.swapaxes(true[:, :3, :3], -1, -2) @ poses[:, :3, :3]) * LEVER_M
        return np.concatenate([poses[:, :3, 3] - true[:, :3, 3], turn], axis=1).ravel()

    fitted = moved(least_squares(residuals, np.zeros(12), method="lm").x)
    position = np.linalg.norm(fitted[:, :3, 3] - true[:, :3, 3], axis=1)
    return position, g.angular_distance(fitted[:, :3, :3], true[:, :3, :3])


def arm_accuracy(ws: Workspace, session: str = "dataset") -> dict[str, dict[str, float]]:
    """Per robot (its facility name): mean position (mm) and rotation (deg) error of its
    flange on ``session``'s captures, calibrated and at its URDF, each registered as the
    module says; empty where calibrate did not fit the arms."""
    config = load_config(None, ws.root / "config.toml")
    chains = read_calibration(ws).kuka.arm_kinematics.chains
    if chains is None:
        return {}
    holders = configured_holders(config.facility.path, config.testbed)[0]
    every = lost_motion.move_directions(read_manifest(ws, "captures").to_pylist())
    rows = sorted((r for r in every if r["session"] == session and r["status"] == "ok"),
                  key=lambda r: r["sample_id"])
    truth = {r["sample_id"]: r for r in read_manifest(ws, "truth").to_pylist()}
    payload = arms.Payload.of(workspace_target(config, ws))
    m = identification.measured(holders, rows, payload, np.asarray(config.calibrate.world_up, float),
                                chains.backlash_preload_nm)
    fitted = np.asarray(chains.parameters, float)[:holders.size]
    out: dict[str, dict[str, float]] = {}
    for name, params in (("calibrated", fitted), ("URDF", np.zeros(holders.size))):
        camee, targetee = identification.flanges(holders, params[None], m)
        for robot in holders.robots:
            model, key = (camee[0], "world_from_camee") if robot.role == "camera" else (targetee[0],
                                                                                         "world_from_targetee")
            true = np.stack([g.transform_from_qt(truth[r["sample_id"]][f"{key}_q"], truth[r["sample_id"]][f"{key}_t"])
                             for r in rows])
            position, rotation = registered_errors(model, true)
            out.setdefault(robot.robot, {}).update({f"{name} mm": float(position.mean() * 1000),
                                                    f"{name} deg": float(np.degrees(rotation.mean()))})
    return out


def describe(accuracy: dict[str, Any]) -> str:
    """``arm_accuracy`` in one cell: per robot, calibrated (URDF) mm / deg."""
    return "; ".join(f"{robot} {v['calibrated mm']:.3f} mm {v['calibrated deg']:.4f} deg (URDF {v['URDF mm']:.2f} "
                     f"mm {v['URDF deg']:.3f} deg)" for robot, v in accuracy.items()) or "-"
