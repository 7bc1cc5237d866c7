"""``PoseDataset``: a PyTorch ``Dataset`` of labelled images (``speedplus.data.records``)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from torch.utils.data import Dataset

from speedplus.data.records import SETS, Sample, samples


def read_rgb(path: Path) -> np.ndarray:
    """An image as (H, W, 3) uint8 RGB (a grey or 16-bit capture converted, as a model sees it)."""
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise FileNotFoundError(f"{path}: missing or not an image")
    if image.dtype == np.uint16:
        image = (image / 257.0).round().astype(np.uint8)
    if image.ndim == 2:
        image = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    return np.ascontiguousarray(image[..., 2::-1])


class PoseDataset(Dataset):
    """Items are dicts of numpy arrays (the default collate makes tensors): ``image`` (H, W, 3)
    uint8 RGB, ``q_vbs2tango_true`` (4,), ``r_Vo2To_vbs_true`` (3,) m, ``camera_matrix`` (3, 3),
    ``dist`` (5,); from a workspace also ``keypoints_px`` (K, 2), ``bbox_px`` (4,), ``sigma_t_m``
    (3,), ``sigma_r_rad`` () and, for twins with ``with_mask``, ``mask`` (H, W) bool; and the
    strings ``sample_id``, ``set``, ``domain``. ``transform`` maps an item to another."""

    def __init__(self, root: str | Path, sets: tuple[str, ...] = SETS, with_mask: bool = False,
                 transform: Callable[[dict[str, Any]], dict[str, Any]] | None = None) -> None:
        self.samples: list[Sample] = samples(root, sets)
        self.with_mask, self.transform = with_mask, transform

    def __len__(self) -> int:
        return len(self.samples)

    def __getitem__(self, index: int) -> dict[str, Any]:
        sample = self.samples[index]
        item: dict[str, Any] = {
            "image": read_rgb(sample.image), "q_vbs2tango_true": sample.q_vbs2tango_true.astype(np.float32),
            "r_Vo2To_vbs_true": sample.r_Vo2To_vbs_true.astype(np.float32),
            "camera_matrix": sample.camera_matrix.astype(np.float32), "dist": sample.dist.astype(np.float32),
            "sample_id": sample.sample_id, "set": sample.set, "domain": sample.domain}
        for key in ("keypoints_px", "bbox_px", "sigma_t_m"):
            value = getattr(sample, key)
            if value is not None:
                item[key] = value.astype(np.float32)
        if sample.sigma_r_rad is not None:
            item["sigma_r_rad"] = np.float32(sample.sigma_r_rad)
        if self.with_mask and sample.mask is not None:
            item["mask"] = cv2.imread(str(sample.mask), cv2.IMREAD_GRAYSCALE) > 0
        return self.transform(item) if self.transform else item
