"""The reference model's recipe: train ``KeypointNet`` on the synthetic training set
(``render --set train``), export it to ONNX with the evaluation contract's metadata, and
score it on held-out synthetic images through ONNX Runtime (never through torch).

Data: every image is cropped and resized exactly as ``evaluate`` will crop testbed images
and twins (``stages.common.model_input.prepare``, crop ``oracle_box``: a square around the
keypoints' box, so scores are those of the pose network given a perfect detector, as the
report says); targets are Gaussian heatmaps at the keypoints' projections, at half
(``heatmap_stride`` 2) or a quarter of the input's resolution. Augmentation
(``stages.reference.augment``): a random rotation, scale and shift of every crop, then
photometric jitter for the plain model, the robust recipe for the augmented one.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from core.config import Config
from core.progress import console, track
from manifests import Workspace, read_manifest
from manifests.files import temporary_name, write_json_atomic
from stages.common.detector import DETECTOR_NAME
from stages.common.heatmap_pnp import poses_from_heatmaps
from stages.common.image_io import read_image, to_uint8
from stages.common.model_contract import IR_VERSION, OPSET, Channels, ModelContract
from stages.common.model_input import apply_affine, normalise, points_box, prepare
from stages.common.pose_model import PoseModel
from stages.common.pose_support import refusal
from stages.common.scores import score
from stages.common.target import Target
from stages.reference.augment import augment, geometric
from stages.reference.config import ReferenceConfig, ReferenceVariant

#: ImageNet's normalisation per channel; for grey, the means of its three channels'
NORMALISATION: dict[Channels, tuple[tuple[float, ...], tuple[float, ...]]] = {
    "rgb": ((0.485, 0.456, 0.406), (0.229, 0.224, 0.225)), "gray": ((0.449,), (0.226,))}
#: model name of each variant (W/models/<name>.onnx) and its augmentation
VARIANTS: dict[str, tuple[str, str]] = {"plain": ("reference", "photometric"),
                                        "augmented": ("reference_augmented", "robust"),
                                        DETECTOR_NAME: (DETECTOR_NAME, "robust")}


def channels_of(config: Config) -> Channels:
    """What the camera gives, which the training images follow (``stages.common.tone``):
    ``gray`` for a mono camera, ``rgb`` for a colour one."""
    return "gray" if config.camera.sensor == "mono" else "rgb"


def contract(recipe: ReferenceConfig, target: Target, channels: Channels = "gray") -> ModelContract:
    """The evaluation contract of a model of ``target``: a heatmap per target keypoint, of
    images of ``channels``."""
    # trained at every rotation, a square model asks evaluate to average its quarter turns
    turns = 4 if recipe.rotation and recipe.input_width == recipe.input_height else 1
    mean, std = NORMALISATION[channels]
    return ModelContract(recipe.input_width, recipe.input_height, channels, mean, std, "heatmaps",
                         np.array(target.keypoints_m, float), "oracle_box", turns, target.name)


def wide_box(box: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A box around ``box`` (x_min, y_min, x_max, y_max) 1.2 to 6 times its size, shifted at
    random with ``box`` inside: crops in which the target is small and anywhere, as in the
    self crop's first pass over a whole image."""
    centre, half = (box[:2] + box[2:]) / 2, np.maximum((box[2:] - box[:2]) / 2, 4.0)
    scale = rng.uniform(1.2, 6.0)
    shifted = centre + rng.uniform(-1, 1, 2) * (scale - 1) * half
    return np.concatenate([shifted - scale * half.max(), shifted + scale * half.max()])


def load_training_set(workspace: Workspace, recipe: ReferenceConfig, target: Target,
                      channels: Channels = "gray") -> dict[str, np.ndarray]:
    """Inputs (N, H, W, C) uint8 (RGB, or grey: C = 1) cropped and resized as ``evaluate`` will, the target's
    masks (N, H, W) uint8 cropped alike, keypoints (N, K, 2) in input pixels, the
    input-to-image maps (N, 3, 3) and the manifest rows; and a wide crop of each image
    (``wide_box``: ``wide_images``, ``wide_masks``, ``wide_keypoints``)."""
    rows = sorted(read_manifest(workspace, "train").to_pylist(), key=lambda r: r["sample_id"])
    if not rows:
        raise ValueError(f"{workspace.manifest_dir('train')}: no training images; run render --set train")
    terms = contract(recipe, target, channels)
    rng = np.random.default_rng(recipe.seed + 1)
    shape = (len(rows), recipe.input_height, recipe.input_width)
    depth = 3 if channels == "rgb" else 1
    out = {"images": np.empty((*shape, depth), np.uint8), "masks": np.empty(shape, np.uint8),
           "keypoints": np.empty((len(rows), len(target.keypoints_m), 2)), "maps": np.empty((len(rows), 3, 3)),
           "wide_images": np.empty((*shape, depth), np.uint8), "wide_masks": np.empty(shape, np.uint8),
           "wide_keypoints": np.empty((len(rows), len(target.keypoints_m), 2))}
    for index, row in enumerate(track(rows, len(rows), "load training images", rows=[0] * len(rows))):
        image = to_uint8(read_image(workspace.fetch(row["image_path"]), "bgr"))
        mask = to_uint8(read_image(workspace.fetch(row["mask_path"]), "bgr"))
        box = points_box(row["keypoints_px"])
        for prefix, crop_box in (("", box), ("wide_", wide_box(box, rng))):
            out[f"{prefix}images"][index], image_from_input = prepare(image, terms, crop_box)
            out[f"{prefix}masks"][index] = prepare(mask, terms, crop_box)[0][..., 0]
            input_from_image = np.linalg.inv(image_from_input)
            out[f"{prefix}keypoints"][index] = apply_affine(input_from_image, row["keypoints_px"])
            if not prefix:
                out["maps"][index] = image_from_input
    return {**out, "rows": np.array(rows, dtype=object)}


def heatmap_targets(keypoints: np.ndarray, height: int, width: int, sigma: float, stride: int) -> np.ndarray:
    """Gaussian heatmaps (N, K, height / stride, width / stride) float32 at input-pixel
    keypoints (N, K, 2); zero for keypoints outside the image."""
    h, w = height // stride, width // stride
    centres = (keypoints + 0.5) / stride - 0.5  # input pixels -> heatmap pixels (centres aligned)
    ys, xs = np.arange(h, dtype=np.float32), np.arange(w, dtype=np.float32)
    gx = np.exp(-((xs[None, None, :] - centres[..., 0:1]) ** 2) / (2 * sigma**2))
    gy = np.exp(-((ys[None, None, :] - centres[..., 1:2]) ** 2) / (2 * sigma**2))
    inside = ((centres[..., 0] > -0.5) & (centres[..., 0] < w - 0.5) & (centres[..., 1] > -0.5)
              & (centres[..., 1] < h - 0.5))
    return (gy[..., :, None] * gx[..., None, :] * inside[..., None, None]).astype(np.float32)


def _save_checkpoint(path: Path, tag: str, state: dict[str, Any]) -> None:
    import torch

    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = temporary_name(path)
    torch.save({"tag": tag, **state}, temporary)
    temporary.replace(path)


def _load_checkpoint(path: Path | None, tag: str) -> dict[str, Any] | None:
    """The checkpoint at ``path`` when it was made by the same run (``tag``: the stage's
    fingerprint), else None."""
    import torch

    if path is None or not path.exists():
        return None
    try:
        state = torch.load(path, weights_only=False)
    except Exception:  # a checkpoint torn by a crash is worth nothing, never an error
        return None
    return state if state.get("tag") == tag else None


def train(data: dict[str, np.ndarray], recipe: ReferenceConfig, target: Target, variant: ReferenceVariant = "plain",
          *, checkpoint: Path | None = None, tag: str = "") -> Any:
    """The trained ``KeypointNet`` (torch, eval mode) and its training log. With a
    ``checkpoint`` path, the state is saved after every epoch and a run with the same
    ``tag`` resumes from it: the random streams are restored with the weights, so a resumed
    training ends with the weights an uninterrupted one would have. Kept in one piece (74
    lines): the seeding, the checkpoint's restore and the epochs' draws share one order."""
    import torch

    from stages.reference.network import KeypointNet

    channels: Channels = "gray" if data["images"].shape[-1] == 1 else "rgb"  # what the images are
    terms = contract(recipe, target, channels)
    torch.manual_seed(recipe.seed)
    torch.set_num_threads(recipe.threads)
    rng = np.random.default_rng(recipe.seed)
    # a GPU when there is one (never required); the random streams stay on the CPU
    device = torch.device("cuda" if torch.cuda.is_available() else "cpu")
    model = KeypointNet(len(target.keypoints_m), recipe.width, recipe.heatmap_stride,
                        len(terms.mean)).to(device)
    images, masks, keypoints = data["images"], data["masks"], data["keypoints"]
    name, augmentation = VARIANTS[variant]
    steps_per_epoch = max(1, len(images) // recipe.batch_size)
    total = recipe.epochs * steps_per_epoch if recipe.max_steps == 0 else recipe.max_steps
    optimiser = torch.optim.Adam(model.parameters(), lr=recipe.learning_rate)
    schedule = torch.optim.lr_scheduler.LambdaLR(
        optimiser, lambda step: 0.02 + 0.98 * 0.5 * (1 + math.cos(math.pi * min(step, total) / total)))
    log, step, started = [], 0, time.perf_counter()
    saved = _load_checkpoint(checkpoint, tag)
    if saved is not None:
        model.load_state_dict({key: value.to(device) for key, value in saved["model"].items()})
        optimiser.load_state_dict(saved["optimiser"])
        schedule.load_state_dict(saved["schedule"])
        rng.bit_generator.state = saved["numpy_rng"]
        torch.set_rng_state(saved["torch_rng"])
        log, step = saved["log"], saved["step"]
        console.print(f"train-reference {name}: resumed at epoch {step / steps_per_epoch:.1f} from {checkpoint}")
    model.train()
    while step < total:
        order = rng.permutation(len(images))
        for first in range(0, steps_per_epoch * recipe.batch_size, recipe.batch_size):
            if step >= total:
                break
            batch = order[first:first + recipe.batch_size]
            chosen_images, chosen_masks, chosen_keypoints = images[batch], masks[batch], keypoints[batch]
            if "wide_images" in data:  # some crops wide: the model learns to find a small target too
                wide = (rng.random(len(batch)) < recipe.wide_crops)[:, None, None]
                chosen_images = np.where(wide[..., None], data["wide_images"][batch], chosen_images)
                chosen_masks = np.where(wide, data["wide_masks"][batch], chosen_masks)
                chosen_keypoints = np.where(wide, data["wide_keypoints"][batch], chosen_keypoints)
            chosen_images, chosen_masks, chosen_keypoints = geometric(
                chosen_images, chosen_masks, chosen_keypoints, rng, rotation=recipe.rotation)
            x = torch.from_numpy(normalise(augment(augmentation, chosen_images, chosen_masks, rng), terms)).to(device)
            target = torch.from_numpy(heatmap_targets(chosen_keypoints, recipe.input_height, recipe.input_width,
                                                      recipe.heatmap_sigma, recipe.heatmap_stride)).to(device)
            output = model(x)
            # foreground pixels weigh more: most of a heatmap is background
            weight = 1.0 + 20.0 * target
            loss = (weight * (output - target) ** 2).mean()
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
            schedule.step()
            step += 1
            if step % steps_per_epoch == 0 or step == total:
                log.append({"step": step, "epoch": step / steps_per_epoch, "loss": loss.item(),
                            "seconds": time.perf_counter() - started})
                console.print(f"train-reference {name}: epoch {step / steps_per_epoch:.1f}/"
                              f"{total / steps_per_epoch:.0f} "
                              f"loss {loss.item():.5f} ({time.perf_counter() - started:.0f} s)")
        if checkpoint is not None:  # at an epoch's end: the next epoch draws its order afresh
            _save_checkpoint(checkpoint, tag, {
                "model": {key: value.cpu() for key, value in model.state_dict().items()},
                "optimiser": optimiser.state_dict(), "schedule": schedule.state_dict(),
                "numpy_rng": rng.bit_generator.state, "torch_rng": torch.get_rng_state(), "log": log, "step": step})
    model.eval()
    return model.cpu(), log


def export(model: Any, recipe: ReferenceConfig, out: Path, target: Target, extra_metadata: dict[str, str],
           channels: Channels = "gray") -> None:
    """ONNX (opset ``OPSET``, IR version ``IR_VERSION``) with the contract's metadata."""
    import onnx
    import torch

    out.parent.mkdir(parents=True, exist_ok=True)
    temporary = temporary_name(out)
    terms = contract(recipe, target, channels)
    dummy = torch.zeros(1, len(terms.mean), recipe.input_height, recipe.input_width)
    torch.onnx.export(model, (dummy,), str(temporary), input_names=["image"], output_names=["heatmaps"],
                      dynamic_axes={"image": {0: "batch"}, "heatmaps": {0: "batch"}}, opset_version=OPSET,
                      dynamo=False)
    proto = onnx.load(str(temporary))
    proto.ir_version = IR_VERSION
    proto.producer_name = "speedplus train-reference"
    del proto.metadata_props[:]
    for key, value in {**terms.metadata(), **extra_metadata}.items():
        entry = proto.metadata_props.add()
        entry.key, entry.value = key, value
    onnx.checker.check_model(proto)
    onnx.save(proto, str(temporary))
    temporary.replace(out)


def held_out_scores(path: Path, data: dict[str, np.ndarray], camera_matrix: np.ndarray,
                    dist: np.ndarray) -> dict[str, float]:
    """SPEED scores of the exported model on prepared images, through ONNX Runtime and PnP."""
    model = PoseModel(path, threads=2)
    errors = []
    for first in range(0, len(data["images"]), 32):
        batch = normalise(data["images"][first:first + 32].astype(np.float32) / 255.0, model.contract)
        rows = data["rows"][first:first + 32]
        solutions, _ = poses_from_heatmaps(model.infer(batch)[0], list(data["maps"][first:first + 32]), model.contract,
                                           camera_matrix, dist, [0.01 * row["width"] for row in rows])
        for row, solution in zip(rows, solutions, strict=True):
            # a pose the crop cannot support is a miss, as evaluate scores it: the worst case,
            # so that no mean reads above pi + 1 (stages/common/pose_support.py)
            refused = solution is None or refusal(solution, model.contract.keypoints_m, points_box(row["keypoints_px"]),
                                                  camera_matrix, dist, row["width"], row["height"]) is not None
            if refused:
                errors.append({"err_q_rad": np.pi, "err_t_norm": 1.0, "score_speed": np.pi + 1.0})
                continue
            errors.append(score(solution.q, solution.t, row["q_vbs2tango_true"], row["r_Vo2To_vbs_true"]))
    err_q = np.degrees([e["err_q_rad"] for e in errors])
    return {"images": len(errors), "mean_speed_score": float(np.mean([e["score_speed"] for e in errors])),
            "median_rotation_error_deg": float(np.median(err_q)), "mean_rotation_error_deg": float(np.mean(err_q)),
            "median_translation_error": float(np.median([e["err_t_norm"] for e in errors]))}


def split_held_out(data: dict[str, np.ndarray]) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """(training, held out): the last tenth of the images, in sample_id order, is held out."""
    held = max(1, len(data["images"]) // 10)
    return {key: value[:-held] for key, value in data.items()}, {key: value[-held:] for key, value in data.items()}


def run(config: Config, data: dict[str, np.ndarray], variant: ReferenceVariant, out: Path, target: Target,
        checkpoint: Path | None = None, tag: str = "") -> dict[str, Any]:
    """Train one variant on ``load_training_set``'s data (resuming from ``checkpoint`` when
    it carries ``tag``), export to ``out``, score the held-out images; returns the model
    card (also written beside the model as JSON)."""
    from stages.common.cameras import train_camera

    recipe = config.reference
    split = split_held_out(data)
    held = len(split[1]["images"])
    started = time.perf_counter()
    channels = channels_of(config)
    model, log = train(split[0], recipe, target, variant, checkpoint=checkpoint, tag=tag)
    seconds = time.perf_counter() - started
    export(model, recipe, out, target, {"speedplus.recipe": json.dumps(asdict(recipe)), "speedplus.variant": variant,
                                "speedplus.augmentation": VARIANTS[variant][1]}, channels)
    camera = train_camera(config)
    scores = held_out_scores(out, split[1], camera.camera_matrix, camera.dist)
    card = {"model": str(out.name), "variant": variant, "augmentation": VARIANTS[variant][1],
            "training_images": len(split[0]["images"]), "held_out_images": held,
            "train_seconds": round(seconds, 1), "recipe": asdict(recipe), "held_out": scores,
            "camera": {"sensor": config.camera.sensor, "gamma": config.camera.gamma},
            "render": {"count": config.render.train_count, "seed": config.render.seed,
                       "resolution_scale": config.render.train_resolution_scale, "spp": config.render.train_spp},
            "log": log}
    write_json_atomic(out.with_suffix(".json"), card)
    return card
