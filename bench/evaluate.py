"""Evaluate: the reference network through ONNX Runtime against torch eager, images per
second at the same batch size and thread count on this machine, and their agreement.

    python -m bench evaluate

The network of the recipe (``[reference]`` of the default profile) with seeded weights is
exported exactly as ``train-reference`` exports it, so both runtimes run one function.
"""

from __future__ import annotations

import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bench.common import report
from pipeline.config import load_config
from stages.common.pose_model import PoseModel
from stages.common.workspace_target import planned_target


def main(*args: str) -> None:
    import torch

    from stages.reference.network import KeypointNet
    from stages.reference.train import export

    recipe = load_config("default").reference
    threads, batch, repeats = 2, 16, 5
    torch.manual_seed(0)
    model = KeypointNet(11, recipe.width, recipe.heatmap_stride).eval()
    directory = tempfile.mkdtemp()
    path = Path(directory) / "network.onnx"
    export(model, recipe, path, planned_target(load_config("default")), {})
    onnx_model = PoseModel(path, threads=threads)
    c = onnx_model.contract
    depth = 3 if c.channels == "rgb" else 1
    x = np.random.default_rng(0).normal(size=(batch, depth, c.height, c.width)).astype(np.float32)
    onnx_model.infer(x)  # warm-up
    started = time.perf_counter()
    for _ in range(repeats):
        ort_out = onnx_model.infer(x)[0]
    ort_rate = batch * repeats / (time.perf_counter() - started)
    rows = [{"runtime": f"onnxruntime (CPU, {threads} threads)", "batch": batch, "images_per_second": ort_rate}]
    torch.set_num_threads(threads)
    with torch.inference_mode():
        model(torch.from_numpy(x))
        started = time.perf_counter()
        for _ in range(repeats):
            torch_out = model(torch.from_numpy(x)).numpy()
        torch_rate = batch * repeats / (time.perf_counter() - started)
    rows.append({"runtime": f"torch eager (CPU, {threads} threads)", "batch": batch, "images_per_second": torch_rate})
    rows.append({"runtime": "ONNX Runtime speed-up over torch eager", "batch": batch,
                 "images_per_second": ort_rate / torch_rate})
    rows.append({"runtime": "max |onnx - torch| of the heatmaps", "batch": batch,
                 "images_per_second": float(np.abs(ort_out - torch_out).max())})
    shutil.rmtree(directory)
    report("evaluate_runtime", f"evaluate: the reference network ({c.width}x{c.height} input), ONNX Runtime vs "
                               "torch eager", rows)


if __name__ == "__main__":
    main(*sys.argv[1:])
