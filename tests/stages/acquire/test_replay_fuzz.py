"""Replay ingestion under random damage to a valid recorded session: every outcome is
either success with valid manifests, or an input error that names a file of the session;
never another exception (a traceback for the user), and nothing is written outside the
workspace. Seeded: a failure replays exactly."""

import hashlib
import os
import shutil

import numpy as np
import pytest

from manifests import MANIFESTS, ManifestError, Workspace, read_manifest
from pipeline import registry, runner
from pipeline.config import load_config
from speedplus.errors import InputError
from tests.stages.acquire.test_replay import recorded_rows, write_session

FILES = ("session.toml", "robot.csv", "mocap.csv")
SNIPPETS = ("", "nan", "inf", "-1e308", "1e400", "0", "../x", "/etc/hostname", "\ufeff", '"', ",", "\n", "deg",
            "rad", "[camera]", "width = -3", "x" * 300, "é", "\x00", "cal000001", "img000004", "  ")


def tree_digest(folder):
    digest = hashlib.sha256()
    for root, dirs, files in sorted(os.walk(folder)):
        dirs.sort()
        for name in sorted(files):
            path = os.path.join(root, name)
            digest.update(path.encode())
            if not os.path.islink(path):
                with open(path, "rb") as handle:
                    digest.update(handle.read())
    return digest.hexdigest()


def mutate(source, rng):
    """One random change a lab's data could carry: a text edit, a lost or repeated line,
    an image truncated, replaced by text, removed, or a link to a file elsewhere."""
    kind = rng.integers(6)
    images = sorted((source / "images").iterdir())
    if kind < 3:
        path = source / FILES[rng.integers(len(FILES))]
        lines = path.read_text(encoding="utf-8").split("\n")
        line = int(rng.integers(len(lines)))
        if kind == 0:  # replace a field or a slice of a line
            text = lines[line]
            cut = int(rng.integers(len(text) + 1))
            end = min(len(text), cut + int(rng.integers(1, 12)))
            lines[line] = text[:cut] + SNIPPETS[rng.integers(len(SNIPPETS))] + text[end:]
        elif kind == 1:
            del lines[line]
        else:
            lines.insert(line, lines[int(rng.integers(len(lines)))])
        path.write_text("\n".join(lines), encoding="utf-8")
    elif kind == 3:
        image = images[rng.integers(len(images))]
        image.write_bytes(image.read_bytes()[: int(rng.integers(0, 60))])
    elif kind == 4:
        images[rng.integers(len(images))].write_text("not an image")
    else:
        image = images[rng.integers(len(images))]
        image.unlink()
        if rng.random() < 0.5:
            image.symlink_to("/etc/hostname")


@pytest.mark.parametrize("seed", range(80))
def test_damaged_sessions_give_valid_captures_or_an_error_naming_a_file(tmp_path, seed):
    rng = np.random.default_rng(seed)
    source = write_session(tmp_path / "session", recorded_rows())
    for _ in range(int(rng.integers(1, 4))):
        mutate(source, rng)
    before = tree_digest(source)
    outside = sorted(p.name for p in tmp_path.iterdir())
    config = None
    try:
        config = load_config("smoke", overrides=["acquire.backend=replay", "acquire.format=session",
                                                 f"acquire.source='{source}'"])
        ws = Workspace(tmp_path / "w")
        runner.run_stage(registry.stage("acquire"), config, ws)
    except (InputError, ManifestError) as error:
        message = str(error)
        assert str(source) in message or any(name in message for name in FILES), message
    else:
        for name in ("captures",):
            table = read_manifest(ws, MANIFESTS[name])
            for path in table.column("image_path").to_pylist():
                assert (ws.root / path).resolve().is_relative_to(ws.root)
    assert tree_digest(source) == before  # the recorded session is never written to
    assert sorted(p.name for p in tmp_path.iterdir() if p.name != "w") == outside
    shutil.rmtree(tmp_path / "w", ignore_errors=True)
