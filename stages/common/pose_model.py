"""A pose model as ``evaluate`` runs it: an ONNX Runtime session with its contract
(``stages.common.model_contract``), fed by ``stages.common.model_input`` and read by
``stages.common.keypoint_pnp``."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from speedplus.errors import InputError
from stages.common.model_contract import parse_contract
from stages.common.model_input import normalise_uint8, prepare


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


def describe(model: PoseModel) -> dict[str, Any]:
    """What a report says about a model."""
    meta = model.session.get_modelmeta()
    return {"producer": meta.producer_name, "graph": meta.graph_name, **model.contract.metadata()}
