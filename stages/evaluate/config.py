"""The evaluate stage's configuration: section [evaluate], each key with its unit and
meaning (``speedplus keys evaluate``), and the rules types cannot express
(``check``). ``SECTIONS``: what ``pipeline/config.py`` gathers (docs/architecture.md section 2)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

from core.config.params import ConfigError, at_least, param

if TYPE_CHECKING:
    from core.config.model import Config


@dataclass(frozen=True)
class EvaluateConfig:
    """The evaluate stage: an ONNX model scored on twins and testbed images."""

    models: tuple[str, ...] = param(
        (), "ONNX models following the contract of stages/common/model_contract.py, each scored on every image; "
        "relative paths: from the current directory, else from the repository. Empty: the models train-reference "
        "made in this workspace (W/models/*.onnx), else, for the built-in Tango, the shipped reference models "
        "(models/reference.onnx, models/reference_augmented.onnx)", "")
    self_crop: bool = param(True, "a model of oracle_box crops is also scored on its own crop: the detector's box "
                            "(evaluate.detector) or its own search over windows, then two keypoint passes, each "
                            "around what the previous one found", "")
    detector: str = param(
        "auto", "what starts the self crop: auto (the detector train-reference made in this workspace, "
        "W/models/detector.onnx, else, for the built-in Tango, the shipped models/detector.onnx, else the search), "
        "an ONNX detector (the contract of stages/common/detector.py; relative paths as evaluate.models), or search "
        "(the keypoint model's own search over windows of the image)", "")
    batch_size: int = param(16, "images per inference call", "count")
    threads: int = param(0, "ONNX Runtime intra-op threads of each worker; 0: the worker's share of the cores (CPUs "
                         "/ run.workers; on Ray, the CPUs reserved for it). The scores do not depend on it", "count")
    ransac_fraction: float = param(
        0.01, "RANSAC inlier threshold of keypoint PnP, as a fraction of the image width", "1")
    turns: bool = param(True, "a model whose metadata asks for it (speedplus.turns=4) sees each crop at four "
                        "quarter turns and its heatmaps, turned back, are averaged; off: one pass", "")
    ransac_seed: int = param(0, "seed of the RANSAC draws that turn heatmaps into poses: the scores of another seed "
                             "show how much of a difference between models or runs is the draw's", "")
    ransac_seeds: int = param(4, "each image's final pass is decoded under this many RANSAC seeds (ransac_seed, "
                              "ransac_seed + 1, ...): a prediction's pose is the first's; Table 2's means average "
                              "them and its intervals draw among them, so that they hold the decoder's spread", "count")
    tracking_rotation_sigma_rad: float = param(
        math.radians(3.0), "plan.mode = trajectory, the tracking filter: a per-frame rotation's error, per axis", "rad")
    tracking_lateral_sigma: float = param(
        0.005, "the tracking filter: a per-frame position's error across the boresight, times the range", "1")
    tracking_depth_sigma: float = param(
        0.03, "the tracking filter: a per-frame position's error along the boresight, times the range", "1")
    tracking_angular_acceleration_sigma: float = param(
        3e-4, "the tracking filter's process noise on the body rate (a tumbling body's rate turns in its frame)",
        "rad/s^2")
    tracking_roe_walk: float = param(
        1e-3, "the tracking filter's random walk of the relative orbital elements (times a)", "m/s^0.5")
    tracking_gate_probability: float = param(
        0.999, "a measurement whose innovation is less likely than this under the filter's covariance is not used",
        "1")

    def check(self, config: Config) -> None:
        """Positive tracking sigmas, a gate probability, counts of at least one."""
        if min(self.tracking_rotation_sigma_rad, self.tracking_lateral_sigma, self.tracking_depth_sigma) <= 0 \
                or min(self.tracking_angular_acceleration_sigma, self.tracking_roe_walk) < 0:
            raise ConfigError("evaluate.tracking_*: the measurement sigmas must be positive, the process noises at "
                              "least 0")
        if not 0 < self.tracking_gate_probability < 1:
            raise ConfigError(f"evaluate.tracking_gate_probability: expected a probability in (0, 1), got "
                              f"{self.tracking_gate_probability}")
        at_least("evaluate", self, {"threads": 0, "batch_size": 1, "ransac_seed": 0, "ransac_seeds": 1})


#: this stage's sections: name -> dataclass
SECTIONS: dict[str, type] = {"evaluate": EvaluateConfig}
