"""The object detector that gives a keypoint model its own crop (``evaluate``'s ``self``
crop), as the paper's reference pipeline crops with a trained detection network (Park et
al. 2019): an ONNX model of the whole image at reduced resolution that outputs a heatmap of
the target's centre and the box's size at every heatmap pixel, after CenterNet (Zhou,
Wang and Kraehenbuehl, "Objects as Points", 2019), for one object.

Its metadata (``metadata_props``):

=========================  ==============================================================
key                        value
=========================  ==============================================================
``speedplus.detector``     ``1`` (this contract's version)
``speedplus.input_size``   ``WxH``: the whole image is resized to it; input (N, C, H, W)
                           float32
``speedplus.channels``     ``rgb`` or ``gray``
``speedplus.normalize``    ``mean/std`` per channel on pixel values in [0, 1]
``speedplus.target``       optional: the target it was made for (absent: Tango)
=========================  ==============================================================

Outputs: ``centre`` (N, 1, h, w) in [0, 1], and ``size`` (N, 2, h, w), the box's width and
height in input pixels, at every heatmap pixel; heatmap pixel centres spread evenly over
the input (as a heatmap model's). The box is read at the centre heatmap's highest peak
(refined to sub-pixel by a parabola through the logarithms of the peak and its neighbours)
and mapped to the image.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from speedplus.errors import InputError
from stages.common.pose_model import BUILTIN_TARGET, Channels, normalise_uint8, parabola_offset

CONTRACT = "1"
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

    def metadata(self) -> dict[str, str]:
        return {"speedplus.detector": CONTRACT, "speedplus.input_size": f"{self.width}x{self.height}",
                "speedplus.channels": self.channels,
                "speedplus.normalize": ",".join(map(str, self.mean)) + "/" + ",".join(map(str, self.std)),
                **({"speedplus.target": self.target} if self.target != BUILTIN_TARGET else {})}


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
    return DetectorContract(width, height, channels, mean, std, metadata.get("speedplus.target", BUILTIN_TARGET))


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


def decode_boxes(centre: np.ndarray, size: np.ndarray, input_width: int, input_height: int,
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Boxes (N, 4) (x_min, y_min, x_max, y_max) in input pixels and their peak values (N,)
    of centre heatmaps (N, 1, h, w) and size maps (N, 2, h, w) [input px]."""
    n, _, rows, cols = centre.shape
    boxes, peaks = np.empty((n, 4)), np.empty(n)
    for index in range(n):
        # a parabola through the logarithms: exact at a Gaussian peak, as the detector learns
        heat = np.log(np.maximum(centre[index, 0], 1e-12))
        row, col = np.unravel_index(int(np.argmax(heat)), heat.shape)
        dx = float(parabola_offset(heat[row, col - 1], heat[row, col], heat[row, col + 1])) if 0 < col < cols - 1 \
            else 0.0
        dy = float(parabola_offset(heat[row - 1, col], heat[row, col], heat[row + 1, col])) if 0 < row < rows - 1 \
            else 0.0
        scale_x, scale_y = input_width / cols, input_height / rows
        cx, cy = (col + dx + 0.5) * scale_x - 0.5, (row + dy + 0.5) * scale_y - 0.5
        half_w, half_h = size[index, 0, row, col] / 2, size[index, 1, row, col] / 2
        boxes[index] = (cx - half_w, cy - half_h, cx + half_w, cy + half_h)
        peaks[index] = centre[index, 0, row, col]
    return boxes, peaks


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
        if names != ["centre", "size"]:
            raise InputError(f"{source}: a detector's outputs are centre and size, got {names}")
        self.input_name = self.session.get_inputs()[0].name

    def boxes(self, images_bgr: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """The target's box (N, 4) in each image's pixels and the peak (N,) of its centre."""
        if not images_bgr:
            return np.empty((0, 4)), np.empty(0)
        pixels = np.stack([whole_image(image, self.contract) for image in images_bgr])
        centre, size = self.session.run(None, {self.input_name: normalise_uint8(pixels, self.contract)})
        boxes, peaks = decode_boxes(np.asarray(centre, float), np.asarray(size, float), self.contract.width,
                                    self.contract.height)
        return np.stack([to_image(box[None], self.contract, image.shape[1], image.shape[0])[0]
                         for box, image in zip(boxes, images_bgr, strict=True)]), peaks
