"""The export stage's configuration: section [export], each key with its unit and
meaning (``speedplus keys export``), and the rules types cannot express
(``check``). ``SECTIONS``: what ``pipeline/config.py`` gathers (docs/architecture.md section 2)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal, get_args

from core.config.params import ConfigError, param

if TYPE_CHECKING:
    from core.config.model import Config

ExportSet = Literal["testbed", "twins", "train"]
ExportFormat = Literal["speedplus", "bop", "shirt", "robot", "session", "rosbag"]
EXPORT_FORMATS: tuple[str, ...] = get_args(ExportFormat)


@dataclass(frozen=True)
class ExportConfig:
    """speedplus export: the labels and testbed images in a layout other tools read."""

    format: ExportFormat = param(
        "speedplus", "speedplus (the layout the Stanford SPEED+ devkits read), bop (bop_toolkit's scenes; a "
        "trajectory plan's sequences are its scenes), shirt (SHIRT's sequences, plan.mode = trajectory) or robot "
        "(the plan as each robot's waypoints and controller program: KUKA KRL, URScript) or session (the captures "
        "in the layout of a lab's logger, which replay reads back) or rosbag (the captures as a ROS 2 bag, MCAP, "
        "with its rosbag.toml mapping, which replay --format rosbag reads back)", "")
    out: str = param("", "export folder; empty: W/export/<format>", "")
    sets: tuple[ExportSet, ...] = param(
        ("testbed", "twins"), "image sets exported: testbed (the labelled captures), twins (their synthetic twins, "
        "from render) and train (the synthetic training set, from render --set train)", "")
    validation_fraction: float = param(
        0.2, "share of the training set in SPEED+'s synthetic/validation.json (SPEED+: 0.2), chosen by a hash of "
        "each sample_id: the same image stays on its side whatever else is rendered", "1")

    def check(self, config: Config) -> None:
        """A validation share, distinct sets, and SHIRT only of sequences and their test images."""
        if not 0.0 <= self.validation_fraction <= 1.0:
            raise ConfigError(f"export.validation_fraction: expected a share in [0, 1], got "
                              f"{self.validation_fraction}")
        if self.format == "shirt" and config.plan.mode != "trajectory":
            raise ConfigError(f"export.format: shirt exports rendezvous sequences, and plan.mode is "
                              f"{config.plan.mode!r} (independent poses): export them with speedplus or bop, or plan "
                              "sequences (plan.mode = \"trajectory\")")
        if self.format == "shirt" and "train" in self.sets:
            raise ConfigError(f"export.sets: {list(self.sets)}: shirt exports the sequences' testbed images and "
                              "twins, not the training set; drop train, or export it with speedplus or bop")
        if not self.sets or len(set(self.sets)) != len(self.sets):
            raise ConfigError(f"export.sets: expected distinct sets among testbed, twins, train, got {self.sets}")


#: this stage's sections: name -> dataclass
SECTIONS: dict[str, type] = {"export": ExportConfig}
