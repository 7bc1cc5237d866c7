"""The fenced blocks of README.md and docs/*.md, each with what the docs walk does with it
(issue 59: the docs are tests). The line before a block says it, as an HTML comment that
Markdown does not show:

- ``<!-- docs: run -->``: shell commands, run in order in the walk's sandbox (a copy of the
  repository's layout where ``data/`` and ``exports/`` are the test's own; ``../shared``
  is the shared folder), on the smoke profile (``WALK_SETTINGS``); ``DIR=path`` after
  ``run`` names the shipped example a placeholder ``DIR`` stands for.
- ``<!-- docs: python -->``: Python run in the same sandbox after the shell blocks before it.
- ``<!-- docs: synopsis -->``: a command summary with ``[optional]`` parts and ``A|B``
  choices: each ``speedplus`` line's command and options must exist.
- ``<!-- docs: covered-by tests/FILE.py::test_name ... -->``: needs a cluster, a bucket,
  a login or hours; the named tests run it instead, and must exist.
- ``<!-- docs: text -->``: not commands (a diagram, a file layout, a TOML example).
"""

from __future__ import annotations

import re
import shlex
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: the documents, in the order a stranger reads them
DOCUMENTS = ("README.md", "docs/user-guide.md", "docs/sequences.md", "docs/formats.md", "docs/loaders.md",
             "docs/models.md", "docs/cluster.md", "docs/accuracy.md", "docs/architecture.md",
             "docs/development.md")
KINDS = ("run", "python", "synopsis", "covered-by", "text")
DIRECTIVE = re.compile(r"^<!--\s*docs:\s*([\w-]+)\s*(.*?)\s*-->\s*$")
FENCE = re.compile(r"^```(\w*)\s*$")


@dataclass
class Block:
    """One fenced block: where it starts (``file:line``), its directive and its text."""

    where: str
    kind: str | None
    arguments: list[str]
    language: str
    text: str
    placeholders: dict[str, str] = field(default_factory=dict)

    def commands(self) -> list[str]:
        """The block's shell lines: continuations joined, comments and blank lines dropped."""
        joined = re.sub(r"\\\n\s*", " ", self.text)
        lines = []
        for line in joined.splitlines():
            words = shlex.split(line, comments=True)
            if words:
                lines.append(shlex.join(words))
        return lines


def blocks(path: Path) -> list[Block]:
    """Every fenced block of ``path`` with the directive on the line before it (or none)."""
    lines = path.read_text().splitlines()
    found, index = [], 0
    while index < len(lines):
        fence = FENCE.match(lines[index])
        if not fence:
            index += 1
            continue
        end = next(i for i in range(index + 1, len(lines)) if lines[i].startswith("```"))
        before = next((lines[i] for i in range(index - 1, -1, -1) if lines[i].strip()), "")
        directive = DIRECTIVE.match(before.strip())
        kind, arguments = (directive.group(1), directive.group(2).split()) if directive else (None, [])
        placeholders = dict(a.split("=", 1) for a in arguments if "=" in a)
        found.append(Block(f"{path.relative_to(ROOT)}:{index + 1}", kind, [a for a in arguments if "=" not in a],
                           fence.group(1), "\n".join(lines[index + 1:end]), placeholders))
        index = end + 1
    return found


def all_blocks() -> list[Block]:
    return [block for name in DOCUMENTS for block in blocks(ROOT / name)]


#: a folder of the walk's own that a command names: a workspace or an export
OWN_FOLDER = re.compile(r"(?<![\w/.])(?:\./)?((?:data|exports)/[\w.-]+)")


def filled(block: Block) -> list[str]:
    """The block's commands with its placeholders (``DIR=path``) filled in, as the walk runs them."""
    out = []
    for command in block.commands():
        for name, value in block.placeholders.items():
            command = re.sub(rf"(?<![\w/]){name}(?![\w/])", value, command)
        out.append(command)
    return out


def own_folders(block: Block) -> set[str]:
    """The walk's folders (``data/...``, ``exports/...``) that the block's commands name."""
    return set(OWN_FOLDER.findall(" ".join(filled(block))))


def run_blocks() -> list[Block]:
    """The ``run`` blocks, document by document in reading order."""
    return [b for name in DOCUMENTS for b in all_blocks() if b.where.startswith(f"{name}:") and b.kind == "run"]


def walks() -> tuple[list[Block], list[Block]]:
    """The run blocks in two walks that share no folder, each in reading order: the first
    holds every block that reaches ``data/default`` (the guide's workspace, which the Python
    blocks read), through the folders its blocks name; the second, the others (chapters on a
    workspace of their own). Two sandboxes, run side by side by pytest-xdist."""
    found = run_blocks()
    folders = {b.where: own_folders(b) for b in found}
    reached, grown = {"data/default"}, True
    while grown:
        grown = False
        for block in found:
            if folders[block.where] & reached and not folders[block.where] <= reached:
                reached |= folders[block.where]
                grown = True
    first = [b for b in found if folders[b.where] & reached]
    return first, [b for b in found if not folders[b.where] & reached]
