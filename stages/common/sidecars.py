"""Readers of the JSON files that stages share through the workspace: the calibrated camera
and offsets in ``W/calibration.json`` (written by calibrate; read by fuse, label, render,
evaluate, report and export) and the mock-up scale in ``W/session.json`` (written by
acquire). Every error names the file and says what to rerun."""

from __future__ import annotations

import json
from typing import Any

import numpy as np

from manifests import Workspace
from manifests.sidecars import read_session
from pipeline.config import Config
from pipeline.errors import InputError
from stages.common.lens import LensCamera


def read_calibration(workspace: Workspace) -> dict[str, Any]:
    """W/calibration.json, or an InputError saying what to do."""
    path = workspace.root / "calibration.json"
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise InputError(f"{path}: missing; run calibrate first") from None
    except json.JSONDecodeError as error:
        raise InputError(f"{path}: not valid JSON ({error}); rerun calibrate") from None


def calibrated_camera(workspace: Workspace) -> LensCamera:
    """The calibrated camera of the labels: K (3, 3), dist (5,), width, height."""
    path = workspace.root / "calibration.json"
    try:
        intrinsics = read_calibration(workspace)["intrinsics"]
        return LensCamera(np.array(intrinsics["K"], float), np.array(intrinsics["dist"], float),
                          int(intrinsics["width"]), int(intrinsics["height"]))
    except (KeyError, TypeError, ValueError) as error:
        raise InputError(f"{path}: intrinsics unreadable ({error!r}); expected K (3x3), dist (5), width, "
                         "height; rerun calibrate") from None


def mockup_scale(config: Config, workspace: Workspace) -> float:
    """The mock-up's scale recorded by acquire, else the configuration's."""
    if workspace.session_path.exists():
        scale = read_session(workspace).mockup_scale
        if scale:
            return scale
    return config.testbed.mockup_scale
