"""Citations of the living record hold: every "docs/architecture.md section N" in the code,
the benchmarks, the tests and the documents names a section that exists."""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: a citation, possibly wrapped across a line (and a docstring's or comment's indent)
CITATION = re.compile(r"architecture\.md,?[\s#]*\(?sections?[\s#]+(\d+)(?:[\s#]+and[\s#]+(\d+))?")


def sections() -> dict[int, str]:
    """Section number -> title of docs/architecture.md's ``## N. Title`` headings."""
    text = (ROOT / "docs" / "architecture.md").read_text()
    return {int(number): title for number, title in re.findall(r"^## (\d+)\. (.+)$", text, re.MULTILINE)}


def citations(paths: list[Path], root: Path = ROOT) -> list[tuple[str, int]]:
    """(file:line, section) of every citation in the files (named relative to ``root``)."""
    found = []
    for path in paths:
        text = path.read_text()
        for match in CITATION.finditer(text):
            line = text.count("\n", 0, match.start()) + 1
            found += [(f"{path.relative_to(root)}:{line}", int(n)) for n in match.groups() if n]
    return found


def _sources() -> list[Path]:
    packages = ("core", "pipeline", "stages", "manifests", "speedplus", "bench", "tests", "docs")
    return sorted(p for package in packages for p in (ROOT / package).rglob("*")
                  if p.suffix in (".py", ".md") and p.is_file()) + [ROOT / "README.md"]


def test_every_section_citation_names_a_section_that_exists():
    known = sections()
    assert len(known) >= 10
    cited = citations(_sources())
    assert len(cited) > 50  # the pattern still finds them
    assert [(where, n) for where, n in cited if n not in known] == []


def test_a_wrapped_or_misnumbered_citation_is_found(tmp_path):
    sample = tmp_path / "sample.py"
    sample.write_text('"""See docs/architecture.md\n    section 42 and docs/architecture.md section 2."""\n')
    assert citations([sample], tmp_path) == [("sample.py:1", 42), ("sample.py:2", 2)]


def test_every_cache_the_code_keeps_is_in_the_guide():
    """Issue 59: what is kept outside the workspace is documented, where it is and how to
    clear it: each ``~/.cache/speedplus/<name>`` the code builds is in the guide's table."""
    code = [p for package in ("core", "pipeline", "stages", "manifests", "speedplus")
            for p in (ROOT / package).rglob("*.py")]
    names = {name for path in code
             for name in re.findall(r'"speedplus"\s*/\s*f?"([^"]+)"', path.read_text())}
    assert {"drjit", "targets", "crashes", "workspaces"} <= names and any(n.startswith("earth-") for n in names)
    guide = (ROOT / "docs" / "user-guide.md").read_text()
    table = guide[guide.index("### What is kept outside the workspace"):]
    for name in names:  # a name's {placeholder} is written in capitals in the guide
        pattern = re.sub(r"\\\{\w+\\\}", "[A-Z]+", re.escape(f"~/.cache/speedplus/{name}"))
        assert re.search(pattern, table), name
