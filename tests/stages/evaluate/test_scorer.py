"""An evaluate worker's predictions depend on the images, the model and the decoding
settings, not on how many threads ONNX Runtime has (``evaluate.threads`` 0 picks them)."""

import numpy as np
import pytest

from core.engines import threads_per_worker
from stages.common.image_io import encode_png
from stages.evaluate.scorer import Decoding, Scorer
from tests.stages.common.test_pose_model import _conv_heatmap_model

K = np.array([[400.0, 0, 159.5], [0, 400.0, 99.5], [0, 0, 1.0]])
DIST = np.zeros(5)


def _items(count: int) -> list[dict]:
    rng = np.random.default_rng(11)
    items = []
    for index in range(count):
        image = rng.integers(0, 40, (200, 320, 3), dtype=np.uint8)
        x, y = rng.integers(60, 220), rng.integers(40, 120)
        image[y:y + 50, x:x + 70] = rng.integers(120, 256, (50, 70, 3), dtype=np.uint8)  # a textured "target"
        for crop in ("oracle_box", "self"):
            items.append({"sample_id": f"s{index}", "view": "solar_panel", "light": "lightbox", "domain": "lightbox",
                          "image_path": f"images/s{index}.png", "image_bytes": encode_png(image),
                          "box": [float(x), float(y), x + 70.0, y + 50.0], "q_true": [1.0, 0, 0, 0],
                          "t_true": [0.0, 0.0, 5.0], "model": "conv", "crop": crop})
    return items


def _scored(path, threads: int) -> list[dict]:
    scorer = Scorer(path.read_bytes(), "conv.onnx", threads, K, DIST, Decoding(0.01))
    return [{key: value for key, value in row.items() if key != "seconds"} for row in scorer.score(_items(3))]


def _same(a: list[dict], b: list[dict]) -> bool:
    def key(row):
        return tuple(np.asarray(v).tobytes() if isinstance(v, np.ndarray | list) else v for v in row.values())
    return [key(row) for row in a] == [key(row) for row in b]


def test_predictions_do_not_depend_on_the_thread_count(tmp_path):
    path = tmp_path / "conv.onnx"
    _conv_heatmap_model(path, "4")
    one, two = _scored(path, 1), _scored(path, 2)
    assert len(one) == 6 and {row["crop"] for row in one} == {"oracle_box", "self"}
    assert _same(one, two)
    assert _same(one, _scored(path, -threads_per_worker(2)))  # the share a worker gets with evaluate.threads = 0


@pytest.mark.parametrize("workers", [0, 1, 2, 64])
def test_threads_per_worker_share_the_cores(workers, monkeypatch):
    monkeypatch.setattr("os.cpu_count", lambda: 8)
    assert threads_per_worker(workers) == {0: 1, 1: 8, 2: 4, 64: 1}[workers]


def fixed_box_detector(path, cells, width: int = 64, height: int = 40) -> None:
    """An ONNX detector (stages/common/detector.py's contract) whose mask is 1 on the same
    mask pixels ``cells`` (column, row, last column, last row) in every image: the box of
    input pixels 2 * column to 2 * last column + 1 (rows alike)."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    from stages.common.detector import DetectorContract

    rows, cols = height // 2, width // 2
    col0, row0, col1, row1 = cells
    mask = np.zeros((1, 1, rows, cols), np.float32)
    mask[0, 0, row0:row1 + 1, col0:col1 + 1] = 1.0
    nodes = [helper.make_node("ReduceMean", ["image"], ["mean"], axes=[1, 2, 3], keepdims=1),
             helper.make_node("Mul", ["mean", "zero"], ["nothing"]),
             helper.make_node("Add", ["nothing", "fixed"], ["mask"])]
    graph = helper.make_graph(
        nodes, "fixed_box", [helper.make_tensor_value_info("image", TensorProto.FLOAT, ["N", 1, height, width])],
        [helper.make_tensor_value_info("mask", TensorProto.FLOAT, ["N", 1, rows, cols])],
        [numpy_helper.from_array(np.zeros((1, 1, 1, 1), np.float32), "zero"), numpy_helper.from_array(mask, "fixed")])
    proto = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    proto.ir_version = 8
    for key, value in DetectorContract(width, height, "gray", (0.5,), (0.25,)).metadata().items():
        entry = proto.metadata_props.add()
        entry.key, entry.value = key, value
    onnx.save(proto, str(path))


def test_the_detector_s_box_starts_the_self_crop(tmp_path):
    """The self crop starts from the detector's box (mapped from its input to the image),
    replacing the model's own search; the oracle crop never asks it."""
    from stages.common.detector import Detector
    from stages.common.pose_model import PoseModel
    from stages.evaluate.scorer import _first_boxes

    model_path, detector_path = tmp_path / "conv.onnx", tmp_path / "detector.onnx"
    _conv_heatmap_model(model_path, "4")
    # 320 x 200 images, a 64 x 40 input: 5 image pixels per input pixel
    fixed_box_detector(detector_path, (10, 5, 17, 9))
    items = _items(2)
    images = [np.zeros((200, 320, 3), np.uint8)] * len(items)
    crops = [item["crop"] for item in items]
    labelled = [np.asarray(item["box"], float) for item in items]
    boxes = _first_boxes(PoseModel(model_path), images, labelled, crops, K, DIST, Decoding(0.01),
                         Detector(detector_path))
    for box, crop, label in zip(boxes, crops, labelled, strict=True):
        # mask pixels 10-17 x 5-9: input pixels 20-35 x 10-19; an input pixel is 5 x 5 image pixels
        expected = (np.array([20.0, 10.0, 35.0, 19.0]) + 0.5) * 5 - 0.5 if crop == "self" else label
        np.testing.assert_allclose(box, expected, atol=0.05)
    scorer = Scorer(model_path.read_bytes(), "conv.onnx", 1, K, DIST, Decoding(0.01), detector_path.read_bytes())
    rows = scorer.score(items)
    assert [row["crop"] for row in rows] == crops and all(np.isfinite(row["score_speed"]) for row in rows)


def test_each_image_is_decoded_under_every_seed_and_its_pose_is_the_first_seed_s(tmp_path):
    path = tmp_path / "conv.onnx"
    _conv_heatmap_model(path, "4")
    items = _items(3)
    one = Scorer(path.read_bytes(), "conv.onnx", 1, K, DIST, Decoding(0.01, ransac_seed=5)).score(items)
    three = Scorer(path.read_bytes(), "conv.onnx", 1, K, DIST, Decoding(0.01, ransac_seed=5, seeds=3)).score(items)
    for single, row in zip(one, three, strict=True):
        assert row["score_speed_seeds"][0] == row["score_speed"] == single["score_speed"]
        assert len(row["score_speed_seeds"]) == len(row["score_speedplus_seeds"]) == 3
        assert row["q_pred"] is None or np.array_equal(row["q_pred"], single["q_pred"])
