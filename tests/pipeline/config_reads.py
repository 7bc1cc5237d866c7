"""What configuration keys a stage's code reads, found in its source (the stage's package
and the shared functions it hands ``config`` to): ``config.section.key`` is one key,
``config.section`` used whole (bound to a name, passed on) is every key of it."""

from __future__ import annotations

import ast
import dataclasses
import importlib.util
from functools import cache
from pathlib import Path

from pipeline.config import SECTION_TYPES

#: the configuration's sections, and its ``profile`` (read whole, as a section without keys)
SECTIONS = frozenset({*SECTION_TYPES, "profile"})
#: each section's own keys; anything else read off a section (a property such as the
#: camera's ``camera_matrix``) may read any of them
KEYS = {"profile": frozenset(),
        **{name: frozenset(f.name for f in dataclasses.fields(kind)) for name, kind in SECTION_TYPES.items()}}
ROOT = Path(__file__).resolve().parents[2]
WHOLE = "*"


def _module_path(module: str) -> Path | None:
    spec = importlib.util.find_spec(module)
    return None if spec is None or spec.origin is None else Path(spec.origin)


@cache
def _tree(path: Path) -> ast.Module:
    return ast.parse(path.read_text(), filename=str(path))


def _imports(tree: ast.Module) -> dict[str, tuple[str, str]]:
    """Names imported from the shared layer: local name -> (module, function)."""
    names = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("stages.common"):
            for alias in node.names:
                names[alias.asname or alias.name] = (node.module, alias.name)
    return names


def _section_of(node: ast.AST, param: str) -> str | None:
    """``param.section`` -> section; anything else -> None."""
    if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id == param
            and node.attr in SECTIONS):
        return node.attr
    return None


def _aliases(node: ast.AST, param: str) -> tuple[dict[str, str], set[int]]:
    """Names bound to a whole section (``render = config.render``, ``a, b = config.a, config.b``)
    -> the section, and the ids of those ``config.section`` nodes."""
    aliases: dict[str, str] = {}
    bound: set[int] = set()
    for sub in ast.walk(node):
        if not isinstance(sub, ast.Assign) or len(sub.targets) != 1:
            continue
        target, value = sub.targets[0], sub.value
        both = isinstance(target, ast.Tuple) and isinstance(value, ast.Tuple)
        pairs = list(zip(target.elts, value.elts, strict=True)) if both else [(target, value)]
        for name, expression in pairs:
            section = _section_of(expression, param)
            if isinstance(name, ast.Name) and section is not None:
                aliases[name.id] = section
                bound.add(id(expression))
    return aliases, bound


def _key(section: str, attribute: str) -> tuple[str, str]:
    return (section, attribute if attribute in KEYS[section] else WHOLE)


def _reads_in(node: ast.AST, param: str) -> set[tuple[str, str]]:
    """``param.section.key`` reads, and ``param.section`` used whole (key ``*``); a name bound
    to a section is followed within ``node``."""
    aliases, skip = _aliases(node, param)
    reads: set[tuple[str, str]] = set()
    for sub in ast.walk(node):
        if not isinstance(sub, ast.Attribute):
            continue
        section = _section_of(sub.value, param)
        if section is not None:
            reads.add(_key(section, sub.attr))
            skip.add(id(sub.value))
        elif isinstance(sub.value, ast.Name) and sub.value.id in aliases:
            reads.add(_key(aliases[sub.value.id], sub.attr))
    for sub in ast.walk(node):
        section = _section_of(sub, param)
        if section is not None and id(sub) not in skip:
            reads.add((section, WHOLE))
    for alias, section in aliases.items():  # an alias handed on whole
        for call in (n for n in ast.walk(node) if isinstance(n, ast.Call)):
            arguments = [*call.args, *(k.value for k in call.keywords)]
            if any(isinstance(a, ast.Name) and a.id == alias for a in arguments):
                reads.add((section, WHOLE))
    return reads


def _config_param(function: ast.FunctionDef, position: int | None, keyword: str | None) -> str | None:
    params = [a.arg for a in function.args.posonlyargs + function.args.args]
    if keyword is not None:
        return keyword if keyword in params else None
    return params[position] if position is not None and position < len(params) else None


@cache
def function_reads(module: str, name: str, position: int | None, keyword: str | None) -> frozenset[tuple[str, str]]:
    """Keys read by ``module.name`` through its argument at ``position`` (or ``keyword``)."""
    path = _module_path(module)
    if path is None or path.suffix != ".py":
        return frozenset()
    tree = _tree(path)
    for node in tree.body:
        if isinstance(node, ast.FunctionDef) and node.name == name:
            param = _config_param(node, position, keyword)
            if param is None:
                return frozenset()
            return frozenset(_reads_in(node, param) | _followed(tree, node, param))
    raise LookupError(f"{module}.{name} takes the configuration but is not a function this scan follows")


def _followed(tree: ast.Module, scope: ast.AST, param: str) -> set[tuple[str, str]]:
    """Keys read by the shared functions ``scope`` hands ``param`` to."""
    imported = _imports(tree)
    local = {node.name for node in tree.body if isinstance(node, ast.FunctionDef)}
    reads: set[tuple[str, str]] = set()
    for call in (n for n in ast.walk(scope) if isinstance(n, ast.Call) and isinstance(n.func, ast.Name)):
        for position, argument in enumerate(call.args):
            if isinstance(argument, ast.Name) and argument.id == param:
                reads |= _callee_reads(tree, imported, local, call.func.id, position, None)
        for keyword in call.keywords:
            if isinstance(keyword.value, ast.Name) and keyword.value.id == param and keyword.arg:
                reads |= _callee_reads(tree, imported, local, call.func.id, None, keyword.arg)
    return reads


def _callee_reads(tree: ast.Module, imported: dict[str, tuple[str, str]], local: set[str], callee: str,
                  position: int | None, keyword: str | None) -> set[tuple[str, str]]:
    if callee in imported:
        return set(function_reads(*imported[callee], position, keyword))
    return set()


#: the registry's hooks: what they read decides what the stage declares (its inputs, whether
#: it runs at all), so it is not itself a dependency of the stage's results
HOOKS = frozenset({"resolve", "skipped_in_chain", "status_views", "preflight"})


def package_reads(package: str) -> set[tuple[str, str]]:
    """Every (section, key) the stage package reads from ``config`` (key ``*``: all of it),
    outside the registry's hooks and its configuration's own rules (``config.py``: checks of
    the values, not dependencies of its results)."""
    directory = ROOT / package.replace(".", "/")
    reads: set[tuple[str, str]] = set()
    for path in sorted(directory.rglob("*.py")):
        if path == directory / "config.py":
            continue
        tree = _tree(path)
        for node in tree.body:
            if isinstance(node, ast.FunctionDef) and node.name in HOOKS:
                continue
            reads |= _reads_in(node, "config") | _followed(tree, node, "config")
    return reads
