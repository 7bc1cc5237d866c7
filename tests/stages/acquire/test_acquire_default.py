"""The default profile's captures are usable: the board is found, the model is in frame."""

import json

import cv2
import numpy as np

from manifests import read_manifest
from stages.common import geometry as g
from stages.common import tango
from stages.common.patterns import PatternSpec, detect


def test_charuco_is_detected_in_95_percent_of_calibration_captures(default_acquisition):
    ws = default_acquisition
    spec = PatternSpec.from_json(json.loads(ws.session_path.read_text())["pattern"])
    calibration = [c for c in read_manifest(ws, "captures").to_pylist() if c["session"] == "calibration"]
    assert len(calibration) == 64
    found = [len(detect(cv2.imread(str(ws.resolve(c["image_path"])), cv2.IMREAD_GRAYSCALE), spec)[1]) >= 6
             for c in calibration]
    assert np.mean(found) >= 0.95


def test_model_is_in_frame_in_every_dataset_capture(default_acquisition):
    ws = default_acquisition
    session = json.loads(ws.session_path.read_text())
    camera_matrix, dist = np.array(session["camera"]["K"]), np.array(session["camera"]["dist"])
    truth = {r["sample_id"]: r for r in read_manifest(ws, "truth").to_pylist()}
    dataset = [c for c in read_manifest(ws, "captures").to_pylist() if c["session"] == "dataset"]
    assert len(dataset) == 48
    for row in dataset:
        image = cv2.imread(str(ws.resolve(row["image_path"])), cv2.IMREAD_GRAYSCALE)
        cam_from_target = g.transform_from_qt(truth[row["sample_id"]]["cam_from_target_q"],
                                              truth[row["sample_id"]]["cam_from_target_t"])
        pixels = g.project(cam_from_target, tango.KEYPOINTS_M * session["mockup_scale"], camera_matrix, dist)
        assert np.all((pixels >= 0) & (pixels <= [image.shape[1] - 1, image.shape[0] - 1])), row["sample_id"]
        x0, y0 = np.floor(pixels.min(axis=0)).astype(int)
        x1, y1 = np.ceil(pixels.max(axis=0)).astype(int)
        assert np.percentile(image[y0:y1 + 1, x0:x1 + 1], 99) > 3 * max(np.median(image), 1), row["sample_id"]
