"""The whole configuration's sections, gathered over the registry: the facility's
(``core.config.FACILITY_SECTIONS``) and each stage's own (``stages/<name>/config.py:
SECTIONS``, docs/architecture.md section 2). Reading them imports each stage's ``config``
module alone (the stage packages are kept empty), so ``speedplus --help`` stays quick.

The functions here are ``core.config``'s with these sections: what the CLI, the benches
and the tests load a configuration with.
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping, Sequence
from pathlib import Path
from types import MappingProxyType

from core.config import FACILITY_SECTIONS, Config, ConfigError, Override
from core.config import layered as _layered
from core.config import load_config as _load_config
from pipeline.registry import STAGES


def _gathered() -> Mapping[str, type]:
    sections: dict[str, type] = dict(FACILITY_SECTIONS)
    for entry in STAGES:
        try:
            module = importlib.import_module(f"{entry.package}.config")
        except ModuleNotFoundError as error:
            if error.name != f"{entry.package}.config":
                raise
            continue  # a stage without keys of its own (report)
        for name, section_type in module.SECTIONS.items():
            if name in sections:
                raise ConfigError(f"configuration section [{name}] is declared twice ({entry.package}.config and "
                                  f"{sections[name].__module__})")
            sections[name] = section_type
    return MappingProxyType(sections)


#: section name -> its dataclass: the facility's, then each stage's in the registry's order
SECTION_TYPES: Mapping[str, type] = _gathered()


def default_config(profile: str = "default") -> Config:
    """Every section at its fields' defaults (no profile file applied)."""
    return Config.defaults(SECTION_TYPES, profile)


def load_config(profile: str | None = None, config_file: str | Path | None = None,
                overrides: Sequence[Override | str] = ()) -> Config:
    """``core.config.load_config`` of every section: the profile, ``config_file``, then
    ``overrides``."""
    return _load_config(profile, config_file, overrides, sections=SECTION_TYPES)


def layered(saved: Path | None, profile: str | None = None, config_file: str | Path | None = None,
            overrides: Sequence[Override] = ()) -> tuple[Config, str | None]:
    """``core.config.layered`` of every section: a command's configuration."""
    return _layered(saved, profile, config_file, overrides, sections=SECTION_TYPES)
