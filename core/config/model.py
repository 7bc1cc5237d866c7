"""The whole configuration: the profile and one typed section per name.

The sections are the facility's (``core/config/facility.py``: ``FACILITY_SECTIONS``) and
each stage's own, which its package declares (``stages/<name>/config.py: SECTIONS``;
docs/architecture.md section 2). This layer cannot name the stages' sections, so a
``Config`` holds whatever sections it is given; the top (``pipeline/config.py``) gathers
the full set over the registry and makes the defaults.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from types import MappingProxyType
from typing import Any

from core.config.facility import (
    CameraConfig,
    FacilityConfig,
    RunConfig,
    TargetConfig,
    TestbedConfig,
    VirtualConfig,
)

#: the sections every run has, whatever its stages: execution, the target, the camera, the
#: facility's room and robots, and the virtual testbed's error model
FACILITY_SECTIONS: Mapping[str, type] = MappingProxyType({
    "run": RunConfig, "target": TargetConfig, "camera": CameraConfig, "facility": FacilityConfig,
    "testbed": TestbedConfig, "virtual": VirtualConfig})


class Config:
    """The whole configuration of a run: ``profile`` and its sections by name, each a frozen
    dataclass of documented fields (``config.plan.mode``). Immutable: ``replace`` makes a
    new one."""

    __slots__ = ("_sections", "profile")

    def __init__(self, profile: str, sections: Mapping[str, Any]) -> None:
        object.__setattr__(self, "profile", profile)
        object.__setattr__(self, "_sections", MappingProxyType(dict(sections)))

    @classmethod
    def defaults(cls, section_types: Mapping[str, type], profile: str = "default") -> Config:
        """Every section of ``section_types`` (name -> dataclass) at its fields' defaults."""
        return cls(profile, {name: section_type() for name, section_type in section_types.items()})

    def __getattr__(self, name: str) -> Any:
        try:
            return self._sections[name]
        except KeyError:
            raise AttributeError(f"configuration has no section {name!r} (sections: "
                                 f"{', '.join(self._sections)})") from None

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError("Config is immutable: use replace()")

    def section(self, name: str) -> Any:
        return getattr(self, name)

    @property
    def names(self) -> tuple[str, ...]:
        """The sections' names, in order."""
        return tuple(self._sections)

    def items(self) -> Iterator[tuple[str, Any]]:
        """(name, section) of every section, in order."""
        return iter(self._sections.items())

    def replace(self, profile: str | None = None, **sections: Any) -> Config:
        """A copy with ``sections`` (name=section) replaced; a name it lacks is an error."""
        unknown = [name for name in sections if name not in self._sections]
        if unknown:
            raise AttributeError(f"configuration has no section {unknown[0]!r}")
        return Config(self.profile if profile is None else profile, {**self._sections, **sections})

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Config) and (self.profile, dict(self._sections)) == (other.profile,
                                                                                      dict(other._sections))

    def __hash__(self) -> int:
        return hash((self.profile, tuple(self._sections.items())))

    def __repr__(self) -> str:
        return f"Config(profile={self.profile!r}, sections={', '.join(self._sections)})"

    def __reduce__(self) -> tuple[Any, ...]:
        return (Config, (self.profile, dict(self._sections)))
