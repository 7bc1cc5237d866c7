"""Every third-party import of the installed packages is a declared dependency (issue 42:
``make dataset`` died on a fresh machine importing click, which only the test extras
brought in). A module may import an optional extra's distributions only if its docstring
says it needs that extra (the words: the ``[NAME]`` extra)."""

import ast
import re
import sys
import tomllib
from functools import cache
from importlib.metadata import packages_distributions
from pathlib import Path

import pytest

from tests.test_layers import imported_modules

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("core", "pipeline", "stages", "manifests", "speedplus")
EXTRA_NOTE = re.compile(r"the ``\[(\w+)\]`` extra")


def _name(requirement: str) -> str:
    """A requirement's distribution name, normalised (PEP 503)."""
    return re.sub(r"[-_.]+", "-", re.split(r"[\s\[<>=!~;]", requirement.strip(), maxsplit=1)[0]).lower()


def declared() -> tuple[set[str], dict[str, set[str]]]:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    extras = {extra: {_name(r) for r in reqs} for extra, reqs in project.get("optional-dependencies", {}).items()}
    return {_name(r) for r in project["dependencies"]}, extras


def third_party(path: Path) -> list[tuple[int, str]]:
    """(line, top-level import name) of each import that is neither the standard library nor this project."""
    out = []
    for line, module in imported_modules(path):
        top = module.split(".")[0]
        if top not in sys.stdlib_module_names and top not in (*PACKAGES, "tests", "__future__"):
            out.append((line, top))
    return sorted(set(out))


@cache
def _distributions() -> dict[str, list[str]]:
    return packages_distributions()


def modules() -> list[Path]:
    return sorted(p for package in PACKAGES for p in (ROOT / package).rglob("*.py"))


@pytest.mark.parametrize("path", modules(), ids=lambda p: str(p.relative_to(ROOT)))
def test_every_import_is_declared(path: Path) -> None:
    runtime, extras = declared()
    docstring = ast.get_docstring(ast.parse(path.read_text())) or ""
    allowed = runtime | {name for extra in EXTRA_NOTE.findall(docstring) for name in extras.get(extra, ())}
    distributions = _distributions()
    for line, top in third_party(path):
        names = {_name(d) for d in distributions.get(top, [])}
        assert names, f"{path.relative_to(ROOT)}:{line}: imports {top!r}, which no installed distribution provides"
        assert names & allowed, (
            f"{path.relative_to(ROOT)}:{line}: imports {top!r} (distribution {', '.join(sorted(names))}), which "
            "[project] dependencies do not declare" + ("" if not names & set().union(*extras.values()) else
                                                       "; it is an extra's: say so in the module's docstring"))


def test_the_check_sees_an_undeclared_import(tmp_path: Path) -> None:
    """The check itself: click (a distribution typer 0.29 no longer brings) is caught, and
    an extra's package is allowed only where the docstring names the extra."""
    bare = tmp_path / "bare.py"
    bare.write_text('"""Nothing."""\nimport click\nimport ray\n')
    noted = tmp_path / "noted.py"
    noted.write_text('"""Runs on a cluster: it needs the ``[cluster]`` extra."""\n\ndef f():\n    import ray\n')
    runtime, extras = declared()
    assert "click" not in runtime and "ray" in extras["cluster"]
    assert [top for _, top in third_party(bare)] == ["click", "ray"]
    assert EXTRA_NOTE.findall(ast.get_docstring(ast.parse(noted.read_text()))) == ["cluster"]
    assert third_party(noted) == [(4, "ray")]
