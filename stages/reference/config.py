"""The reference stage's configuration: section [reference], each key with its unit and
meaning (``speedplus keys reference``), and the rules types cannot express
(``check``). ``SECTIONS``: what ``pipeline/config.py`` gathers (docs/architecture.md section 2)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

from core.config.params import param

if TYPE_CHECKING:
    from core.config.model import Config

#: the reference models: ``plain`` (photometric jitter) and ``augmented`` (the robust recipe of
#: stages/reference/augment.py), named reference and reference_augmented
ReferenceVariant = Literal["plain", "augmented", "detector"]


@dataclass(frozen=True)
class ReferenceConfig:
    """speedplus train-reference: the recipe of the reference keypoint CNN (torch)."""

    images: int = param(3000, "training-set images rendered for it (90% train, 10% held out)", "count")
    resolution_scale: float = param(1.0, "training images: camera resolution times this", "1")
    input_width: int = param(192, "network input width (the crop around the target is resized to it)", "px")
    input_height: int = param(192, "network input height", "px")
    width: int = param(16, "channels of the network's first layer (the others are multiples)", "count")
    epochs: int = param(45, "passes over the training images", "count")
    batch_size: int = param(32, "images per optimiser step", "count")
    learning_rate: float = param(2e-3, "Adam's initial learning rate (cosine decay to 2% of it)", "1")
    heatmap_sigma: float = param(1.0, "standard deviation of the target Gaussians, in heatmap pixels", "px")
    heatmap_stride: Literal[2, 4] = param(4, "input pixels per heatmap pixel (2: heatmaps of half the input's "
                                          "resolution, 4: a quarter)", "px")
    wide_crops: float = param(0.0, "share of training crops taken wide (the box 1.2 to 6 times larger, shifted): "
                              "the model also finds a small target, as the self crop's first pass needs", "1")
    rotation: bool = param(True, "rotate every training crop by a random angle in the image plane (with a random "
                           "scale of 1 +- 0.15 and shift of +- 6%); off: scale and shift only", "")
    variants: tuple[ReferenceVariant, ...] = param(
        ("plain", "augmented", "detector"), "models to train: plain (photometric jitter: models/reference.onnx), "
        "augmented (style, texture, Earth backgrounds, glare, blur, noise: models/reference_augmented.onnx), "
        "detector (the target's pixels in the whole image, the start of the self crop: models/detector.onnx)", "")
    detector_input_width: int = param(
        192, "detector: the whole image is resized to this width (the height keeps the camera's aspect, in "
        "multiples of 16); the keypoint passes after it refine its box", "px")
    detector_epochs: int = param(15, "detector: passes over the training images", "count")
    seed: int = param(0, "seed of initialisation, shuffling and augmentation", "")
    threads: int = param(2, "torch threads", "count")
    max_steps: int = param(0, "stop after this many optimiser steps (a quick check of the recipe); 0: the "
                           "whole recipe", "count")

    def check(self, config: Config) -> None:
        """Nothing beyond the types."""


#: this stage's sections: name -> dataclass
SECTIONS: dict[str, type] = {"reference": ReferenceConfig}
