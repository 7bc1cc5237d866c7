"""The ONNX model contract, preprocessing, output decoding and pose recovery.

Any ONNX model can be scored if its metadata (``metadata_props``) says how to feed it and
read it: the keys of ``CONTRACT_KEYS`` (docs/models.md's table is generated from it by
``python -m stages.common.contract_tables``).

Keypoint outputs become poses by AP3P inside RANSAC, then Levenberg-Marquardt refinement
on the inliers, with the label camera (intrinsics and distortion); without a consensus, by
EPnP on every point and a confidence-weighted refinement (``pose_from_keypoints``): finite
outputs always give a pose. Heatmap outputs keep several peaks per keypoint
(``heatmap_pnp``), falling back to this on their highest peaks.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import cv2
import numpy as np

from manifests.schema import NAME_PATTERN
from speedplus.errors import InputError
from stages.common import geometry as g
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
#: keypoints that must agree with a RANSAC pose for it to stand
MIN_CONSENSUS = 5
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


class PoseModel:
    """An ONNX Runtime session with its contract: ``preprocess`` turns an image (and the
    label's box, for ``oracle_box`` crops) into the model's input, ``infer`` runs a batch;
    evaluate turns the outputs into poses (``decode_heatmaps``, ``pose_from_keypoints``)."""

    def __init__(self, path: Path | bytes, threads: int = 1, name: str = "") -> None:
        """``path``: the model file, or its bytes (a worker that cannot see the file) with
        ``name`` to call it in messages."""
        import onnxruntime as ort

        source = (name or "model") if isinstance(path, bytes) else str(path)
        if not isinstance(path, bytes) and not Path(path).exists():
            raise InputError(f"{source}: model file not found")
        options = ort.SessionOptions()
        options.intra_op_num_threads = max(1, threads)
        options.inter_op_num_threads = 1
        try:
            self.session = ort.InferenceSession(path if isinstance(path, bytes) else source, options,
                                                providers=["CPUExecutionProvider"])
        except Exception as error:  # noqa: BLE001 - onnxruntime raises several types for unreadable models
            raise InputError(f"{source}: not a loadable ONNX model ({error})") from None
        self.source = source
        self.contract = parse_contract(self.session.get_modelmeta().custom_metadata_map, source)
        inputs = self.session.get_inputs()
        expected = [3 if self.contract.channels == "rgb" else 1, self.contract.height, self.contract.width]
        if len(inputs) != 1 or len(inputs[0].shape) != 4 or list(inputs[0].shape[1:]) != expected:
            raise InputError(f"{source}: input {[(i.name, i.shape) for i in inputs]} does not match the metadata; "
                             f"expected one input (N, {expected[0]}, {expected[1]}, {expected[2]})")
        self.input_name = inputs[0].name
        #: a model exported without dynamic axes takes batches of exactly this size (None: any)
        self.fixed_batch = inputs[0].shape[0] if isinstance(inputs[0].shape[0], int) else None
        outputs = self.session.get_outputs()
        if self.contract.output == "pose" and len(outputs) != 2:
            raise InputError(f"{source}: speedplus.output=pose needs two outputs (q, t), got {len(outputs)}")

    def preprocess(self, images_bgr: list[np.ndarray], boxes: list[np.ndarray | None],
                   ) -> tuple[np.ndarray, list[np.ndarray]]:
        """The (N, C, H, W) float32 input of crops of images around boxes (one each; the same
        image may come several times), and each crop's (3, 3) affine map from input pixels to
        image pixels. The crops are normalised together: one conversion, not N."""
        prepared = [prepare(image, self.contract, box) for image, box in zip(images_bgr, boxes, strict=True)]
        pixels = np.stack([crop for crop, _ in prepared])
        return normalise_uint8(pixels, self.contract), [affine for _, affine in prepared]

    def infer(self, batch: np.ndarray, turns: bool = True) -> list[np.ndarray]:
        """The model's outputs for a batch (N, C, H, W); with ``turns`` and a contract of 4
        turns, the mean of the heatmaps of the batch turned by k quarter turns, each turned
        back: a network trained at every rotation errs differently at each, and the
        mean keeps what they agree on (held-out synthetic images, the reference model:
        poses off by more than 10 deg 20% -> 16%, mean SPEED score 0.53 -> 0.27)."""
        if not turns or self.contract.turns == 1:
            return self._checked(self._run(batch))
        total = None
        for k in range(self.contract.turns):
            turned = np.ascontiguousarray(np.rot90(batch, k, axes=(2, 3)))
            heatmaps = self._run(turned)[0]
            if heatmaps.ndim != 4 or heatmaps.shape[2] != heatmaps.shape[3]:
                raise InputError(f"{self.source}: speedplus.turns=4 needs square heatmaps (N, K, h, h), "
                                 f"got {heatmaps.shape}")
            heatmaps = np.rot90(heatmaps, -k, axes=(2, 3))
            total = heatmaps.copy() if total is None else total + heatmaps
        return self._checked([np.ascontiguousarray(total / self.contract.turns)])

    def _run(self, batch: np.ndarray) -> list[np.ndarray]:
        """The session's outputs for (N, C, H, W): a model of a fixed batch size gets chunks of
        that size, the last padded with copies of its first image and the padding dropped."""
        size = self.fixed_batch
        if size is None or len(batch) == size:
            return self.session.run(None, {self.input_name: batch})
        chunks = []
        for start in range(0, len(batch), size):
            chunk = batch[start:start + size]
            real = len(chunk)
            if real < size:
                chunk = np.concatenate([chunk, np.repeat(chunk[:1], size - real, axis=0)])
            chunks.append([np.asarray(output)[:real] for output in self.session.run(None, {self.input_name: chunk})])
        return [np.concatenate([chunk[k] for chunk in chunks]) for k in range(len(chunks[0]))]

    def check(self) -> None:
        """Run one blank input through the model: its outputs must fit the contract (an
        InputError naming the file and what is wrong, before evaluate discards anything)."""
        channels = 3 if self.contract.channels == "rgb" else 1
        blank = np.zeros((self.fixed_batch or 1, channels, self.contract.height, self.contract.width), np.float32)
        try:
            self.infer(blank)
        except InputError:
            raise
        except Exception as error:  # noqa: BLE001 - onnxruntime's failures have many types
            raise InputError(f"{self.source}: the model fails on an input of its declared shape "
                             f"({' '.join(str(error).split())[:300]})") from None

    def _checked(self, outputs: list[np.ndarray]) -> list[np.ndarray]:
        """``outputs`` when their first is of the contract's shape: a model whose heatmaps or
        keypoints disagree with its keypoint list is an error naming it, not a traceback."""
        count = len(self.contract.keypoints_m)
        first = np.asarray(outputs[0])
        expected = {"heatmaps": f"(N, {count}, h, w)", "keypoints": f"(N, {count}, 2)"}.get(self.contract.output)
        fits = {"heatmaps": first.ndim == 4 and first.shape[1] == count and min(first.shape[2:], default=0) > 0,
                "keypoints": first.ndim == 3 and first.shape[1:] == (count, 2)}.get(self.contract.output, True)
        if not fits:
            raise InputError(f"{self.source}: speedplus.output={self.contract.output} needs {expected} for its "
                             f"{count} keypoints, got {first.shape}")
        return outputs


def parabola_offset(lo: np.ndarray, mid: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Sub-pixel position of a peak from its value and its two neighbours, in [-0.5, 0.5]."""
    curvature = lo - 2 * mid + hi
    safe = np.where(np.abs(curvature) > 1e-12, curvature, -1.0)
    return np.clip(np.where(np.abs(curvature) > 1e-12, 0.5 * (lo - hi) / safe, 0.0), -0.5, 0.5)


def crop_window(contract: ModelContract, width: int, height: int, box: np.ndarray | None) -> tuple[int, ...]:
    """The image window (x0, y0, w, h) in pixels that becomes the network input: the whole
    image, or a square of 1.25 times the box's larger side centred on the box."""
    if contract.crop == "full":
        return 0, 0, width, height
    if box is None or not np.all(np.isfinite(box)):
        raise InputError("speedplus.crop=oracle_box needs the label's box")
    centre = (np.asarray(box[:2], float) + np.asarray(box[2:], float)) / 2
    side = int(np.ceil(CROP_MARGIN * max(box[2] - box[0], box[3] - box[1], 8.0)))
    x0, y0 = (int(round(c - (side - 1) / 2)) for c in centre)
    return x0, y0, side, side


def prepare(image_bgr: np.ndarray, contract: ModelContract, box: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """The input image (H, W, C) uint8 (RGB or gray) and the (3, 3) affine map from input
    pixels to image pixels (pixel centres at integer coordinates in both)."""
    height, width = image_bgr.shape[:2]
    x0, y0, w, h = crop_window(contract, width, height, box)
    window = _window(image_bgr, x0, y0, w, h)
    shrinking = w > contract.width or h > contract.height
    resized = cv2.resize(window, (contract.width, contract.height),
                         interpolation=cv2.INTER_AREA if shrinking else cv2.INTER_LINEAR)
    pixels = resized[..., ::-1] if contract.channels == "rgb" else cv2.cvtColor(resized, cv2.COLOR_BGR2GRAY)[..., None]
    scale_x, scale_y = w / contract.width, h / contract.height
    image_from_input = np.array([[scale_x, 0, x0 + 0.5 * scale_x - 0.5], [0, scale_y, y0 + 0.5 * scale_y - 0.5],
                                 [0, 0, 1.0]])
    return np.ascontiguousarray(pixels), image_from_input


def _window(image: np.ndarray, x0: int, y0: int, w: int, h: int) -> np.ndarray:
    """The pixels (h, w, ...) of an image's window at (x0, y0), black outside the image: a
    view where the window is inside (an integer shift needs no resampling), else padded."""
    height, width = image.shape[:2]
    left, top, right, bottom = max(x0, 0), max(y0, 0), min(x0 + w, width), min(y0 + h, height)
    if right <= left or bottom <= top:
        return np.zeros((h, w, *image.shape[2:]), image.dtype)
    inside = image[top:bottom, left:right]
    if (left, top, right, bottom) == (x0, y0, x0 + w, y0 + h):
        return inside
    return cv2.copyMakeBorder(inside, top - y0, y0 + h - bottom, left - x0, x0 + w - right, cv2.BORDER_CONSTANT,
                              value=0)


def points_box(points_px: np.ndarray) -> np.ndarray:
    """x_min, y_min, x_max, y_max [px] of points (K, 2): the labels' box definition."""
    points_px = np.asarray(points_px, float)
    return np.concatenate([points_px.min(axis=0), points_px.max(axis=0)])


def apply_affine(affine: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Points (..., 2) through a (3, 3) affine map (e.g. ``prepare``'s image_from_input)."""
    return np.asarray(points, float) @ affine[:2, :2].T + affine[:2, 2]


def normalise(pixels: np.ndarray, contract: ModelContract) -> np.ndarray:
    """(..., H, W, C) values in [0, 1] -> (..., C, H, W) float32 normalised as the contract says."""
    out = (pixels - np.asarray(contract.mean, np.float32)) / np.asarray(contract.std, np.float32)
    return np.ascontiguousarray(np.moveaxis(out.astype(np.float32), -1, -3))


def normalise_uint8(pixels: np.ndarray, contract: ModelContract) -> np.ndarray:
    """``normalise`` of (..., H, W, C) uint8 pixels scaled to [0, 1], by a table of the 256
    values of each channel: the same float32 values, without converting every pixel."""
    table = normalise((np.arange(256, dtype=np.float32) / 255.0)[None, :, None], contract)[:, 0]  # (C, 256)
    channels = pixels.shape[-1]
    rows = pixels.reshape(-1, pixels.shape[-2], channels) if channels > 1 else pixels.reshape(-1, pixels.shape[-2])
    looked_up = cv2.LUT(np.ascontiguousarray(rows), np.ascontiguousarray(table.T[None]))
    return np.ascontiguousarray(np.moveaxis(looked_up.reshape(pixels.shape), -1, -3))


def decode_heatmaps(heatmaps: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Keypoints (N, K, 2) in input pixels and confidences (N, K) from heatmaps (N, K, h, w):
    the peak, refined by a parabola through its neighbours in x and in y."""
    n, k, h, w = heatmaps.shape
    ys, xs = np.divmod(heatmaps.reshape(n, k, -1).argmax(axis=-1), w)
    return peak_positions(heatmaps, ys, xs, width, height)


def peak_positions(heatmaps: np.ndarray, ys: np.ndarray, xs: np.ndarray, width: int,
                   height: int) -> tuple[np.ndarray, np.ndarray]:
    """Input-pixel positions (N, K, ..., 2) and values (N, K, ...) of heatmap pixels (ys, xs)
    (N, K, ...) of heatmaps (N, K, h, w) (a W x H input), each refined by a parabola through
    its neighbours in x and in y (not at the border)."""
    n, k, h, w = heatmaps.shape
    trailing = (1,) * (ys.ndim - 2)
    i, j = np.arange(n).reshape(n, 1, *trailing), np.arange(k).reshape(1, k, *trailing)
    peak = heatmaps[i, j, ys, xs]
    left, right = heatmaps[i, j, ys, np.maximum(xs - 1, 0)], heatmaps[i, j, ys, np.minimum(xs + 1, w - 1)]
    up, down = heatmaps[i, j, np.maximum(ys - 1, 0), xs], heatmaps[i, j, np.minimum(ys + 1, h - 1), xs]
    x = xs + parabola_offset(left, peak, right) * ((xs > 0) & (xs < w - 1))
    y = ys + parabola_offset(up, peak, down) * ((ys > 0) & (ys < h - 1))
    points = np.stack([(x + 0.5) * width / w - 0.5, (y + 0.5) * height / h - 0.5], axis=-1)
    return points, peak


#: how a prediction's pose was found: AP3P inside RANSAC, EPnP on all points (RANSAC found no
#: consensus), given by the model itself (``speedplus.output=pose``), or not at all
PNP_METHODS = ("ransac", "all_points", "direct", "none")


@dataclass(frozen=True)
class PnPSolution:
    """A pose recovered from keypoints: ``q`` (4,) and ``t`` (3,) [m] of cam_from_target,
    ``method`` (``PNP_METHODS``), the keypoints within the RANSAC threshold of it
    (``inliers``) and the reprojection RMS over every finite keypoint (``rms_px``)."""

    q: np.ndarray
    t: np.ndarray
    method: str
    inliers: int
    rms_px: float


def plausible(tvec: np.ndarray, object_points: np.ndarray, camera_matrix: np.ndarray) -> bool:
    """In front of the camera and at least a couple of pixels across (degenerate solutions
    at huge distances explain collapsed keypoints perfectly)."""
    return bool(in_reach(np.ravel(tvec), farthest_plausible_m(object_points, camera_matrix)))


def farthest_plausible_m(object_points: np.ndarray, camera_matrix: np.ndarray) -> float:
    """The distance [m] beyond which the object (K, 3) [m] would be under a couple of pixels
    across (``plausible``): computed once, for RANSAC's many samples."""
    radius = float(np.max(np.linalg.norm(object_points - object_points.mean(axis=0), axis=1)))
    return camera_matrix[0][0] * radius


def in_reach(tvec: np.ndarray, farthest_m: float) -> np.ndarray:
    """``plausible`` for translations (..., 3) [m] and the object's ``farthest_plausible_m``:
    (...) booleans (RANSAC asks it of a chunk of samples at once)."""
    tvec = np.asarray(tvec, float)
    return np.all(np.isfinite(tvec), axis=-1) & (tvec[..., 2] > 0) & (np.sqrt(np.sum(tvec ** 2, axis=-1)) <= farthest_m)


def spans(rvec: np.ndarray, tvec: np.ndarray, object_points: np.ndarray, camera_matrix: np.ndarray,
          dist: np.ndarray, extent_px: tuple[float, float] | None) -> bool:
    """Whether the object's points at a pose span (least, most) pixels in the image (the
    larger of the x and y extents); always true without ``extent_px``."""
    if extent_px is None:
        return True
    projected = cv2.projectPoints(object_points, rvec, tvec, camera_matrix, dist)[0][:, 0]
    span = (projected.max(axis=0) - projected.min(axis=0)).max()
    return bool(extent_px[0] <= span <= extent_px[1])


def _residuals(object_points: np.ndarray, image_points: np.ndarray, camera_matrix: np.ndarray, dist: np.ndarray,
               rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
    """(K,) reprojection distances [px]."""
    projected = cv2.projectPoints(object_points, rvec, tvec, camera_matrix, dist)[0][:, 0]
    return np.linalg.norm(projected - image_points, axis=1)


def _weighted_lm(object_points: np.ndarray, image_points: np.ndarray, camera_matrix: np.ndarray, dist: np.ndarray,
                 rvec: np.ndarray, tvec: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Levenberg-Marquardt on the reprojection errors, each weighted by its keypoint's
    confidence (OpenCV's refinement has no weights)."""
    from scipy.optimize import least_squares

    root = np.sqrt(weights)[:, None]

    def residual(x: np.ndarray) -> np.ndarray:
        projected = cv2.projectPoints(object_points, x[:3], x[3:], camera_matrix, dist)[0][:, 0]
        return ((projected - image_points) * root).ravel()

    start = np.concatenate([rvec.ravel(), tvec.ravel()])
    solution = least_squares(residual, start, method="lm", max_nfev=200)
    x = solution.x if np.all(np.isfinite(solution.x)) else start
    return x[:3].reshape(3, 1), x[3:].reshape(3, 1)


def pose_from_keypoints(keypoints_px: np.ndarray, keypoints_m: np.ndarray, camera_matrix: np.ndarray,
                        dist: np.ndarray, reprojection_px: float, confidence: np.ndarray | None = None,
                        extent_px: tuple[float, float] | None = None) -> PnPSolution | None:
    """The pose of cam_from_target from K image points (K, 2) [px] and body points (K, 3)
    [m], with the label camera: AP3P inside RANSAC (threshold ``reprojection_px``), then LM
    on the inliers; when RANSAC finds no plausible consensus (in front of the camera and,
    given ``extent_px``, spanning it: ``spans``), EPnP on every point, then LM with each
    residual weighted by its keypoint's ``confidence`` (K,) (heatmap peaks).
    None only when fewer than 4 keypoints are finite: finite outputs always give a pose."""
    image_points = np.asarray(keypoints_px, np.float64).reshape(-1, 2)
    finite = np.all(np.isfinite(image_points), axis=1)
    if finite.sum() < 4:
        return None
    object_points = np.ascontiguousarray(np.asarray(keypoints_m, np.float64)[finite])
    image_points = np.ascontiguousarray(image_points[finite])
    weights = np.ones(len(image_points)) if confidence is None else np.asarray(confidence, float)[finite]
    weights = np.clip(np.nan_to_num(weights, nan=0.0, posinf=1.0, neginf=0.0), 1e-3, None)
    method = "ransac"
    # minimal samples of 4 solved by AP3P: on the previous reference model's held-out
    # keypoints this found the right consensus more often than EPnP's samples (30% vs 32%
    # of poses off by more than 10 deg, median error 1.95 vs 2.8 deg) and 3x faster
    ok, rvec, tvec, inliers = cv2.solvePnPRansac(
        object_points, image_points, camera_matrix, dist, flags=cv2.SOLVEPNP_AP3P,
        reprojectionError=reprojection_px, iterationsCount=500, confidence=0.999)
    # a consensus is more than the sample: AP3P fits any 4 points (the 4th only picks a root)
    if ok and inliers is not None and len(inliers) >= MIN_CONSENSUS:
        chosen = inliers[:, 0]
        rvec, tvec = cv2.solvePnPRefineLM(object_points[chosen], image_points[chosen], camera_matrix, dist, rvec,
                                          tvec)
        ok = plausible(tvec[:, 0], object_points, camera_matrix) and spans(rvec, tvec, object_points, camera_matrix,
                                                                           dist, extent_px)
    else:
        ok = False
    if not ok:
        method = "all_points"
        ok, rvec, tvec = cv2.solvePnP(object_points, image_points, camera_matrix, dist, flags=cv2.SOLVEPNP_EPNP)
        if not ok or not (np.all(np.isfinite(rvec)) and np.all(np.isfinite(tvec))):
            ok, rvec, tvec = cv2.solvePnP(object_points, image_points, camera_matrix, dist, flags=cv2.SOLVEPNP_SQPNP)
        rvec, tvec = _weighted_lm(object_points, image_points, camera_matrix, dist, np.asarray(rvec, float),
                                  np.asarray(tvec, float), weights)
    residuals = _residuals(object_points, image_points, camera_matrix, dist, rvec, tvec)
    q, t = g.transform_to_qt(g.make_transform(cv2.Rodrigues(rvec)[0], tvec[:, 0]))
    return PnPSolution(q, t, method, int(np.sum(residuals <= reprojection_px)),
                       float(np.sqrt(np.mean(residuals ** 2))))


def describe(model: PoseModel) -> dict[str, Any]:
    """What a report says about a model."""
    meta = model.session.get_modelmeta()
    return {"producer": meta.producer_name, "graph": meta.graph_name, **model.contract.metadata()}
