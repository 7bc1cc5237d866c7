"""The detector's recipe (``reference.variants`` ``detector``): a heatmap of the target's
pixels (``stages.common.detector``) learnt on the same rendered training set as the
keypoint models, from whole images at reduced resolution, exported to ONNX with the
detector contract.

The network is ``KeypointNet``'s encoder-decoder with one output map at half the input's
resolution; its target is the render's mask averaged over each heatmap pixel (the share of
it the target covers), its loss the binary cross-entropy. Augmentation: a random zoom (0.7
to 1.4) about a random point and a shift, applied alike to the image and the mask (no
in-plane rotation: the SO(3)-uniform poses already turn the target every way), then the
keypoint model's robust recipe (Earth backgrounds, texture, style, glare, blur, noise): the
testbed's room, lamp and sensor are what the detector has to see through.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from core.config import Config
from core.progress import console, track
from manifests import Workspace, read_manifest
from manifests.files import temporary_name, write_json_atomic
from stages.common.detector import Detector, DetectorContract, decode_boxes, whole_image
from stages.common.image_io import read_image, to_uint8
from stages.common.model_contract import IR_VERSION, OPSET, Channels
from stages.common.model_input import normalise
from stages.common.target import Target
from stages.reference.augment import augment
from stages.reference.config import ReferenceConfig

#: input pixels per mask pixel
STRIDE = 2


def detector_contract(recipe: ReferenceConfig, aspect: float, target: Target, channels: Channels,
                      normalisation: tuple[tuple[float, ...], tuple[float, ...]]) -> DetectorContract:
    """The contract of a detector of images of ``aspect`` (width / height)."""
    height = max(16, int(round(recipe.detector_input_width / aspect / 16)) * 16)
    return DetectorContract(recipe.detector_input_width, height, channels, *normalisation, target.name)


def load_whole_images(workspace: Workspace, terms: DetectorContract) -> dict[str, np.ndarray]:
    """Whole training images resized to the detector's input (N, H, W, C) uint8, their masks
    (N, H, W) uint8 and boxes (N, 4) in input pixels (the mask's box, as a label's)."""
    rows = sorted(read_manifest(workspace, "train").to_pylist(), key=lambda r: r["sample_id"])
    if not rows:
        raise ValueError(f"{workspace.manifest_dir('train')}: no training images; run render --set train")
    depth = 3 if terms.channels == "rgb" else 1
    out = {"images": np.empty((len(rows), terms.height, terms.width, depth), np.uint8),
           "masks": np.empty((len(rows), terms.height, terms.width), np.uint8), "boxes": np.empty((len(rows), 4))}
    for index, row in enumerate(track(rows, len(rows), "load whole training images", rows=[0] * len(rows))):
        image = to_uint8(read_image(workspace.fetch(row["image_path"]), "bgr"))
        mask = to_uint8(read_image(workspace.fetch(row["mask_path"]), "bgr"))
        out["images"][index] = whole_image(image, terms)
        out["masks"][index] = whole_image(mask, terms)[..., 0]
        scale = np.array([terms.width / image.shape[1], terms.height / image.shape[0]] * 2)
        out["boxes"][index] = (np.asarray(row["bbox_px"], float) + 0.5) * scale - 0.5
    return out


def zoom(images: np.ndarray, masks: np.ndarray, boxes: np.ndarray, rng: np.random.Generator,
         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Images (N, H, W, C), masks (N, H, W) and boxes (N, 4) [px] zoomed by 0.7 to 1.4 about
    a random point and shifted by up to a fifth of the image; black comes in from outside."""
    n, height, width = images.shape[:3]
    out_images, out_masks, out_boxes = np.empty_like(images), np.empty_like(masks), np.empty_like(boxes)
    for index in range(n):
        factor = math.exp(rng.uniform(math.log(0.7), math.log(1.4)))
        about = rng.uniform((0, 0), (width - 1, height - 1))
        warp = np.array([[factor, 0.0, 0.0], [0.0, factor, 0.0]])
        warp[:, 2] = about * (1 - factor) + rng.uniform(-0.2, 0.2, 2) * (width, height)
        out_images[index] = cv2.warpAffine(images[index], warp, (width, height), flags=cv2.INTER_LINEAR,
                                           borderMode=cv2.BORDER_CONSTANT).reshape(images.shape[1:])
        out_masks[index] = cv2.warpAffine(masks[index], warp, (width, height), flags=cv2.INTER_LINEAR,
                                          borderMode=cv2.BORDER_CONSTANT)
        out_boxes[index] = boxes[index] * factor + np.tile(warp[:, 2], 2)
    return out_images, out_masks, out_boxes


def mask_targets(masks: np.ndarray) -> np.ndarray:
    """The share of each heatmap pixel the target covers (N, 1, H / STRIDE, W / STRIDE)
    float32, of masks (N, H, W) uint8."""
    n, height, width = masks.shape
    small = [cv2.resize(mask, (width // STRIDE, height // STRIDE), interpolation=cv2.INTER_AREA) for mask in masks]
    return (np.stack(small)[:, None] / 255.0).astype(np.float32)


def train_detector(data: dict[str, np.ndarray], recipe: ReferenceConfig, terms: DetectorContract) -> tuple[Any, list]:
    """The trained network (torch, eval mode: the mask's logits at half the input's
    resolution) and its log."""
    import torch

    from stages.reference.network import KeypointNet

    torch.manual_seed(recipe.seed)
    torch.set_num_threads(recipe.threads)
    rng = np.random.default_rng(recipe.seed)
    model = KeypointNet(1, recipe.width, STRIDE, len(terms.mean))
    steps_per_epoch = max(1, len(data["images"]) // recipe.batch_size)
    total = recipe.detector_epochs * steps_per_epoch if recipe.max_steps == 0 else recipe.max_steps
    optimiser = torch.optim.Adam(model.parameters(), lr=recipe.learning_rate)
    schedule = torch.optim.lr_scheduler.LambdaLR(
        optimiser, lambda step: 0.02 + 0.98 * 0.5 * (1 + math.cos(math.pi * min(step, total) / total)))
    log, step, started = [], 0, time.perf_counter()
    model.train()
    while step < total:
        order = rng.permutation(len(data["images"]))
        for first in range(0, steps_per_epoch * recipe.batch_size, recipe.batch_size):
            if step >= total:
                break
            batch = order[first:first + recipe.batch_size]
            images, masks, _ = zoom(data["images"][batch], data["masks"][batch], data["boxes"][batch], rng)
            x = torch.from_numpy(normalise(augment("robust", images, masks, rng), terms))
            target = torch.from_numpy(mask_targets(masks))
            loss = torch.nn.functional.binary_cross_entropy_with_logits(model(x), target)
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
            schedule.step()
            step += 1
            if step % steps_per_epoch == 0 or step == total:
                log.append({"step": step, "epoch": step / steps_per_epoch, "loss": loss.item(),
                            "seconds": time.perf_counter() - started})
                console.print(f"train-reference detector: epoch {step / steps_per_epoch:.1f}/"
                              f"{total / steps_per_epoch:.0f} loss {loss.item():.5f} "
                              f"({time.perf_counter() - started:.0f} s)")
    model.eval()
    return model, log


def export_detector(model: Any, terms: DetectorContract, out: Path, extra_metadata: dict[str, str]) -> None:
    """ONNX (opset ``OPSET``, IR version ``IR_VERSION``) with the output ``mask`` (after its
    sigmoid) and the detector contract."""
    import onnx
    import torch

    class Exported(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.net = model

        def forward(self, x: torch.Tensor) -> torch.Tensor:
            return torch.sigmoid(self.net(x))

    out.parent.mkdir(parents=True, exist_ok=True)
    temporary = temporary_name(out)
    dummy = torch.zeros(1, len(terms.mean), terms.height, terms.width)
    axes = {name: {0: "batch"} for name in ("image", "mask")}
    torch.onnx.export(Exported().eval(), (dummy,), str(temporary), input_names=["image"],
                      output_names=["mask"], dynamic_axes=axes, opset_version=OPSET, dynamo=False)
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


def box_iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Intersection over union of boxes (N, 4) and (N, 4) (x_min, y_min, x_max, y_max)."""
    width = np.clip(np.minimum(a[:, 2], b[:, 2]) - np.maximum(a[:, 0], b[:, 0]), 0, None)
    height = np.clip(np.minimum(a[:, 3], b[:, 3]) - np.maximum(a[:, 1], b[:, 1]), 0, None)
    inter = width * height
    union = np.prod(a[:, 2:] - a[:, :2], axis=1) + np.prod(b[:, 2:] - b[:, :2], axis=1) - inter
    return np.where(union > 0, inter / np.where(union > 0, union, 1), 0.0)


def _found(path: Path, data: dict[str, np.ndarray]) -> np.ndarray:
    """The exported detector's boxes (N, 4) of prepared whole images, in input pixels, before
    its ``box_scale``."""
    detector = Detector(path, threads=2)
    found = []
    for first in range(0, len(data["images"]), 32):
        pixels = data["images"][first:first + 32]
        (masks,) = detector.session.run(None, {detector.input_name: normalise(pixels / 255.0, detector.contract)})
        found.append(decode_boxes(masks, detector.contract.width, detector.contract.height)[0])
    return np.concatenate(found)


def box_scale(found: np.ndarray, boxes: np.ndarray) -> float:
    """The median ratio of the labels' box sides to the found ones (both axes), rounded to
    0.01: what the detector's boxes miss of the projected model (unlit faces, antennas)."""
    ratio = (boxes[:, 2:] - boxes[:, :2]) / np.maximum(found[:, 2:] - found[:, :2], 1.0)
    return float(np.clip(round(float(np.median(ratio)), 2), 0.5, 2.0))


def scaled(boxes: np.ndarray, factor: float) -> np.ndarray:
    """Boxes (N, 4) scaled about their centres by ``factor``."""
    centres, halves = (boxes[:, :2] + boxes[:, 2:]) / 2, (boxes[:, 2:] - boxes[:, :2]) / 2 * factor
    return np.concatenate([centres - halves, centres + halves], axis=1)


def held_out_boxes(path: Path, data: dict[str, np.ndarray]) -> dict[str, float]:
    """The exported detector's box IoU on held-out whole images (in input pixels), with its
    ``box_scale`` set from them into its metadata (the IoU before it too)."""
    import onnx

    found = _found(path, data)
    factor = box_scale(found, data["boxes"])
    proto = onnx.load(str(path))
    entry = proto.metadata_props.add()
    entry.key, entry.value = "speedplus.box_scale", repr(factor)
    temporary = temporary_name(path)
    onnx.save(proto, str(temporary))
    temporary.replace(path)
    iou, unscaled = box_iou(scaled(found, factor), data["boxes"]), box_iou(found, data["boxes"])
    return {"images": len(iou), "box_scale": factor, "median_box_iou": float(np.median(iou)),
            "mean_box_iou": float(np.mean(iou)), "share_box_iou_0.9": float(np.mean(iou >= 0.9)),
            "share_box_iou_0.5": float(np.mean(iou >= 0.5)), "median_box_iou_unscaled": float(np.median(unscaled))}


def run(config: Config, workspace: Workspace, out: Path, target: Target, channels: Channels,
        normalisation: tuple[tuple[float, ...], tuple[float, ...]]) -> dict[str, Any]:
    """Train the detector on the training set (the last tenth held out, as the keypoint
    models'), export it to ``out`` and write its card beside it; returns the card."""
    from stages.common.cameras import train_camera

    camera = train_camera(config)
    terms = detector_contract(config.reference, camera.width / camera.height, target, channels, normalisation)
    data = load_whole_images(workspace, terms)
    held = max(1, len(data["images"]) // 10)
    training = {key: value[:-held] for key, value in data.items()}
    held_out = {key: value[-held:] for key, value in data.items()}
    started = time.perf_counter()
    model, log = train_detector(training, config.reference, terms)
    seconds = time.perf_counter() - started
    export_detector(model, terms, out, {"speedplus.recipe": json.dumps(asdict(config.reference))})
    card = {"model": str(out.name), "variant": "detector", "augmentation": "robust",
            "training_images": len(training["images"]), "held_out_images": held,
            "train_seconds": round(seconds, 1), "recipe": asdict(config.reference),
            "held_out": held_out_boxes(out, held_out),
            "camera": {"sensor": config.camera.sensor, "gamma": config.camera.gamma},
            "render": {"count": config.render.train_count, "seed": config.render.seed,
                       "resolution_scale": config.render.train_resolution_scale, "spp": config.render.train_spp},
            "log": log}
    write_json_atomic(out.with_suffix(".json"), card)
    return card
