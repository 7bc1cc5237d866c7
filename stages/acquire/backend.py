"""The testbed interface every acquisition backend implements.

``samples()`` lists what to capture (the plan's rows for the virtual testbed, the
recorded samples for a replay); ``capture(sample)`` moves the testbed there and returns
one ``captures`` row (and a ``truth`` row when the backend knows the truth), having
written the image into the workspace. ``session()`` describes the capture session for
the stages after it: the calibration pattern, the camera and the measurement sources.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import cv2
import numpy as np


@dataclass(frozen=True)
class CaptureRecord:
    captures: dict[str, Any]
    truth: dict[str, Any] | None


class Testbed(Protocol):
    def samples(self) -> list[dict[str, Any]]: ...

    def capture(self, sample: dict[str, Any]) -> CaptureRecord: ...

    def session(self) -> dict[str, Any]: ...


def write_png_atomic(path: Path, image: np.ndarray) -> None:
    """Write a PNG under a temporary name, fsync, rename: never a half image."""
    path.parent.mkdir(parents=True, exist_ok=True)
    ok, encoded = cv2.imencode(".png", image)
    if not ok:
        raise OSError(f"could not encode {path}")
    temporary = path.with_name(f".{path.name}.tmp")
    with open(temporary, "wb") as handle:
        handle.write(encoded.tobytes())
        handle.flush()
        os.fsync(handle.fileno())
    os.replace(temporary, path)
