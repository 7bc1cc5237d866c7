"""The ONNX model contract: what a model's metadata (``metadata_props``) must say for
``evaluate`` to feed it and read it, the keys of ``CONTRACT_KEYS`` (docs/models.md's table
is generated from it by ``python -m stages.common.contract_tables``), parsed into a
``ModelContract`` with errors that name the file and the key."""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Literal

import numpy as np

from manifests.schema import NAME_PATTERN
from speedplus.errors import InputError
from stages.common import tango

CONTRACT_VERSION = "1"


#: the contract's metadata keys -> what each holds (Markdown); "optional" ones may be absent
CONTRACT_KEYS: dict[str, str] = {
    "speedplus.contract": "`1`",
    "speedplus.input_size": "`WxH` of the single input `(N, C, H, W)` float32, e.g. `192x192`",
    "speedplus.channels": "`rgb` (C = 3) or `gray` (C = 1): what the camera gives is `gray` for a mono camera "
                          "(the default, as SPEED+: testbed images and twins are grey); an `rgb` model sees a grey "
                          "image in all three channels, a `gray` model a colour image's luminance",
    "speedplus.normalize": "`mean/std` per channel for pixel values scaled to [0, 1], e.g. "
                           "`0.485,0.456,0.406/0.229,0.224,0.225`",
    "speedplus.output": "`keypoints` (N, K, 2) in input pixels; `heatmaps` (N, K, h, w), heatmap pixel centres "
                        "spread evenly over the input; or `pose` (two outputs, q (N, 4) Hamilton w first and t "
                        "(N, 3) m, full scale, of `cam_from_target`)",
    "speedplus.keypoints": "`tango11` (the 11 keypoints of docs/architecture.md section 7, in order) or a JSON list "
                           "of K body-frame points (m, full scale)",
    "speedplus.crop": "`full` (whole image resized to the input) or `oracle_box` (a square of 1.25 times the "
                      "larger side of the label's keypoint box, resized; scores are then those of the pose network "
                      "given a perfect detector, and the report says so)",
    "speedplus.turns": "optional: `4` for a heatmap model with a square input trained at every rotation: its "
                       "heatmaps of the crop turned by 0, 90, 180 and 270 deg, turned back, are averaged "
                       "(`evaluate.turns = false`: one pass); absent: `1`",
    "speedplus.target": "optional: the name of the target the model was trained on (its `target.toml` `name`); "
                        "absent: `tango`. `evaluate` refuses a model of another target than the workspace's",
}


#: the target of a model whose contract names none (every model made before targets had names)
BUILTIN_TARGET = "tango"


OUTPUT_KINDS = ("keypoints", "heatmaps", "pose")


CROPS = ("full", "oracle_box")


OPSET = 17


IR_VERSION = 8  # onnxruntime 1.31 reads IR versions up to 13


#: an oracle_box crop is a square of this many times the box's larger side
CROP_MARGIN = 1.25


#: what a model takes: three channels, or one grey channel (a mono camera's image; a colour
#: model given a mono camera's image sees its grey in all three channels)
Channels = Literal["rgb", "gray"]


@dataclass(frozen=True)
class ModelContract:
    width: int
    height: int
    channels: Channels
    mean: tuple[float, ...]
    std: tuple[float, ...]
    output: str
    keypoints_m: np.ndarray  # (K, 3) body frame, full scale
    crop: str
    turns: int = 1
    target: str = BUILTIN_TARGET

    def metadata(self) -> dict[str, str]:
        """The ``metadata_props`` that state this contract (for exporters)."""
        keypoints = ("tango11" if self.keypoints_m.shape == tango.KEYPOINTS_M.shape
                     and np.allclose(self.keypoints_m, tango.KEYPOINTS_M) else json.dumps(self.keypoints_m.tolist()))
        return {
            "speedplus.contract": CONTRACT_VERSION,
            "speedplus.input_size": f"{self.width}x{self.height}",
            "speedplus.channels": self.channels,
            "speedplus.normalize": ",".join(map(str, self.mean)) + "/" + ",".join(map(str, self.std)),
            "speedplus.output": self.output,
            "speedplus.keypoints": keypoints,
            "speedplus.crop": self.crop,
            **({"speedplus.turns": str(self.turns)} if self.turns != 1 else {}),
            **({"speedplus.target": self.target} if self.target != BUILTIN_TARGET else {}),
        }


def parse_contract(metadata: dict[str, str], source: str) -> ModelContract:
    """The contract stated by a model's metadata; InputError naming the key otherwise."""
    def need(key: str) -> str:
        if key not in metadata:
            raise InputError(f"{source}: ONNX metadata key {key!r} missing; a model must state "
                             "speedplus.contract/input_size/channels/normalize/output/keypoints/crop "
                             "(docs/models.md, \"the ONNX model contract\", gives each key and an export recipe)")
        return metadata[key]

    def fail(key: str, expected: str) -> InputError:
        return InputError(f"{source}: ONNX metadata {key}={metadata.get(key)!r}; expected {expected}")

    if need("speedplus.contract") != CONTRACT_VERSION:
        raise fail("speedplus.contract", CONTRACT_VERSION)
    try:
        width, height = (int(v) for v in need("speedplus.input_size").lower().split("x"))
    except ValueError:
        raise fail("speedplus.input_size", "WIDTHxHEIGHT, e.g. 256x160") from None
    channels = need("speedplus.channels")
    if channels not in ("rgb", "gray"):
        raise fail("speedplus.channels", "rgb or gray")
    count = 3 if channels == "rgb" else 1
    try:
        mean_text, std_text = need("speedplus.normalize").split("/")
        mean = tuple(float(v) for v in mean_text.split(","))
        std = tuple(float(v) for v in std_text.split(","))
    except ValueError:
        raise fail("speedplus.normalize", f"{count} means / {count} standard deviations, comma-separated") from None
    if len(mean) != count or len(std) != count or min(std) <= 0:
        raise fail("speedplus.normalize", f"{count} means / {count} positive standard deviations")
    output = need("speedplus.output")
    if output not in OUTPUT_KINDS:
        raise fail("speedplus.output", " or ".join(OUTPUT_KINDS))
    keypoints_text = need("speedplus.keypoints")
    try:
        keypoints = (tango.KEYPOINTS_M.copy() if keypoints_text == "tango11"
                     else np.asarray(json.loads(keypoints_text), float))
    except (ValueError, TypeError):
        raise fail("speedplus.keypoints", "tango11 or a JSON list of [x, y, z] metres") from None
    if keypoints.ndim != 2 or keypoints.shape[1] != 3 or len(keypoints) < 4:
        raise fail("speedplus.keypoints", "at least 4 points [x, y, z]")
    crop = need("speedplus.crop")
    if crop not in CROPS:
        raise fail("speedplus.crop", " or ".join(CROPS))
    turns = metadata.get("speedplus.turns", "1")
    if turns not in ("1", "4") or (turns == "4" and (output != "heatmaps" or width != height)):
        raise fail("speedplus.turns", "1, or 4 for a heatmap model with a square input")
    target = metadata.get("speedplus.target", BUILTIN_TARGET)
    if not NAME_PATTERN.fullmatch(target):
        raise fail("speedplus.target", "a target's name (a-z, 0-9, _ and -)")
    return ModelContract(width, height, channels, mean, std, output, keypoints, crop, int(turns), target)
