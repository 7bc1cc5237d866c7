"""The reference model's recipe still runs and exports a model the evaluation can load."""

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import onnx
import pytest

from manifests import Workspace, read_manifest
from pipeline.config import load_config
from stages.common.detector import Detector
from stages.common.pose_model import PoseModel
from stages.common.workspace_target import planned_target
from stages.reference.train import heatmap_targets
from tests.conftest import speedplus


def test_recipe_runs_a_few_steps_and_exports_loadable_plain_and_augmented_models(tmp_path):
    out = tmp_path / "models"
    out.mkdir()
    theirs = out / "tango_reference_augmented.json"  # a file the command did not make
    theirs.write_text("{}")
    refused = speedplus("train-reference", "--profile", "smoke", "--workspace", str(tmp_path / "w"),
                        "--set", "reference.images=10", "--steps", "2", "--out", str(out),
                        "--set", 'reference.variants=["plain", "augmented", "detector"]')
    assert refused.returncode == 1 and f"{theirs}: exists" in refused.stderr, refused.stderr
    assert not (tmp_path / "w").exists() and theirs.read_text() == "{}"  # refused before training anything
    theirs.unlink()
    result = speedplus("train-reference", "--profile", "smoke", "--workspace", str(tmp_path / "w"),
                       "--set", "reference.images=10", "--steps", "2", "--out", str(out),
                       "--set", 'reference.variants=["plain", "augmented", "detector"]')
    assert result.returncode == 0, result.stderr
    recipe = load_config("smoke").reference
    ws = Workspace(tmp_path / "w")
    rows = {row["model"]: row for row in read_manifest(ws, "models").to_pylist()}
    assert set(rows) == {"reference", "reference_augmented", "detector"}
    for name, augmentation in (("reference", "photometric"), ("reference_augmented", "robust")):
        path = out / f"tango_{name}.onnx"  # named by target: never the shipped models' names
        proto = onnx.load(str(path))
        assert proto.ir_version <= 13  # what onnxruntime 1.31 reads
        assert {e.key: e.value for e in proto.metadata_props}["speedplus.augmentation"] == augmentation
        model = PoseModel(path)
        assert (model.contract.width, model.contract.height) == (recipe.input_width, recipe.input_height)
        assert model.contract.output == "heatmaps" and model.contract.crop == "oracle_box"
        assert model.contract.channels == "gray" and model.contract.mean == (0.449,)  # the smoke camera is mono
        batch = np.zeros((2, 1, recipe.input_height, recipe.input_width), np.float32)
        (heatmaps,) = model.infer(batch)
        stride = recipe.heatmap_stride
        assert heatmaps.shape == (2, 11, recipe.input_height // stride, recipe.input_width // stride)
        card = json.loads(path.with_suffix(".json").read_text())
        assert card["training_images"] == 9 and card["held_out"]["images"] == 1
        assert card["augmentation"] == augmentation
        assert 0 <= card["held_out"]["mean_speed_score"] <= np.pi + 1  # a miss scores the worst case, no more
        assert ws.resolve(rows[name]["path"]).read_bytes() == path.read_bytes()
    detector = Detector(out / "tango_detector.onnx")
    assert detector.contract.channels == "gray" and detector.contract.width == recipe.detector_input_width
    boxes, peaks = detector.boxes([np.zeros((200, 320, 3), np.uint8)] * 2)
    assert boxes.shape == (2, 4) and np.all(np.isfinite(boxes)) and np.all((peaks >= 0) & (peaks <= 1))
    card = json.loads((out / "tango_detector.json").read_text())
    assert card["held_out"]["images"] == 1 and 0 <= card["held_out"]["median_box_iou"] <= 1
    assert rows["detector"]["held_out_mean_speed_score"] is None
    assert result.stdout.count("held-out synthetic") == 3
    again = speedplus("train-reference", "--workspace", str(ws.root), "--steps", "2", "--out", str(out))
    assert again.returncode == 0 and "train-reference: up to date" in again.stdout, again.stderr
    assert sorted(p.name for p in out.iterdir()) == sorted(f"tango_{n}.{e}" for n in rows for e in ("json", "onnx"))


def test_without_out_the_models_stay_in_the_workspace(tmp_path, monkeypatch):
    """Run from the repository's root, as issue 42's user did: the shipped models are untouched.
    Training that fails keeps the training set rendered before it (issue 58), and the same
    command resumes from training."""
    from stages.evaluate.stage import SHIPPED_MODELS

    repository = Path(__file__).resolve().parents[3]
    shipped = {name: (repository / name).read_bytes() for name in SHIPPED_MODELS}
    args = ("train-reference", "--profile", "smoke", "--workspace", str(tmp_path / "w"), "--set",
            "reference.images=6", "--set", "reference.variants=[\"plain\"]", "--steps", "1")
    failed = speedplus(*args, cwd=repository, env={"SPEEDPLUS_FAULT_FAIL_STAGE": "train-reference"})
    said = " ".join(failed.stderr.split())
    assert failed.returncode == 1 and "injected fault" in said and "kept: render (completed;" in said, said
    images = sorted((tmp_path / "w" / "renders" / "train").glob("*.png"))
    assert len(images) == 6 and not (tmp_path / "w" / "models").exists()
    result = speedplus(*args, cwd=repository)
    assert result.returncode == 0, result.stderr
    assert "render: up to date" in result.stdout
    assert (tmp_path / "w" / "models" / "reference.onnx").is_file()
    assert {name: (repository / name).read_bytes() for name in SHIPPED_MODELS} == shipped
    assert "w/models/reference.onnx: trained on 5 images" in result.stdout


def test_heatmap_targets_peak_at_the_keypoints():
    keypoints = np.array([[[10.0, 20.0], [100.5, 60.25], [-30.0, 5.0]]])
    for stride in (2, 4):
        targets = heatmap_targets(keypoints, 96, 128, sigma=1.0, stride=stride)
        assert targets.shape == (1, 3, 96 // stride, 128 // stride)
        for k in range(2):
            y, x = np.unravel_index(targets[0, k].argmax(), targets.shape[2:])
            assert abs((x + 0.5) * stride - 0.5 - keypoints[0, k, 0]) <= stride / 2
            assert abs((y + 0.5) * stride - 0.5 - keypoints[0, k, 1]) <= stride / 2
        assert targets[0, 2].max() == 0  # outside the image: no target


def test_an_interrupted_training_resumes_to_the_weights_of_an_uninterrupted_one(tmp_path, monkeypatch):
    import torch

    from stages.reference import train as training

    recipe = replace(load_config("smoke").reference, input_width=64, input_height=64, width=4, batch_size=4,
                     max_steps=6, threads=1)
    rng = np.random.default_rng(3)
    data = {"images": rng.integers(0, 255, (8, 64, 64, 3), dtype=np.uint8),
            "masks": rng.integers(0, 255, (8, 64, 64), dtype=np.uint8), "keypoints": rng.uniform(5, 59, (8, 11, 2))}
    target = planned_target(load_config("smoke"))
    reference, _ = training.train(data, recipe, target, "augmented")

    saved = training._save_checkpoint
    calls = []

    def crash_after_two_epochs(*args, **kwargs):
        saved(*args, **kwargs)
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt

    monkeypatch.setattr(training, "_save_checkpoint", crash_after_two_epochs)
    checkpoint = tmp_path / "reference.checkpoint.pt"
    with pytest.raises(KeyboardInterrupt):
        training.train(data, recipe, target, "augmented", checkpoint=checkpoint, tag="run-a")
    monkeypatch.setattr(training, "_save_checkpoint", saved)
    assert torch.load(checkpoint, weights_only=False)["step"] == 4
    resumed, log = training.train(data, recipe, target, "augmented", checkpoint=checkpoint, tag="run-a")
    assert [entry["step"] for entry in log] == [2, 4, 6]
    for name, value in reference.state_dict().items():
        assert torch.equal(value, resumed.state_dict()[name]), name
    # a checkpoint of another run (another fingerprint) is ignored, never resumed from
    other, other_log = training.train(data, recipe, target, "augmented", checkpoint=checkpoint, tag="run-b")
    assert [entry["step"] for entry in other_log] == [2, 4, 6]


def test_a_training_set_the_user_rendered_is_trained_on_or_replaced_only_with_force(tmp_path):
    """Issue 59: 2000 images of `render --set train --count 2000` are not replaced by the
    recipe's count without a word; the refusal's command trains on them, and `status` and
    train-reference then agree that the models are up to date."""
    ws = tmp_path / "w"
    tiny = ("--set", "reference.max_steps=1", "--set", 'reference.variants=["plain"]')
    made = speedplus("render", "--profile", "smoke", "-w", str(ws), "--set", "train", "--count", "8")
    assert made.returncode == 0, made.stderr
    before = sorted(p.name for p in (ws / "renders" / "train").glob("*.png"))
    refused = speedplus("train-reference", "-w", str(ws), "--set", "reference.images=6", *tiny)
    said = " ".join(refused.stderr.split())
    assert refused.returncode == 1 and "holds a training set of 8 images" in said, said
    command = said[said.index("`speedplus train-reference") + 1:]
    command = command[: command.index("`")].split()
    assert command == ["speedplus", "train-reference", "-w", str(ws), "--set", "reference.images=8"]
    assert sorted(p.name for p in (ws / "renders" / "train").glob("*.png")) == before and not (ws / "models").exists()
    trained = speedplus(*command[1:], *tiny)
    assert trained.returncode == 0, trained.stderr
    assert "render: up to date" in trained.stdout and "trained on 7 images" in " ".join(trained.stdout.split())
    status = " ".join(speedplus("status", "-w", str(ws)).stdout.split())
    assert "│ train-reference │ done │" in status and "│ render train │ done │ train 8" in status, status
    again = speedplus(*command[1:], *tiny)
    assert again.returncode == 0 and "train-reference: up to date" in again.stdout, again.stdout + again.stderr
    verified = " ".join(speedplus("verify", "-w", str(ws)).stdout.split())  # what status lists, verify checks
    assert "│ render │ train │ intact │" in verified and "│ train-reference │ models │ intact │" in verified, verified
