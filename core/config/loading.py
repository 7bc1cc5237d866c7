"""Resolving a configuration: profile, then ``--config`` file, then overrides, each value
checked against its field's type once, then the rules that types cannot express; and
writing the resolved configuration to ``W/config.toml``."""

from __future__ import annotations

import difflib
import math
import tomllib
import types
import typing
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields, replace
from importlib import resources
from pathlib import Path
from typing import Any, Literal

import tomli_w

from core.config.model import Config
from core.config.params import ConfigError

PROFILES = ("smoke", "default", "paper")


# ---------------------------------------------------------------------------- validation
def _coerce(value: Any, annotation: Any, key: str) -> Any:
    """``value`` (from TOML or --set) as ``annotation``; ConfigError naming ``key`` if not."""
    origin = typing.get_origin(annotation)
    if annotation is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(f"{key}: expected a number, got {value!r}")
        if not math.isfinite(value):  # TOML writes nan and inf; no setting means them
            raise ConfigError(f"{key}: expected a finite number, got {value!r}")
        return float(value)
    if annotation is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{key}: expected an integer, got {value!r}")
        return value
    if annotation is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{key}: expected true or false, got {value!r}")
        return value
    if annotation is str:
        if not isinstance(value, str):
            raise ConfigError(f"{key}: expected a string, got {value!r}")
        return value
    if origin is Literal:
        choices = typing.get_args(annotation)
        if value not in choices:
            listed = ", ".join(str(c) for c in choices[:-1]) + f" or {choices[-1]}"
            raise ConfigError(f"{key}: expected {listed}, got {value!r}")
        return value
    if origin is tuple:
        args = typing.get_args(annotation)
        if not isinstance(value, list | tuple):
            raise ConfigError(f"{key}: expected a list, got {value!r}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_coerce(v, args[0], key) for v in value)
        if len(value) != len(args):
            raise ConfigError(f"{key}: expected {len(args)} values, got {len(value)}")
        return tuple(_coerce(v, a, key) for v, a in zip(value, args, strict=True))
    if origin in (types.UnionType, typing.Union):
        raise ConfigError(f"{key}: union types are not supported in configuration")
    raise ConfigError(f"{key}: unsupported type {annotation!r}")


def _unknown(key: str, known: list[str]) -> ConfigError:
    close = difflib.get_close_matches(key, known, n=1)
    hint = f" (did you mean {close[0]}?)" if close else ""
    return ConfigError(f"unknown configuration key {key!r}{hint}")


#: keys older versions wrote into W/config.toml -> (the key now, how its value converts)
RENAMED: dict[str, tuple[str, Any]] = {"evaluate.model": ("evaluate.models", lambda value: [value]),
                                       "virtual.gamma": ("camera.gamma", lambda value: value)}
#: keys that moved into the target folder (target.toml) -> (the value older versions wrote,
#: the built-in Tango's, which is dropped; where another value now belongs)
RETIRED: dict[str, tuple[Any, str]] = {
    "testbed.mockup_scale": (0.5, "[mockup] scale"),
    "testbed.mockup_mass_kg": (4.0, "[mockup] mass_kg"),
    "virtual.model_mass_kg": (4.0, "[mockup] mass_kg"),
    "testbed.mount_target_from_targetee_q": ((0.0, math.sqrt(0.5), 0.0, math.sqrt(0.5)), "[mockup] fixture_q"),
    "testbed.mount_target_from_targetee_t_m": ((-0.305, 0.0, 0.08), "[mockup] fixture_t (full scale)"),
    "testbed.target_from_board_q": ((0.0, 1.0, 0.0, 0.0), "[mockup] board_q"),
    "testbed.target_from_board_t_m": ((-0.165, 0.165, 0.16375), "[mockup] board_t (full scale)"),
    "virtual.target_markers_rel": (((0.9, 0.8, 1.02), (-0.9, 0.85, 1.02), (0.85, -0.9, 1.02), (1.03, 0.2, 0.5),
                                    (-1.03, -0.3, 0.3), (0.2, 1.03, 0.2)), "[mockup] markers (full scale)"),
}


def _frozen(value: Any) -> Any:
    """A TOML value with its lists as tuples, to compare with a default."""
    return tuple(_frozen(v) for v in value) if isinstance(value, list | tuple) else value


def _renamed(updates: dict[str, Any]) -> dict[str, Any]:
    """``updates`` with the keys of ``RENAMED`` under their names now (in their sections now);
    a key written under both names keeps the new one's value."""
    out = {name: dict(values) if isinstance(values, dict) else values for name, values in updates.items()}
    for old, (new, convert) in RENAMED.items():
        old_section, old_name = old.split(".")
        new_section, new_name = new.split(".")
        values = out.get(old_section)
        if not isinstance(values, dict) or old_name not in values:
            continue
        value = values.pop(old_name)
        target = out.setdefault(new_section, {})
        if isinstance(target, dict):
            target.setdefault(new_name, convert(value))
    return out


def _apply(config: Config, updates: dict[str, Any], source: str) -> Config:
    section_types = {name: type(section) for name, section in config.items()}
    known_keys = [f"{s}.{f.name}" for s, t in section_types.items() for f in fields(t)]
    changes: dict[str, Any] = {}
    for section_name, values in _renamed(updates).items():
        if section_name == "profile":
            continue
        if section_name not in section_types:
            raise ConfigError(f"{source}: " + str(_unknown(section_name, list(section_types))))
        if not isinstance(values, dict):
            raise ConfigError(f"{source}: {section_name!r} must be a table of keys")
        section_type = section_types[section_name]
        hints = typing.get_type_hints(section_type)
        field_names = {f.name for f in fields(section_type)}
        coerced = {}
        for name, value in values.items():
            key = f"{section_name}.{name}"
            if key in RETIRED:
                builtin, moved_to = RETIRED[key]
                if _frozen(value) == builtin:
                    continue  # the built-in Tango's, written by an older version: its target folder holds it
                raise ConfigError(f"{source}: {key} is now the target's own: set {moved_to} in the target folder's "
                                  f"target.toml (target.path; the built-in Tango's folder holds what was the "
                                  f"default, {builtin})")
            if name not in field_names:
                raise ConfigError(f"{source}: " + str(_unknown(key, known_keys)))
            try:
                coerced[name] = _coerce(value, hints[name], key)
            except ConfigError as error:
                raise ConfigError(f"{source}: {error}") from None
        changes[section_name] = replace(getattr(config, section_name), **coerced)
    return config.replace(**changes)


def _check(config: Config) -> Config:
    """Each section's rules that types cannot express (its own ``check``, beside its fields);
    a relative ``target.path`` or ``facility.path`` is made absolute (the saved configuration
    must name the same folder from any directory)."""
    for name in ("target", "facility"):
        section = config.section(name)
        if section.path and not Path(section.path).is_absolute():
            config = config.replace(**{name: replace(section, path=str(Path(section.path).resolve()))})
    for _, section in config.items():
        section.check(config)
    return config


# -------------------------------------------------------------------------------- loading
def _read_toml(path: Path, label: str) -> dict[str, Any]:
    try:
        return tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise ConfigError(f"{label}: file not found") from None
    except tomllib.TOMLDecodeError as error:
        raise ConfigError(f"{label}: not valid TOML ({error})") from None


def profile_path(profile: str) -> Path:
    if profile not in PROFILES:
        raise ConfigError(f"unknown profile {profile!r}; choose one of {', '.join(PROFILES)}")
    return Path(str(resources.files("core") / "profiles" / f"{profile}.toml"))


@dataclass(frozen=True)
class Override:
    """One key set for this command: ``section.key = value`` (a typed value, checked against
    the field's type when applied), and where it came from for messages (``--set ...``)."""

    section: str
    key: str
    value: Any
    origin: str

    @classmethod
    def of(cls, dotted: str, value: Any, origin: str) -> Override:
        """An override a command option sets, e.g. ``Override.of("acquire.source", path, "--source")``."""
        section, key = dotted.split(".", 1)
        return cls(section, key, value, origin)


def parse_override(text: str) -> Override:
    """``section.key=value`` as given to ``--set``: the value in TOML syntax (bare words are
    strings). Parsed here, once; applying it checks the type."""
    if "=" not in text or "." not in text.split("=", 1)[0]:
        raise ConfigError(f"--set {text!r}: expected section.key=value")
    dotted, raw = text.split("=", 1)
    section, key = dotted.strip().split(".", 1)
    try:
        value = tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw.strip()
    return Override(section.strip(), key.strip(), value, f"--set {text}")


def with_overrides(config: Config, overrides: Sequence[Override]) -> Config:
    """``config`` with ``overrides`` applied in order, then checked as a whole."""
    for override in overrides:
        config = _apply(config, {override.section: {override.key: override.value}}, override.origin)
    return _check(config)


def load_config(profile: str | None = None, config_file: str | Path | None = None,
                overrides: Sequence[Override | str] = (), *, sections: Mapping[str, type]) -> Config:
    """Resolve a configuration of ``sections`` (name -> section dataclass; the whole set:
    ``pipeline.config``): the profile, then ``config_file``, then ``overrides`` (``Override``
    records, or ``--set`` texts, parsed once here).

    Without ``profile``, the ``profile`` key of ``config_file`` (e.g. a workspace's
    ``config.toml``) picks the base profile; otherwise ``default``.
    """
    data = _read_toml(Path(config_file), str(config_file)) if config_file is not None else {}
    if profile is None:
        profile = data.get("profile", "default")
        if not isinstance(profile, str):
            raise ConfigError(f"{config_file}: profile must be a string, got {profile!r}")
    config = _apply(Config.defaults(sections, profile), _read_toml(profile_path(profile), f"profile {profile}"),
                    f"profile {profile}")
    if data:
        config = _apply(config, data, str(config_file))
    return with_overrides(config, [parse_override(o) if isinstance(o, str) else o for o in overrides])


def layered(saved: Path | None, profile: str | None = None, config_file: str | Path | None = None,
            overrides: Sequence[Override] = (), *, sections: Mapping[str, type]) -> tuple[Config, str | None]:
    """A command's configuration, lowest precedence first (docs/user-guide.md, "Configuration"):

    1. the workspace's saved ``W/config.toml`` (``saved``, when it exists), else the profile
       (``profile``, else the ``profile`` key of ``config_file``, else ``default``);
    2. ``config_file`` (``--config``): only the keys it holds;
    3. ``overrides`` (``--set`` and the command's options), in order.

    A ``profile`` other than the saved one switches profile explicitly: the saved values are
    dropped and the new profile is the base. Returns the configuration and, on a switch, the
    profile it switched from. A ``--config`` file naming another profile than the saved one
    is refused: switching is ``--profile``'s job.
    """
    data = _read_toml(Path(config_file), str(config_file)) if config_file is not None else {}
    named = data.get("profile")
    if named is not None and (not isinstance(named, str) or named not in PROFILES):
        raise ConfigError(f"{config_file}: key profile: expected one of {', '.join(PROFILES)}, got {named!r}")
    switched_from = None
    if saved is not None and saved.is_file():
        saved_profile = _read_toml(saved, str(saved)).get("profile", "default")
        if profile is not None and profile != saved_profile:
            switched_from, base = saved_profile, load_config(profile, sections=sections)
        else:
            if named is not None and named != saved_profile and profile is None:
                raise ConfigError(f"{config_file}: key profile: {named!r}, but the workspace was made with profile "
                                  f"{saved_profile!r} ({saved}); switch profile with --profile {named}")
            base = load_config(None, saved, sections=sections)
    else:
        base = load_config(profile or named or "default", sections=sections)
    config = _apply(base, data, str(config_file)) if data else base
    return with_overrides(config, overrides), switched_from


def to_dict(config: Config) -> dict[str, Any]:
    """Plain TOML-able dictionary (tuples become lists)."""
    def plain(value: Any) -> Any:
        if isinstance(value, tuple):
            return [plain(v) for v in value]
        return value

    out: dict[str, Any] = {"profile": config.profile}
    for name, section in config.items():
        out[name] = {f.name: plain(getattr(section, f.name)) for f in fields(section)}
    return out


def write_config(config: Config, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(f".{path.name}.tmp")
    temporary.write_text("# resolved SPEED+ builder configuration (written by speedplus)\n"
                         + tomli_w.dumps(to_dict(config)))
    temporary.replace(path)

