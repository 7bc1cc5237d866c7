"""An evaluate worker's predictions depend on the images, the model and the decoding
settings, not on how many threads ONNX Runtime has (``evaluate.threads`` 0 picks them)."""

import numpy as np
import pytest

from pipeline.engines import threads_per_worker
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
