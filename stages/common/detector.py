"""The object detector that gives a keypoint model its own crop (``evaluate``'s ``self``
crop), as the paper's reference pipeline crops with a trained detection network (Park et
al. 2019): an ONNX model of the whole image at reduced resolution that outputs a heatmap of
the target's pixels (the probability that the target covers each heatmap pixel); the box is
the extent of its largest region above one half.

Why the target's pixels and not its centre and size (CenterNet, tried first): a target
that fills half the image has its centre far from any of its edges, which a small network
must see all at once; whether a pixel is the target needs only its neighbourhood. Trained
on the same 2,700 images and the same recipe, the centre-and-size detector found held-out
boxes with a median IoU of 0.52 (docs/models.md, "The detector").

Its metadata (``metadata_props``): the keys of ``DETECTOR_KEYS`` (docs/models.md's table is
generated from it by ``python -m stages.common.contract_tables``).

Output: ``mask`` (N, 1, h, w) in [0, 1], heatmap pixels tiling the input evenly (each
``W / w`` x ``H / h`` input pixels). A box edge lies where the mask's profile across it
crosses one half, interpolated between heatmap pixel centres: a heatmap pixel that the
target covers in part learns that part, so the crossing finds the edge within the pixel.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from speedplus.errors import InputError
from stages.common.model_contract import BUILTIN_TARGET, Channels
from stages.common.model_input import normalise_uint8

CONTRACT = "1"
#: the detector contract's metadata keys -> what each holds (Markdown)
DETECTOR_KEYS: dict[str, str] = {
    "speedplus.detector": "`1` (this contract's version)",
    "speedplus.input_size": "`WxH`: the whole image is resized to it; input (N, C, H, W) float32",
    "speedplus.channels": "`rgb` or `gray`",
    "speedplus.normalize": "`mean/std` per channel on pixel values in [0, 1]",
    "speedplus.target": "optional: the target it was made for (absent: Tango)",
    "speedplus.box_scale": "optional: each box is scaled about its centre by this factor (absent: 1): "
                           "train-reference sets it to the median ratio of the held-out labels' box sides to the "
                           "detector's, since the label's box holds parts no image shows (unlit faces, thin "
                           "antennas)",
}
#: the file name a detector has beside the keypoint models (W/models/, models/)
DETECTOR_NAME = "detector"


@dataclass(frozen=True)
class DetectorContract:
    width: int
    height: int
    channels: Channels
    mean: tuple[float, ...]
    std: tuple[float, ...]
    target: str = BUILTIN_TARGET
    box_scale: float = 1.0

    def metadata(self) -> dict[str, str]:
        return {"speedplus.detector": CONTRACT, "speedplus.input_size": f"{self.width}x{self.height}",
                "speedplus.channels": self.channels,
                "speedplus.normalize": ",".join(map(str, self.mean)) + "/" + ",".join(map(str, self.std)),
                **({"speedplus.target": self.target} if self.target != BUILTIN_TARGET else {}),
                **({"speedplus.box_scale": repr(self.box_scale)} if self.box_scale != 1.0 else {})}


def parse_detector_contract(metadata: dict[str, str], source: str) -> DetectorContract:
    """The contract of a detector's metadata; an InputError naming ``source`` and the key."""
    def need(key: str) -> str:
        if key not in metadata:
            raise InputError(f"{source}: not a detector: metadata key {key} is missing (stages/common/detector.py)")
        return metadata[key]

    if need("speedplus.detector") != CONTRACT:
        raise InputError(f"{source}: speedplus.detector={metadata['speedplus.detector']}, expected {CONTRACT}")
    try:
        width, height = (int(v) for v in need("speedplus.input_size").split("x"))
        mean_text, std_text = need("speedplus.normalize").split("/")
        mean = tuple(float(v) for v in mean_text.split(","))
        std = tuple(float(v) for v in std_text.split(","))
    except ValueError:
        raise InputError(f"{source}: speedplus.input_size must be WxH and speedplus.normalize mean/std") from None
    channels = need("speedplus.channels")
    if channels not in ("rgb", "gray") or len(mean) != len(std) or len(mean) != (3 if channels == "rgb" else 1):
        raise InputError(f"{source}: speedplus.channels={channels} with {len(mean)} means, {len(std)} stds")
    try:
        box_scale = float(metadata.get("speedplus.box_scale", "1"))
    except ValueError:
        box_scale = float("nan")
    if not 0.5 <= box_scale <= 2.0:
        raise InputError(f"{source}: speedplus.box_scale={metadata['speedplus.box_scale']}: expected a factor in "
                         "0.5-2")
    return DetectorContract(width, height, channels, mean, std, metadata.get("speedplus.target", BUILTIN_TARGET),
                            box_scale)


def whole_image(image_bgr: np.ndarray, contract: DetectorContract) -> np.ndarray:
    """The detector's input pixels (H, W, C) uint8 of an image (h, w, 3) BGR uint8: the whole
    image resized (area averaging when shrinking)."""
    height, width = image_bgr.shape[:2]
    shrinking = width > contract.width or height > contract.height
    resized = cv2.resize(image_bgr, (contract.width, contract.height),
                         interpolation=cv2.INTER_AREA if shrinking else cv2.INTER_LINEAR)
    if resized.ndim == 2:
        resized = resized[..., None]
    if contract.channels == "rgb":
        return np.ascontiguousarray(np.broadcast_to(resized, (*resized.shape[:2], 3))[..., ::-1])
    return resized[..., :1] if resized.shape[-1] == 1 else cv2.cvtColor(resized, cv2.COLOR_BGR2GRAY)[..., None]


def _edge(profile: np.ndarray) -> float:
    """Where a profile (n,) [0, 1] along an axis first reaches one half, in heatmap pixels
    (its pixel centres at 0, 1, ...), interpolated linearly from the pixel before; the
    heatmap's own edge (-0.5) where its first pixel does."""
    first = int(np.argmax(profile >= 0.5))
    if first == 0:
        return -0.5
    below, above = profile[first - 1], profile[first]
    return first - 1 + float((0.5 - below) / max(above - below, 1e-9))


def decode_boxes(masks: np.ndarray, input_width: int, input_height: int) -> tuple[np.ndarray, np.ndarray]:
    """Boxes (N, 4) (x_min, y_min, x_max, y_max) in input pixels (pixel centres at integer
    coordinates) and their confidences (N,) (the region's highest value) from masks
    (N, 1, h, w): the largest connected region of at least one half (of at least half the
    mask's highest value where nothing reaches it), its edges where the profiles of the
    region's rows and columns cross one half."""
    n, _, rows, cols = masks.shape
    scale_x, scale_y = input_width / cols, input_height / rows
    boxes, confidence = np.empty((n, 4)), np.empty(n)
    for index in range(n):
        mask = np.asarray(masks[index, 0], np.float64)
        if not mask.max() > 1e-6:  # an empty mask: the whole input
            boxes[index], confidence[index] = (0.0, 0.0, input_width - 1.0, input_height - 1.0), 0.0
            continue
        level = min(0.5, 0.5 * float(mask.max()))
        _, labels, stats, _ = cv2.connectedComponentsWithStats((mask >= level).astype(np.uint8), connectivity=8)
        largest = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
        region = cv2.dilate((labels == largest).astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
        inside = np.where(region, mask, 0.0) / (level / 0.5)
        across, down = inside.max(axis=0), inside.max(axis=1)
        x0, x1 = _edge(across), cols - 1 - _edge(across[::-1])
        y0, y1 = _edge(down), rows - 1 - _edge(down[::-1])
        # heatmap pixel edges (k +- 0.5) -> input pixel edges, then in to the extreme pixels' centres
        box = np.array([(x0 + 0.5) * scale_x - 0.5, (y0 + 0.5) * scale_y - 0.5,
                        (x1 + 0.5) * scale_x - 0.5, (y1 + 0.5) * scale_y - 0.5])
        boxes[index] = box + np.array([0.5, 0.5, -0.5, -0.5])
        confidence[index] = float(mask[labels == largest].max())
    return boxes, confidence


def to_image(boxes: np.ndarray, contract: DetectorContract, width: int, height: int) -> np.ndarray:
    """Boxes (N, 4) in input pixels -> image pixels of an image ``width`` x ``height``
    (pixel centres at integer coordinates in both)."""
    scale = np.array([width / contract.width, height / contract.height] * 2)
    return (np.asarray(boxes, float) + 0.5) * scale - 0.5


class Detector:
    """An ONNX Runtime session of a detector with its contract."""

    def __init__(self, path: Path | bytes, threads: int = 1, name: str = "") -> None:
        import onnxruntime as ort

        source = (name or DETECTOR_NAME) if isinstance(path, bytes) else str(path)
        if not isinstance(path, bytes) and not Path(path).is_file():
            raise InputError(f"{source}: detector file not found")
        options = ort.SessionOptions()
        options.intra_op_num_threads, options.inter_op_num_threads = max(1, threads), 1
        try:
            self.session = ort.InferenceSession(path if isinstance(path, bytes) else source, options,
                                                providers=["CPUExecutionProvider"])
        except Exception as error:  # noqa: BLE001 - onnxruntime raises several types for unreadable models
            raise InputError(f"{source}: not a loadable ONNX model ({error})") from None
        self.source = source
        self.contract = parse_detector_contract(self.session.get_modelmeta().custom_metadata_map, source)
        names = [output.name for output in self.session.get_outputs()]
        if names != ["mask"]:
            raise InputError(f"{source}: a detector has one output, mask, got {names}")
        self.input_name = self.session.get_inputs()[0].name

    def boxes(self, images_bgr: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """The target's box (N, 4) in each image's pixels and its confidence (N,)."""
        if not images_bgr:
            return np.empty((0, 4)), np.empty(0)
        pixels = np.stack([whole_image(image, self.contract) for image in images_bgr])
        (masks,) = self.session.run(None, {self.input_name: normalise_uint8(pixels, self.contract)})
        boxes, peaks = decode_boxes(np.asarray(masks, float), self.contract.width, self.contract.height)
        centres, halves = (boxes[:, :2] + boxes[:, 2:]) / 2, (boxes[:, 2:] - boxes[:, :2]) / 2 * self.contract.box_scale
        boxes = np.concatenate([centres - halves, centres + halves], axis=1)
        return np.stack([to_image(box[None], self.contract, image.shape[1], image.shape[0])[0]
                         for box, image in zip(boxes, images_bgr, strict=True)]), peaks
