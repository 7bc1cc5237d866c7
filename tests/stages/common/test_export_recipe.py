"""docs/models.md's recipe, run as written: a PyTorch model becomes an ONNX file that
evaluate takes, its contract as the recipe states it."""

import re
from pathlib import Path

import numpy as np

from stages.common.pose_model import PoseModel

MODELS_DOC = Path(__file__).resolve().parents[3] / "docs" / "models.md"


def recipe() -> str:
    text = MODELS_DOC.read_text()
    found = re.search(r"<!-- recipe: export -->\s*(?:<!-- docs: python -->\s*)?```python\n(.*?)```", text, re.S)
    assert found, "docs/models.md lost its export recipe"
    return found.group(1)


def test_the_export_recipe_gives_a_model_evaluate_takes(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    exec(compile(recipe(), "docs/models.md recipe", "exec"), {"__name__": "recipe"})
    model = PoseModel(tmp_path / "my_model.onnx", threads=1)
    model.check()  # what evaluate asks of a model before it writes anything
    contract = model.contract
    assert (contract.width, contract.height, contract.output, contract.crop) == (256, 256, "heatmaps", "oracle_box")
    assert len(contract.keypoints_m) == 11 and model.fixed_batch is None
    heatmaps = model.infer(np.zeros((3, 3, 256, 256), np.float32))[0]
    assert heatmaps.shape == (3, 11, 64, 64)
