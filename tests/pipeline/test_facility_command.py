"""``speedplus facility DIR`` as a user runs it: the table of what the pipeline will use,
and bad folders ending with exit 1 and one line naming the file and the key or element."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from tests.conftest import speedplus

TESTS = Path(__file__).resolve().parents[1] / "facilities"


def test_a_facility_is_checked_and_measured():
    result = speedplus("facility", str(TESTS / "ur10_tripod"), "--distance", "0.6", "1.2", "--samples", "24",
                       "--calibration-poses", "6")
    assert result.returncode == 0, result.stderr
    text = " ".join(result.stdout.replace("│", " ").split())
    for expected in ("ur10", "numerical", "tripod", "static mount", "presentable", "% of SO(3)", "95% interval",
                     "6 calibration poses determine the robots'", "smallest singular value", "weakly determined"):
        assert expected in text, expected


def test_bad_folders_exit_1_naming_the_file_and_key(tmp_path):
    folder = tmp_path / "lab"
    shutil.copytree(TESTS / "ur10_tripod", folder)
    (folder / "ur10.urdf").write_text((folder / "ur10.urdf").read_text().replace("</robot>", ""))
    result = speedplus("facility", str(folder))
    assert result.returncode == 1 and "Traceback" not in result.stderr
    message = " ".join(result.stderr.split())
    assert "facility.toml: key robot[0].urdf:" in message and "ur10.urdf: line" in message, message
    result = speedplus("facility", str(tmp_path / "nowhere"))
    assert result.returncode == 1 and "facility.toml: missing" in " ".join(result.stderr.split())
    result = speedplus("facility", str(TESTS / "ur10_tripod"), "--distance", "2", "1")
    assert result.returncode == 1 and "expected 0 < MIN <= MAX" in " ".join(result.stderr.split())


def test_a_facility_that_presents_nothing_says_what_limits_it():
    result = speedplus("facility", str(TESTS / "ur10_tripod"), "--distance", "2.5", "3.0", "--samples", "16")
    message = " ".join(result.stderr.split())
    assert result.returncode == 1 and "Traceback" not in result.stderr
    assert "ur10_tripod/facility.toml: the facility presents none of 16 relative poses at 2.5-3 m" in message
    stated = message.split("what stops it: ", 1)[1].split("; ")
    limits = {why: int(share.rstrip("%)")) for why, share in (item.rsplit(" (", 1) for item in stated)}
    assert set(limits) == {"the camera would leave the room", "ur10 cannot reach the camera's pose"}, message
    assert 99 <= sum(limits.values()) <= 101  # shares of the failed attempts


def test_the_rehearsals_card_is_shown_and_known_stale(tmp_path):
    """The folder's rehearsal.json (its rehearsal's pooled figures) is shown, said to be made
    on this folder, and said to be stale once a file the facility names changes; a malformed
    one ends with exit 1 naming the file and the key."""
    from manifests.facility import facility_digest
    from manifests.rehearsal import RehearsalRecord, write_rehearsal
    from manifests.sidecars.base import SidecarError

    folder = tmp_path / "lab"
    shutil.copytree(TESTS / "ur10_tripod", folder)
    (folder / "rehearsal.json").unlink(missing_ok=True)
    args = ("facility", str(folder), "--distance", "0.6", "1.2", "--samples", "16", "--calibration-poses", "0")
    assert "none yet" in " ".join(speedplus(*args).stdout.split())
    write_rehearsal(folder, RehearsalRecord(facility_digest(folder), "smoke", (), "cubesat3u", (71, 72), 16, 12,
                                            (0.5, 0.9), 2.4, (0.9, 0.95, 0.85), (1.0, 0.9, 1.2)))
    text = " ".join(speedplus(*args).stdout.replace("│", " ").split())
    assert "12 of 16 labels under the SPEED+ thresholds, 75% [95% interval 50%, 90%]" in text
    assert "measured on this folder" in text
    (folder / "ur10.urdf").write_text((folder / "ur10.urdf").read_text() + "\n")
    assert "rehearse it again" in " ".join(speedplus(*args).stdout.split())
    text = (folder / "rehearsal.json").read_text()
    (folder / "rehearsal.json").write_text(text.replace('"under_speedplus": 12', '"under_speedplus": 20'))
    result = speedplus(*args)
    message = " ".join(result.stderr.split())
    assert result.returncode == 1 and "rehearsal.json: key under_speedplus: expected at most labels (16)" in message
    assert "rehearse the folder again (python -m bench honesty --facility DIR)" in message
    # a rehearsal.json the lab wrote itself is not replaced by the rehearsal's card
    (folder / "rehearsal.json").write_text('{"notes": "our own"}')
    with pytest.raises(SidecarError, match="rehearsal.json: version None"):
        write_rehearsal(folder, RehearsalRecord(facility_digest(folder), "smoke", (), None, (71,), 8, 8, (0.6, 1.0),
                                                1.0, (1.0, 1.0, 1.0), (1.0, 1.0, 1.0)))
    assert (folder / "rehearsal.json").read_text() == '{"notes": "our own"}'
