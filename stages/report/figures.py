"""The report's figures (matplotlib, Agg) and image thumbnails, each written to a file."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402 - the backend must be chosen first
import numpy as np  # noqa: E402

from stages.common import geometry as g  # noqa: E402

DOMAIN_COLOURS = {"synthetic": "tab:blue", "lightbox": "tab:orange", "sunlamp": "tab:red"}


def _save(figure: Any, path: Path) -> str:
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)
    return path.name


def calibration_residuals(samples: list[dict[str, Any]], path: Path,
                          names: tuple[str, str] = ("KUKA", "Vicon")) -> str:
    """Per calibration sample: each source's disagreement with the pattern's PnP pose;
    ``names``: the robots' and the motion capture's, as the facility calls them."""
    figure, (left, right) = plt.subplots(1, 2, figsize=(10, 3.4))
    for source, marker in (("kuka", "o"), ("vicon", "s")):
        ids, dt, dr = [], [], []
        for index, row in enumerate(samples):
            if row.get(f"{source}_cam_from_target_q") is None or row["cam_from_target_cal_q"] is None:
                continue
            measured = g.transform_from_qt(row[f"{source}_cam_from_target_q"], row[f"{source}_cam_from_target_t"])
            pattern = g.transform_from_qt(row["cam_from_target_cal_q"], row["cam_from_target_cal_t"])
            ids.append(index)
            dt.append(1000 * np.linalg.norm(measured[:3, 3] - pattern[:3, 3]))
            dr.append(np.degrees(g.angular_distance(measured[:3, :3], pattern[:3, :3])))
        left.plot(ids, dt, marker, ms=4, label=names[0] if source == "kuka" else names[1])
        right.plot(ids, dr, marker, ms=4)
    left.set(xlabel="calibration sample", ylabel="translation residual [mm]", title="E_T per sample")
    right.set(xlabel="calibration sample", ylabel="rotation residual [deg]", title="E_R per sample")
    left.legend()
    return _save(figure, path)


def pose_distribution(labels: list[dict[str, Any]], path: Path) -> str:
    """Label positions (full scale) and Euler angles of cam_from_target."""
    from scipy.spatial.transform import Rotation

    t = np.array([row["r_Vo2To_vbs_true"] for row in labels])
    rotations = g.quat_to_matrix(np.array([row["q_vbs2tango_true"] for row in labels]))
    euler = Rotation.from_matrix(rotations).as_euler("ZYX", degrees=True)
    figure, axes = plt.subplots(1, 3, figsize=(12, 3.4))
    colours = ["tab:orange" if row["domain"] == "lightbox" else "tab:red" for row in labels]
    axes[0].scatter(t[:, 0], t[:, 2], c=colours, s=12)
    axes[0].set(xlabel="x [m]", ylabel="z (boresight) [m]", title="positions (full scale)")
    axes[1].scatter(t[:, 1], t[:, 2], c=colours, s=12)
    axes[1].set(xlabel="y [m]", ylabel="z [m]", title="orange: light boxes, red: sun lamp")
    for column, name in enumerate(("yaw (Z)", "pitch (Y)", "roll (X)")):
        axes[2].hist(euler[:, column], bins=18, range=(-180, 180), histtype="step", label=name)
    axes[2].set(xlabel="angle [deg]", ylabel="labels", title="Euler angles Z-Y-X")
    axes[2].legend(fontsize=8)
    return _save(figure, path)


def per_sample_scores(predictions: list[dict[str, Any]], path: Path) -> str:
    """The paper's Figure 12: SPEED score per sample, synthetic twin against testbed image."""
    testbed = sorted((r for r in predictions if r["domain"] != "synthetic"),
                     key=lambda r: (r["view"], r["light"], r["sample_id"]))
    synthetic = {r["sample_id"]: r for r in predictions if r["domain"] == "synthetic"}
    figure, axis = plt.subplots(figsize=(11, 3.6))
    xs = np.arange(len(testbed))
    axis.plot(xs, [synthetic[r["sample_id"]]["score_speed"] if r["sample_id"] in synthetic else np.nan
                   for r in testbed], "o", ms=4, color=DOMAIN_COLOURS["synthetic"], label="synthetic twin")
    axis.plot(xs, [r["score_speed"] for r in testbed], "x", ms=5, color="black", label="testbed")
    for index, row in enumerate(testbed):
        if row["light"] == "sunlamp":
            axis.axvspan(index - 0.5, index + 0.5, color="tab:red", alpha=0.08, lw=0)
    axis.set(xlabel="sample (solar-panel views first; shaded: sun lamp)", ylabel="SPEED score", yscale="log",
             title="SPEED score per sample")
    axis.legend()
    return _save(figure, path)


def rotation_cdf(predictions: list[dict[str, Any]], models: list[str], path: Path) -> str:
    """Cumulative distributions of the rotation error: one panel per view x light
    configuration (columns) and crop (rows: the contract's, then the model's own), every
    model in each panel (a colour each), solid on testbed images and dashed on their twins,
    so the gap each model leaves is read side by side for light boxes and sun lamp."""
    models = models or ["-"]
    configurations = sorted({(r["view"], r["light"]) for r in predictions}, key=str) or [("-", "-")]
    crops = [c for c in ("oracle_box", "full", "self") if any(r["crop"] == c for r in predictions)] or ["-"]
    figure, axes = plt.subplots(len(crops), len(configurations), figsize=(4.2 * len(configurations),
                                3.4 * len(crops)), squeeze=False, sharex=True, sharey=True)
    colours = plt.get_cmap("tab10")
    for row, crop in enumerate(crops):
        for column, (view, light) in enumerate(configurations):
            axis = axes[row][column]
            for index, model in enumerate(models):
                for testbed, style in ((True, "-"), (False, "--")):
                    errors = np.sort(np.degrees([r["err_q_rad"] for r in predictions if r["model"] == model
                                                 and r["crop"] == crop and (r["view"], r["light"]) == (view, light)
                                                 and (r["domain"] != "synthetic") == testbed]))
                    if len(errors):
                        axis.step(errors, np.arange(1, len(errors) + 1) / len(errors), where="post",
                                  color=colours(index % 10), ls=style,
                                  label=f"{model}: {'testbed' if testbed else 'twins'}")
            axis.set(xscale="log", title=f"{view}, {light} ({crop.replace('_', ' ')})")
            axis.axvline(0.169, color="grey", ls=":", lw=1)
            if row == len(crops) - 1:
                axis.set_xlabel("rotation error [deg]")
            if column == 0:
                axis.set_ylabel("share of images")
            if row == 0 and column == 0:
                axis.legend(fontsize=7)
    return _save(figure, path)


def tracking_errors(tracks: list[dict[str, Any]], path: Path) -> str:
    """SPEED score against time for each sequence (rows) and domain (columns): per model and
    crop (a colour each) the tracked score (solid) and the per-frame one (dots)."""
    sequences = list(dict.fromkeys(r["sequence_id"] for r in sorted(tracks, key=lambda r: r["track_id"]))) or ["-"]
    domains = [d for d in ("synthetic", "testbed") if any(r["domain"] == d for r in tracks)] or ["-"]
    runs = sorted({(r["model"], r["crop"]) for r in tracks})
    figure, axes = plt.subplots(len(sequences), len(domains), figsize=(6.0 * len(domains), 3.2 * len(sequences)),
                                squeeze=False, sharey=True)
    colours = plt.get_cmap("tab10")
    for row, sequence in enumerate(sequences):
        for column, domain in enumerate(domains):
            axis = axes[row][column]
            for index, (model, crop) in enumerate(runs):
                chosen = sorted((r for r in tracks if (r["sequence_id"], r["domain"], r["model"], r["crop"])
                                 == (sequence, domain, model, crop)), key=lambda r: r["frame"])
                if not chosen:
                    continue
                times = [r["time_s"] for r in chosen]
                axis.plot(times, [r["score_speed"] for r in chosen], "-", color=colours(index % 10),
                          label=f"{model} ({crop.replace('_', ' ')}): tracked")
                axis.plot(times, [r["frame_score_speed"] for r in chosen], ".", color=colours(index % 10), ms=4,
                          label=f"{model} ({crop.replace('_', ' ')}): per frame")
            axis.set(yscale="log", title=f"{sequence}, {domain}", xlabel="time since the epoch [s]",
                     ylabel="SPEED score")
            if row == 0 and column == 0:
                axis.legend(fontsize=7)
    return _save(figure, path)


def corners(image: np.ndarray, detected: np.ndarray, reprojected: np.ndarray | None) -> np.ndarray:
    """A calibration capture (brightened, BGR) with its detected corners (M, 2) as green
    crosses and reprojected ones as red circles, joined by a line where they differ."""
    drawn = brighten(image.copy() if image.ndim == 3 else cv2.cvtColor(image, cv2.COLOR_GRAY2BGR))
    size = max(3, round(image.shape[1] / 300))
    for index, point in enumerate(np.round(detected * 4).astype(int)):
        cv2.drawMarker(drawn, (point[0] >> 2, point[1] >> 2), (60, 220, 60), cv2.MARKER_CROSS, 2 * size, 1)
        if reprojected is not None:
            other = np.round(reprojected[index] * 4).astype(int)
            cv2.circle(drawn, tuple(other), size * 4, (40, 40, 230), 1, cv2.LINE_AA, shift=2)
            cv2.line(drawn, tuple(point), tuple(other), (40, 40, 230), 1, cv2.LINE_AA, shift=2)
    return drawn


def thumbnail(image: np.ndarray, width: int = 320) -> np.ndarray:
    scale = width / image.shape[1]
    return cv2.resize(image, (width, round(image.shape[0] * scale)), interpolation=cv2.INTER_AREA)


def brighten(image: np.ndarray, gain: float | None = None) -> np.ndarray:
    """A testbed image with its shadows lifted for viewing (the room is dark): by ``gain``,
    else by what brings its 99.5th percentile to 230 (1x-16x), so a dim capture is seen.
    An 8-bit image goes through a table of its 256 values (the same values as scaling every
    pixel in float32: a gallery of the paper profile brightened 990 images at 28 ms each)."""
    if not image.size:
        return image.astype(np.uint8)
    if gain is None:
        bright = percentile_8bit(image, 99.5) if image.dtype == np.uint8 else float(np.percentile(image, 99.5))
        gain = float(np.clip(230.0 / max(bright, 1.0), 1.0, 16.0))
    if image.dtype == np.uint8:
        table = np.clip(np.arange(256, dtype=np.float32) * gain, 0, 255).astype(np.uint8)
        return cv2.LUT(image, table).reshape(image.shape)  # OpenCV drops or adds a unit axis
    return np.clip(image.astype(np.float32) * gain, 0, 255).astype(np.uint8)


def percentile_8bit(image: np.ndarray, q: float) -> float:
    """``np.percentile(image, q)`` of a non-empty uint8 image, the same float, from its
    histogram instead of a partition of its pixels: the order statistics either side of
    the virtual index (n - 1) q / 100 and NumPy's linear interpolation between them."""
    if not 0 <= q <= 100:
        raise ValueError(f"percentile_8bit: q = {q} is not in [0, 100]")
    count = image.size
    virtual = (count - 1) * (q / 100)
    previous = int(np.floor(virtual))
    gamma = virtual - previous
    if count < 1 << 24:  # OpenCV counts in float32: exact below 2^24, and 12x NumPy's bincount
        histogram = cv2.calcHist([image.reshape(1, -1)], [0], None, [256], [0, 256]).ravel().astype(np.int64)
    else:
        histogram = np.bincount(image.ravel(), minlength=256)
    cumulative = np.cumsum(histogram)
    low = int(np.searchsorted(cumulative, previous, side="right"))
    high = int(np.searchsorted(cumulative, min(previous + 1, count - 1), side="right"))
    step = high - low
    return low + step * gamma if gamma < 0.5 else high - step * (1 - gamma)


def overlay(image: np.ndarray, label: dict[str, Any], camera_matrix: np.ndarray, dist: np.ndarray,
            wireframe: tuple[np.ndarray, list[tuple[int, int]]],
            brightened_already: np.ndarray | None = None) -> np.ndarray:
    """The label's wireframe (points (P, 3) full scale, body frame, and edges: the target's
    ``feature_edges``) drawn on a testbed image (BGR), brightened (``brightened_already``:
    ``brighten(image)`` of a BGR (H, W, 3) image, where the caller has it)."""
    points, edges = wireframe
    cam_from_target = g.transform_from_qt(label["q_vbs2tango_true"], label["r_Vo2To_vbs_true"])
    pixels = g.project(cam_from_target, points, camera_matrix, dist)
    drawn = image.copy() if image.ndim == 3 else cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    brightened = brighten(drawn) if brightened_already is None else brightened_already.copy()
    for a, b in edges:
        cv2.line(brightened, tuple(np.round(pixels[a] * 4).astype(int)), tuple(np.round(pixels[b] * 4).astype(int)),
                 (80, 255, 80), 1, cv2.LINE_AA, shift=2)
    return brightened
