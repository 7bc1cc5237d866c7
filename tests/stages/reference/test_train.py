"""The reference model's recipe still runs and exports a model the evaluation can load."""

import json

import numpy as np
import onnx

from pipeline.config import load_config
from stages.common.pose_model import PoseModel
from stages.reference.train import heatmap_targets
from tests.conftest import speedplus


def test_recipe_runs_a_few_steps_and_exports_a_loadable_model(tmp_path):
    out = tmp_path / "model.onnx"
    result = speedplus("train-reference", "--profile", "smoke", "--workspace", str(tmp_path / "w"),
                       "--set", "reference.images=20", "--steps", "2", "--out", str(out))
    assert result.returncode == 0, result.stderr
    proto = onnx.load(str(out))
    assert proto.ir_version <= 13  # what onnxruntime 1.31 reads
    model = PoseModel(out)
    recipe = load_config("smoke").reference
    assert (model.contract.width, model.contract.height) == (recipe.input_width, recipe.input_height)
    assert model.contract.output == "heatmaps" and model.contract.crop == "oracle_box"
    batch = np.zeros((2, 3, recipe.input_height, recipe.input_width), np.float32)
    (heatmaps,) = model.infer(batch)
    assert heatmaps.shape == (2, 11, recipe.input_height // 4, recipe.input_width // 4)
    card = json.loads(out.with_suffix(".json").read_text())
    assert card["training_images"] == 18 and card["held_out"]["images"] == 2
    assert "held-out synthetic" in result.stdout


def test_heatmap_targets_peak_at_the_keypoints():
    keypoints = np.array([[[10.0, 20.0], [100.5, 60.25], [-30.0, 5.0]]])
    targets = heatmap_targets(keypoints, 96, 128, sigma=1.0)
    assert targets.shape == (1, 3, 24, 32)
    for k in range(2):
        y, x = np.unravel_index(targets[0, k].argmax(), targets.shape[2:])
        assert abs((x + 0.5) * 4 - 0.5 - keypoints[0, k, 0]) <= 2 and abs((y + 0.5) * 4 - 0.5 - keypoints[0, k, 1]) <= 2
    assert targets[0, 2].max() == 0  # outside the image: no target
