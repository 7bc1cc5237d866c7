"""The acquire stage's configuration: section [acquire], each key with its unit and
meaning (``speedplus keys acquire``), and the rules types cannot express
(``check``). ``SECTIONS``: what ``pipeline/config.py`` gathers (docs/architecture.md section 2)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

from core.config.params import ConfigError, param

if TYPE_CHECKING:
    from core.config.model import Config


@dataclass(frozen=True)
class AcquireConfig:
    """The acquire stage: which testbed backend produces the captures."""

    backend: Literal["virtual", "replay"] = param(
        "virtual", "virtual (embedded digital twin) or replay (recorded session on disk)", "")
    format: Literal["session", "handeye", "tabb", "rosbag"] = param(
        "session", "replay format: session (a TRON-like logger's folder), handeye (images and a "
        "pose file described by dataset.toml), tabb (Tabb's robot-world/hand-eye folders, a "
        "preset of handeye) or rosbag (a ROS 2 bag's folder with its rosbag.toml mapping); see "
        "docs/user-guide.md", "")
    source: str = param("", "replay: the recorded session directory (rosbag: the bag's folder)", "")

    def check(self, config: Config) -> None:
        """A replay names its recording."""
        if self.backend == "replay" and not self.source:
            raise ConfigError("acquire.source: the replay backend needs the recorded session directory")


#: this stage's sections: name -> dataclass
SECTIONS: dict[str, type] = {"acquire": AcquireConfig}
