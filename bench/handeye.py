"""Real hand-eye data: this pipeline against OpenCV's own recipe on the same images.

OpenCV's recipe: ``findChessboardCornersSB`` in every image, ``calibrateCamera`` on all
of them, then ``calibrateRobotWorldHandEye`` (Shah) on calibrateCamera's per-image poses;
E_T, E_R and E_p are measured against those per-image poses and detected corners. Ours:
``speedplus acquire --format handeye|tabb`` then ``speedplus calibrate`` (each solver),
in-sample and cross-validated.

    python -m bench handeye            (Ali et al.'s KUKA set and Tabb's DS1 from ../shared/external)
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from bench.common import report
from manifests import Workspace
from manifests.sidecars import read_calibration

EXTERNAL = Path(__file__).resolve().parents[2] / "shared" / "external"
#: Ali et al.'s folder described for ``--format handeye`` (``camera_on``: flange, as recorded)
KUKA_TOML = """format_version = 1
[robot]
file = "RobotPosesVec.txt"
layout = "rowmajor4x4"
transform = "base_from_flange"
length_unit = "m"
[setup]
camera_on = "{camera_on}"
[images]
glob = "*.png"
[pattern]
kind = "chessboard"
size = [28, 17]
square_m = 0.02
"""


def opencv_reference(images: list[Path], cam_side_b: np.ndarray, size: tuple[int, int],
                     square_m: float) -> dict[str, float]:
    """OpenCV's recipe on ``images`` with the robot's ``B_i = camee_from_targetee`` (N, 4, 4, m):
    mean E_T (m), E_R (rad), E_p (px) over the images where the board is found."""
    from stages.common import geometry as g

    xs, ys = np.meshgrid(np.arange(size[0]), np.arange(size[1]))
    board = (np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], axis=1) * square_m).astype(np.float32)
    found, corners = [], []
    for index, path in enumerate(images):
        grey = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        ok, detected = cv2.findChessboardCornersSB(grey, size, flags=cv2.CALIB_CB_EXHAUSTIVE)
        if ok:
            found.append(index)
            corners.append(detected.reshape(-1, 2))
    height, width = cv2.imread(str(images[0]), cv2.IMREAD_GRAYSCALE).shape
    _, camera_matrix, dist, rvecs, tvecs = cv2.calibrateCamera([board] * len(found), corners, (width, height),
                                                               None, None)
    a = np.stack([g.make_transform(cv2.Rodrigues(r)[0], t.ravel()) for r, t in zip(rvecs, tvecs, strict=True)])
    b = cam_side_b[found]
    r_x, t_x, r_z, t_z = cv2.calibrateRobotWorldHandEye([m[:3, :3] for m in a], [m[:3, 3] for m in a],
                                                        [m[:3, :3] for m in b], [m[:3, 3] for m in b],
                                                        method=cv2.CALIB_ROBOT_WORLD_HAND_EYE_SHAH)
    predicted = g.make_transform(r_z, t_z.ravel()) @ b @ g.invert(g.make_transform(r_x, t_x.ravel()))
    e_p = [np.sqrt(np.mean(np.sum((g.project(p, board.astype(float), camera_matrix, dist.ravel()) - c) ** 2, 1)))
           for p, c in zip(predicted, corners, strict=True)]
    return {"E_T_m": float(np.mean(np.linalg.norm(predicted[:, :3, 3] - a[:, :3, 3], axis=1))),
            "E_R_rad": float(np.mean(g.angular_distance(predicted[:, :3, :3], a[:, :3, :3]))),
            "E_p_px": float(np.mean(e_p)), "images": len(found)}


def kuka_b() -> np.ndarray:
    """Ali et al.'s poses as ``B_i = flange_from_base`` (eye-in-hand)."""
    from stages.common import geometry as g

    base_from_flange = np.loadtxt(EXTERNAL / "ali2019_kuka_1" / "RobotPosesVec.txt").reshape(-1, 4, 4)
    return np.stack([g.invert(m) for m in base_from_flange])


def tabb_b() -> np.ndarray:
    hand_from_base = np.loadtxt(EXTERNAL / "tabb_ds1" / "robot_cali.txt", skiprows=1).reshape(-1, 4, 4).copy()
    hand_from_base[:, :3, 3] /= 1000.0
    return hand_from_base


def speedplus(*args: str) -> None:
    result = subprocess.run([sys.executable, "-m", "pipeline.cli", *args], capture_output=True, text=True)
    if result.returncode != 0:
        raise SystemExit(result.stderr)


def main() -> None:
    rows = []
    with tempfile.TemporaryDirectory() as directory:
        kuka = Path(directory) / "kuka"
        kuka.mkdir()
        for path in sorted((EXTERNAL / "ali2019_kuka_1").glob("*.png")) + [
                EXTERNAL / "ali2019_kuka_1" / "RobotPosesVec.txt"]:
            shutil.copyfile(path, kuka / path.name)
        (kuka / "dataset.toml").write_text(KUKA_TOML.format(camera_on="flange"))
        sets = {"Ali KUKA (30 x 1928x1208)": (kuka, "handeye", sorted(kuka.glob("*.png")), kuka_b(), (28, 17), 0.02),
                "Tabb DS1 (88 x 640x480)": (EXTERNAL / "tabb_ds1", "tabb",
                                            [EXTERNAL / "tabb_ds1" / "images" / f"image{i}.png" for i in range(88)],
                                            tabb_b(), (8, 6), 0.0285)}
        for name, (source, fmt, images, b, size, square) in sets.items():
            started = time.perf_counter()
            reference = opencv_reference(images, b, size, square)
            rows.append({"set": name, "method": "OpenCV calibrateCamera + Shah", "fit": "in-sample",
                         "samples": reference["images"], "E_T_mm": reference["E_T_m"] * 1000,
                         "E_R_deg": float(np.degrees(reference["E_R_rad"])), "E_p_px": reference["E_p_px"],
                         "seconds": time.perf_counter() - started})
            workspace = Path(directory) / f"w_{fmt}"
            speedplus("acquire", "-w", str(workspace), "--backend", "replay", "--format", fmt, "--source", str(source))
            for solver in ("frobenius", "reprojection"):
                started = time.perf_counter()
                speedplus("calibrate", "-w", str(workspace), "--force", "--set", f"calibrate.solver={solver}")
                seconds = time.perf_counter() - started
                entry = read_calibration(Workspace(workspace)).to_json()["kuka"]
                for fit in ("in_sample", "cross_validated"):
                    metric = entry["metrics"][fit]
                    rows.append({"set": name, "method": f"speedplus ({solver})", "fit": fit.replace("_", "-"),
                                 "samples": entry["samples"], "E_T_mm": metric["E_T_m"][0] * 1000,
                                 "E_R_deg": float(np.degrees(metric["E_R_rad"][0])), "E_p_px": metric["E_p_px"][0],
                                 "seconds": seconds})
    report("handeye", "Real hand-eye data: speedplus against OpenCV's recipe", rows)


if __name__ == "__main__":
    main()
