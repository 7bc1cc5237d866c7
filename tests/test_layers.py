"""The import contract of the layers (docs/architecture.md section 2): a stage package
imports the shared layer ``stages.common``, ``manifests`` and ``pipeline`` (configuration,
errors, progress, engines), never another stage; ``stages.common`` imports no stage;
``manifests`` imports nothing under ``stages``; ``pipeline`` imports no stage, and its
registry names each stage's entry points as strings, imported only when the stage runs."""

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


@pytest.mark.parametrize("package", ["stages/common", "manifests", "pipeline", "speedplus"])
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


def test_manifests_and_pipeline_share_errors_not_a_cycle():
    """manifests imports nothing from pipeline (pipeline's configuration reads manifests'
    schema); the errors both raise live in speedplus.errors, which imports neither."""
    upward = [(path.name, line, module) for path in sorted((ROOT / "manifests").rglob("*.py"))
              for line, module in imported_modules(path) if module.split(".")[0] == "pipeline"]
    assert upward == []
    errors = [module for _, module in imported_modules(ROOT / "speedplus" / "errors.py")]
    assert not [m for m in errors if m.split(".")[0] in ("pipeline", "manifests", "stages")]


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
