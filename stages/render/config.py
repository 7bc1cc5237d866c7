"""The render stage's configuration: section [render], each key with its unit and
meaning (``speedplus keys render``), and the rules types cannot express
(``check``). ``SECTIONS``: what ``pipeline/config.py`` gathers (docs/architecture.md section 2)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

from core.config.params import ConfigError, at_least, param

if TYPE_CHECKING:
    from core.config.model import Config


@dataclass(frozen=True)
class RenderConfig:
    """The render stage: Mitsuba 3 synthetic twins of the labels, and the training set."""

    #: which set the stage makes now; each set's fingerprint holds the keys that shape it (``applies``)
    set: Literal["twin", "train"] = param(
        "twin", "what to render: twin (one per label) or train (the synthetic training set)", "")
    seed: int = param(7, "random seed of the training poses, lights and of every image's Monte-Carlo noise", "")
    spp: int = param(64, "twins: samples per pixel", "count", applies=("twin",))
    max_depth: int = param(4, "path length of the path tracer (3: direct light and one bounce)", "count")
    irradiance: float = param(
        3.0, "irradiance of the directional light on the model; the synthetic images' exposure is fixed, "
        "so 3.0 puts a sunlit white radiator near saturation", "W/m^2", applies=("twin",))
    train_count: int = param(
        1000, "images of the training set (render --set train --count N)", "count", applies=("train",))
    train_distance_m: tuple[float, ...] = param(
        (), "camera-to-target distance of training images, full scale, [min, max]; empty: SPEED+ synthetic's "
        "(3-10 m for Tango), for another target the same apparent size (2.19-7.3 of its diameters); drawn "
        "uniformly where this and render.train_distance_diameters both hold", "m", applies=("train",))
    train_distance_diameters: tuple[float, float] = param(
        (0.0, 1e9), "the same range in units of the target's diameter (Tango: 1.37 m), which narrows "
        "render.train_distance_m", "1", applies=("train",))
    train_irradiance: tuple[float, float] = param(
        (1.0, 6.0), "training images: range of the light's irradiance (log-uniform)", "W/m^2",
        applies=("train",))
    train_earth_fraction: float = param(
        0.5, "share of training images with the Earth behind the target", "1", applies=("train",))
    train_resolution_scale: float = param(
        1.0, "training images: camera resolution times this (intrinsics scaled with it)", "1",
        applies=("train",))
    margin_px: float = param(
        10.0, "training images: the target's bounding sphere stays this far inside the image when it fits", "px",
        applies=("train",))
    train_spp: int = param(16, "training images: samples per pixel", "count", applies=("train",))
    ground_truth: bool = param(
        True, "write each image's per-pixel ground truth (depth, normals, body coordinates, part index, linear "
        "radiance) as one EXR beside it (stages/common/ground_truth.py); off: PNG and mask only", "")

    def check(self, config: Config) -> None:
        """Renderer counts, the training set's ranges, irradiance, Earth share and scale."""
        at_least("render", self, {"spp": 1, "train_spp": 1, "max_depth": 1, "train_count": 0})
        if len(self.train_distance_m) not in (0, 2):
            raise ConfigError(f"render.train_distance_m: expected [] (SPEED+'s, in the target's diameters) or "
                              f"[min, max], got {list(self.train_distance_m)}")
        ranges = [("render.train_distance_m", self.train_distance_m)] if self.train_distance_m else []
        for key, (low, high) in [*ranges, ("render.train_distance_diameters", self.train_distance_diameters)]:
            if not 0 <= low <= high or high == 0:
                raise ConfigError(f"{key}: expected 0 <= min <= max (max > 0), got {(low, high)}")
        if not 0 < self.train_irradiance[0] <= self.train_irradiance[1]:
            raise ConfigError(f"render.train_irradiance: expected 0 < min <= max, got {self.train_irradiance}")
        if not 0 <= self.train_earth_fraction <= 1:
            raise ConfigError(f"render.train_earth_fraction: expected [0, 1], got {self.train_earth_fraction}")
        if not 0 < self.train_resolution_scale <= 4:
            raise ConfigError(f"render.train_resolution_scale: expected (0, 4], got {self.train_resolution_scale}")


#: this stage's sections: name -> dataclass
SECTIONS: dict[str, type] = {"render": RenderConfig}
