"""The import contract of the layers (docs/architecture.md section 2), bottom to top:
``speedplus.errors``, ``manifests``, ``core`` (configuration, engines, progress), the
shared ``stages.common``, each stage package, and ``pipeline`` (CLI, registry, runner) on
top. A stage imports the layers below it, never another stage; nothing imports
``pipeline``; the registry names each stage's entry points as strings, imported only when
the stage runs; and the packages import one way (no cycle)."""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
STAGES = sorted(p.name for p in (ROOT / "stages").iterdir() if (p / "__init__.py").exists() and p.name != "common")


def imported_modules(path: Path) -> list[tuple[int, str]]:
    """(line, dotted module) of every import in a file, lazy ones inside functions included."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out += [(node.lineno, node.module)] + [(node.lineno, f"{node.module}.{a.name}") for a in node.names]
    return out


def stage_of(module: str) -> str | None:
    """The stage a dotted module belongs to, or None (shared layer, manifests, others)."""
    parts = module.split(".")
    return parts[1] if parts[0] == "stages" and len(parts) > 1 and parts[1] in STAGES else None


def violations(files: list[Path], allowed: set[str]) -> list[str]:
    """``file:line imports module`` for each import of a stage outside ``allowed``."""
    found: dict[tuple[Path, int], str] = {}
    for path in files:
        for line, module in imported_modules(path):
            stage = stage_of(module)
            if stage is not None and stage not in allowed:
                found.setdefault((path, line), module)
    return [f"{path.name}:{line} imports {module}" for (path, line), module in found.items()]


def test_the_stage_list_is_the_registrys():
    from pipeline import registry

    assert set(STAGES) == {entry.package.split(".")[1] for entry in registry.STAGES}


@pytest.mark.parametrize("stage", STAGES)
def test_a_stage_imports_no_other_stage(stage):
    assert violations(sorted((ROOT / "stages" / stage).rglob("*.py")), {stage}) == []


@pytest.mark.parametrize("stage", STAGES)
def test_reading_a_stages_configuration_imports_nothing_else_of_it(stage):
    """A stage's ``__init__`` imports nothing and its ``config`` module imports only the
    layers below the stages: gathering every section (``pipeline.config``, on every command
    and in every worker) loads no stage's code."""
    package = ROOT / "stages" / stage
    assert imported_modules(package / "__init__.py") == []
    below = {"core", "manifests", "speedplus", "__future__", "typing", "dataclasses", "math", "datetime",
             "pathlib", "numpy"}
    if (package / "config.py").exists():
        assert [m for _, m in imported_modules(package / "config.py") if m.split(".")[0] not in below] == []
    if (package / "cli.py").exists():  # read when the CLI starts: its own config at most, the rest lazily
        tree = ast.parse((package / "cli.py").read_text())
        eager = [node.module for node in tree.body if isinstance(node, ast.ImportFrom)]
        eager += [alias.name for node in tree.body if isinstance(node, ast.Import) for alias in node.names]
        own_config = f"stages.{stage}.config"
        assert [m for m in eager if m.split(".")[0] not in {*below, "typer"} and m != own_config] == []


def test_resolving_every_stage_loads_no_plotting_or_fitting_library():
    """Every command resolves every stage (status, fingerprints, a chain's refusals before its
    first stage), so a stage's ``stage`` module and what it imports load scipy's fitting and
    statistics, matplotlib and the rest where they are used: importing all of them cost
    0.87 s a command, 0.20 s after (`speedplus status` 1.65 -> 0.87 s, docs/development.md)."""
    import subprocess
    import sys

    code = ("import sys, importlib; import pipeline.cli\n"
            f"for s in {STAGES!r}: importlib.import_module(f'stages.{{s}}.stage')\n"
            "print(sorted(m for m in sys.modules if m.split('.')[0] == 'matplotlib' or m.startswith(("
            "'scipy.optimize', 'scipy.stats', 'scipy.spatial', 'scipy.integrate', 'torch', 'onnxruntime', "
            "'mitsuba', 'ray'))))")
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, check=True)
    assert loaded.stdout.strip() == "[]", loaded.stdout[:500]


@pytest.mark.parametrize("package", ["stages/common", "manifests", "core", "pipeline", "speedplus"])
def test_shared_layers_import_no_stage(package):
    assert violations(sorted((ROOT / package).rglob("*.py")), set()) == []


def test_manifests_sit_below_the_shared_domain_code():
    imports = [(path.name, line, module) for path in sorted((ROOT / "manifests").rglob("*.py"))
               for line, module in imported_modules(path) if module.split(".")[0] == "stages"]
    assert imports == []


def test_the_loaders_read_files_not_stages():
    imports = [(path.name, line, module) for path in sorted((ROOT / "speedplus").rglob("*.py"))
               for line, module in imported_modules(path) if module.split(".")[0] == "stages"]
    assert imports == []


@pytest.mark.parametrize("package", ["stages", "manifests", "core", "speedplus"])
def test_nothing_below_the_top_imports_pipeline(package):
    upward = [(path.name, line, module) for path in sorted((ROOT / package).rglob("*.py"))
              for line, module in imported_modules(path) if module.split(".")[0] == "pipeline"]
    assert upward == []


def test_core_and_manifests_sit_below_the_stages():
    """core's configuration reads manifests' schema, never the other way; neither reads a
    stage; the errors every layer raises live in speedplus.errors, which imports nothing."""
    upward = [(path.name, line, module) for package, above in (("core", ("stages", "pipeline")),
                                                                 ("manifests", ("core", "stages", "pipeline")))
              for path in sorted((ROOT / package).rglob("*.py"))
              for line, module in imported_modules(path) if module.split(".")[0] in above]
    assert upward == []
    errors = [module for _, module in imported_modules(ROOT / "speedplus" / "errors.py")]
    assert not [m for m in errors if m.split(".")[0] in ("core", "pipeline", "manifests", "stages")]


def package_of(module: str) -> str:
    """The node of the package graph a module belongs to: ``stages.<name>`` for a stage or
    the shared layer; ``speedplus.errors`` (the bottom) and ``speedplus.data`` (loaders
    above manifests) apart, as ``speedplus`` only gathers public names; else its top-level
    package."""
    parts = module.split(".")
    return ".".join(parts[:2]) if parts[0] in ("stages", "speedplus") and len(parts) > 1 else parts[0]


def package_cycles() -> list[list[str]]:
    """Cycles of the graph of package imports (lazy ones included), each as its nodes."""
    tops = ("core", "pipeline", "stages", "manifests", "speedplus")
    edges: dict[str, set[str]] = {}
    for top in tops:
        for path in sorted((ROOT / top).rglob("*.py")):
            source = package_of(".".join(path.relative_to(ROOT).with_suffix("").parts))
            for _, module in imported_modules(path):
                target = package_of(module)
                if module.split(".")[0] in tops and target != source and target not in ("stages", "speedplus"):
                    edges.setdefault(source, set()).add(target)
    cycles, state = [], {}

    def visit(node: str, trail: list[str]) -> None:
        state[node] = "open"
        for nxt in sorted(edges.get(node, ())):
            if state.get(nxt) == "open":
                cycles.append(trail[trail.index(nxt):] + [nxt] if nxt in trail else [node, nxt])
            elif nxt not in state:
                visit(nxt, [*trail, nxt])
        state[node] = "done"

    for node in sorted(edges):
        if node not in state:
            visit(node, [node])
    return cycles


def test_the_packages_import_one_way():
    assert package_cycles() == []


def test_the_cycle_check_finds_a_cycle(monkeypatch):
    """The check is not vacuous: a stage imported back by core is a cycle."""
    original = imported_modules

    def with_cycle(path: Path) -> list[tuple[int, str]]:
        extra = [(1, "stages.fuse")] if path.name == "progress.py" else []
        return original(path) + extra

    monkeypatch.setitem(globals(), "imported_modules", with_cycle)
    assert any("core" in cycle and "stages.fuse" in cycle for cycle in package_cycles())


def test_the_store_interface_ends_the_workspace_remote_cycle():
    """The workspace is written against manifests.store's protocols; only manifests.remote
    knows object storage."""
    imports = {module for _, module in imported_modules(ROOT / "manifests" / "workspace.py")}
    assert not any(module.startswith("manifests.remote") for module in imports)


def test_only_the_registry_names_stages():
    source = (ROOT / "pipeline" / "registry.py").read_text()
    assert all(f'"stages.{stage}' in source for stage in STAGES)
    for path in sorted((ROOT / "pipeline").rglob("*.py")):
        if path.name != "registry.py":
            assert '"stages.' not in path.read_text(), path.name


def test_the_contract_catches_lazy_imports_of_another_stage(tmp_path):
    offender = tmp_path / "offender.py"
    offender.write_text("from stages.common import geometry\nimport stages.fuse.x\n\n\ndef f():\n"
                        "    from stages.calibrate import run\n")
    assert violations([offender], {"fuse"}) == ["offender.py:6 imports stages.calibrate"]
    assert violations([offender], set()) == ["offender.py:2 imports stages.fuse.x",
                                             "offender.py:6 imports stages.calibrate"]


def test_mitsuba_is_called_from_one_module():
    """Every Mitsuba and Dr.Jit call goes through stages/common/mitsuba_adapter.py (its
    ``LoadedScene``, ``bsdf``, ``mesh``, ray casts): no other module imports them or calls
    an attribute of the module it hands out (``mi``)."""
    adapter = ROOT / "stages" / "common" / "mitsuba_adapter.py"
    found = []
    for path in sorted(p for package in ("stages", "core", "pipeline", "manifests", "bench")
                       for p in (ROOT / package).rglob("*.py")):
        if path == adapter:
            continue
        tree = ast.parse(path.read_text(), str(path))
        for line, module in imported_modules(path):
            if module.split(".")[0] in ("mitsuba", "drjit"):
                found.append(f"{path.name}:{line} imports {module}")
        for node in ast.walk(tree):
            if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id == "mi" \
                    and isinstance(node.ctx, ast.Load) and node.attr[:1].isupper() or (
                    isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
                    and isinstance(node.func.value, ast.Name) and node.func.value.id == "mi"):
                found.append(f"{path.name}:{node.lineno} calls mi.{getattr(node, 'attr', '') or node.func.attr}")
    assert found == []


def test_the_cli_sets_no_stages_key():
    """The CLI is generic over the registry: no key of a stage's own section is named in
    pipeline/ (a stage's options set them from its package's cli module)."""
    from core.config import FACILITY_SECTIONS
    from pipeline.config import SECTION_TYPES

    stage_sections = set(SECTION_TYPES) - set(FACILITY_SECTIONS)
    named = [(path.name, node.value) for path in sorted((ROOT / "pipeline").rglob("*.py"))
             for node in ast.walk(ast.parse(path.read_text())) if isinstance(node, ast.Constant)
             and isinstance(node.value, str) and node.value.split(".")[0] in stage_sections and "." in node.value]
    assert named == []
