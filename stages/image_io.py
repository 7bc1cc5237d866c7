"""Image files written by stages: PNG, atomically (a crash never leaves half an image)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from manifests.io import write_bytes_atomic


def write_png_atomic(path: Path, image: np.ndarray) -> None:
    """Write ``image`` (H, W) or (H, W, 3) BGR, uint8, as a PNG at ``path``."""
    ok, encoded = cv2.imencode(".png", image)
    if not ok:
        raise OSError(f"could not encode {path}")
    write_bytes_atomic(path, encoded.tobytes())
