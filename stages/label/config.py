"""The label stage's configuration: section [label], each key with its unit and
meaning (``speedplus keys label``), and the rules types cannot express
(``check``). ``SECTIONS``: what ``pipeline/config.py`` gathers (docs/architecture.md section 2)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import PurePosixPath
from typing import TYPE_CHECKING

from core.config.params import ConfigError, param

if TYPE_CHECKING:
    from core.config.model import Config


@dataclass(frozen=True)
class LabelConfig:
    """The label stage: SPEED+ labels of the dataset captures."""

    filename_template: str = param("{sample_id}.png", "image file name of a label in exports", "")

    def check(self, config: Config) -> None:
        """A file name template of {sample_id} that stays inside the export folder."""
        template = self.filename_template
        try:
            example = PurePosixPath(template.format(sample_id="img000000"))
        except (KeyError, IndexError, ValueError) as error:
            raise ConfigError(f"label.filename_template: {template!r} is not a template of {{sample_id}} "
                              f"({error})") from None
        if example.is_absolute() or ".." in example.parts or "\\" in template or "{sample_id}" not in template:
            raise ConfigError(f"label.filename_template: {template!r} must name a file inside the export folder "
                              "and contain {sample_id}")


#: this stage's sections: name -> dataclass
SECTIONS: dict[str, type] = {"label": LabelConfig}
