"""What every JSON file of the workspace shares (docs/architecture.md section 4): one error
type, one loader that names the file and says what to rerun, and a validating walker whose
errors name the key by its dotted path (``kuka.cam_from_camee.q``)."""

from __future__ import annotations

import json
import math
import tomllib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple, TypeVar

from manifests.files import write_json_atomic
from speedplus.errors import InputError, unknown_keys

T = TypeVar("T")


class SidecarError(InputError):
    """A JSON file of the workspace that is missing, unreadable or malformed."""


def load(path: Path, version: int, writer: str, again: str | None = None) -> Fields:
    """The JSON object in ``path`` at ``version``, as a ``Fields`` walker; ``writer`` is the
    command that makes the file (for the message), ``again`` how to make it anew (default:
    rerun it with --force)."""
    again = again or f"rerun {writer} with --force"
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise SidecarError(f"{path}: missing; {again} (a finished stage writes it anew only when forced)"
                           ) from None
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        raise SidecarError(f"{path}: not valid JSON ({error}); {again}") from None
    if not isinstance(data, dict):
        raise SidecarError(f"{path}: expected a JSON object")
    if data.get("version") != version:
        raise SidecarError(f"{path}: version {data.get('version')!r}, this program reads version {version} "
                           f"(written by an older or newer program); {again}")
    return Fields(data, str(path), "")


def read(path: Path, version: int, writer: str, parse: Callable[[Fields], T], again: str | None = None) -> T:
    """The file at ``path`` parsed by ``parse``; any error names the file and the key and
    says which command makes the file anew (``again``, as for ``load``)."""
    fields = load(path, version, writer, again)
    try:
        return parse(fields)
    except SidecarError as error:
        raise SidecarError(f"{error}; {again or f'rerun {writer} with --force'}") from None


def save(path: Path, payload: dict[str, Any]) -> None:
    write_json_atomic(path, payload)


class Pose(NamedTuple):
    """A rigid transform as stored in the workspace's JSON: unit quaternion ``q`` (w, x, y, z)
    and translation ``t`` (m). ``geometry.transform_from_qt(*pose)`` makes the 4 x 4."""

    q: tuple[float, float, float, float]
    t: tuple[float, float, float]

    def to_json(self) -> dict[str, list[float]]:
        return {"q": list(self.q), "t": list(self.t)}


def read_toml(path: Path, error: type[SidecarError], missing: str) -> dict[str, Any]:
    """A folder format's TOML file as a dict; ``error`` naming the file when it is missing
    (``missing`` says what the folder should hold), not TOML (line and column) or unreadable."""
    try:
        return tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise error(f"{path}: missing; {missing}") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as failure:
        raise error(f"{path}: not valid TOML ({failure})") from None
    except OSError as failure:  # a file given for the folder, no permission
        raise error(f"{path}: cannot be read ({failure.strerror or failure})") from None


@dataclass(frozen=True)
class Fields:
    """A JSON object being validated; every error starts with the file and names the key."""

    data: dict[str, Any]
    where: str
    prefix: str

    def key(self, name: str) -> str:
        return f"{self.prefix}{name}"

    def fail(self, name: str, expected: str) -> SidecarError:
        return SidecarError(f"{self.where}: key {self.key(name)}: expected {expected}, got "
                            f"{self.data.get(name)!r}"[:400])

    def only(self, *names: str) -> None:
        unknown = sorted(set(self.data) - set(names))
        if unknown:
            where = f" in {self.prefix.rstrip('.')}" if self.prefix else ""
            raise SidecarError(f"{self.where}: unknown key(s){where} {unknown_keys(unknown, names)}")

    def raw(self, name: str) -> Any:
        if name not in self.data:
            raise SidecarError(f"{self.where}: key {self.key(name)} missing")
        return self.data[name]

    def optional(self, name: str) -> bool:
        """Whether the key is present and not null."""
        return self.data.get(name) is not None

    def child(self, name: str) -> Fields:
        value = self.raw(name)
        if not isinstance(value, dict):
            raise self.fail(name, "an object")
        return Fields(value, self.where, f"{self.key(name)}.")

    def number(self, name: str, *, positive: bool = False) -> float:
        value = self.raw(name)
        if (isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value)
                or (positive and value <= 0)):
            raise self.fail(name, "a positive number" if positive else "a finite number")
        return float(value) if isinstance(value, float) else value

    def integer(self, name: str, *, minimum: int = 0) -> int:
        value = self.raw(name)
        if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
            raise self.fail(name, f"an integer >= {minimum}")
        return value

    def boolean(self, name: str) -> bool:
        value = self.raw(name)
        if not isinstance(value, bool):
            raise self.fail(name, "true or false")
        return value

    def text(self, name: str, choices: tuple[str, ...] | None = None) -> str:
        value = self.raw(name)
        if not isinstance(value, str) or (choices is not None and value not in choices):
            raise self.fail(name, " or ".join(choices) if choices else "a string")
        return value

    def vector(self, name: str, length: int | None = None) -> tuple[float, ...]:
        value = self.raw(name)
        if (not isinstance(value, list) or (length is not None and len(value) != length)
                or not all(isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
                           for v in value)):
            raise self.fail(name, f"a list of {length or 'any number of'} finite numbers")
        return tuple(value)

    def matrix(self, name: str, rows: int, columns: int) -> tuple[tuple[float, ...], ...]:
        value = self.raw(name)
        if not isinstance(value, list) or len(value) != rows:
            raise self.fail(name, f"a {rows} x {columns} list of numbers")
        inner = Fields({str(i): row for i, row in enumerate(value)}, self.where, f"{self.key(name)}.")
        return tuple(inner.vector(str(i), columns) for i in range(rows))

    def pose(self, name: str) -> Pose:
        entry = self.child(name)
        entry.only("q", "t")
        q = entry.vector("q", 4)
        if abs(math.sqrt(sum(v * v for v in q)) - 1.0) > 1e-6:
            raise entry.fail("q", "a unit quaternion (w, x, y, z)")
        return Pose(q, entry.vector("t", 3))
