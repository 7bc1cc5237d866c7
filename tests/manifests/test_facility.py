"""The facility folder's format (manifests/facility.py): the built-in TRON folder reads as
the configuration's testbed, and each bad folder is refused naming the file and the key."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from manifests.facility import FacilityError, facility_digest, read_facility_spec
from stages.common.facilities import builtin_folder

TESTS = Path(__file__).resolve().parents[1] / "facilities"


def _copy(tmp_path: Path, source: Path | None = None) -> Path:
    folder = tmp_path / "facility"
    shutil.copytree(source or builtin_folder(), folder)
    return folder


def _edit(folder: Path, old: str, new: str) -> None:
    path = folder / "facility.toml"
    text = path.read_text()
    assert old in text, old
    path.write_text(text.replace(old, new, 1))


def test_the_three_folders_read_in_metres():
    tron = read_facility_spec(builtin_folder())
    assert tron.room_m == (8.0, 3.0, 3.0) and [r.name for r in tron.robots] == ["camera_robot", "target_robot"]
    assert tron.robots[0].rail.travel_m == (0.0, 5.9) and len(tron.light_boxes) == 10
    abb = read_facility_spec(TESTS / "abb_rail")  # millimetres
    assert abb.room_m == (12.0, 4.5, 3.5) and abb.robots[0].rail.travel_m == (0.0, 7.0)
    assert abb.robots[0].flange_from_tool.t == pytest.approx((0.0, 0.0, 0.15))
    tripod = read_facility_spec(TESTS / "ur10_tripod")
    assert tripod.carrier("target").name == "tripod" and tripod.obstacles == ("table.stl",)


def test_the_digest_follows_every_file(tmp_path):
    folder = _copy(tmp_path)
    before = facility_digest(folder)
    (folder / "kr16_2.urdf").write_text((folder / "kr16_2.urdf").read_text().replace("0.158", "0.159"))
    assert facility_digest(folder) != before


@pytest.mark.parametrize(("old", "new", "message"), [
    ("size = [8.0, 3.0, 3.0]", "size = [8000.0, 3000.0, 3000.0]", "key room.size: a room of 8000 x 3000 x 3000 m"),
    ("travel = [0.0, 5.9]", "travel = [0.0, 0.0]", "key robot[0].rail.travel: a rail of zero or negative length"),
    ("world_from_base_t = [0.6, 1.5, 0.0]", "world_from_base_t = [0.6, 4.5, 0.0]",
     "key robot[1].world_from_base_t: (0.6, 4.5, 0) m is outside the room"),
    ("travel = [0.0, 5.9]", "travel = [0.0, 9.0]", "key robot[0].rail.travel: at 9 m the base is at"),
    ('urdf = "kr16_2.urdf"', 'urdf = "../kr16_2.urdf"', "key robot[0].urdf: '../kr16_2.urdf' is outside the facility"),
    ('urdf = "kr16_2.urdf"', 'urdf = "/etc/passwd.urdf"', "is outside the facility folder"),
    ('urdf = "kr16_2.urdf"', 'urdf = "missing.urdf"', "key robot[0].urdf:"),
    ("world_from_base_q = [0.0, 1.0, 0.0, 0.0]", "world_from_base_q = [0.0, 1.0, 0.0, 0.5]",
     "key robot[0].world_from_base_q: expected a unit quaternion"),
    ('carries = "target"', 'carries = "camera"', "exactly one robot or static mount carries the camera"),
    ('length_unit = "m"', 'lenght_unit = "m"', "lenght_unit (did you mean length_unit?)"),
    ("format_version = 1", "format_version = 2", "key format_version: expected 1"),
    ('name = "tron"', 'name = "TRON lab"', "key name: expected a name of a-z"),
    ("[room]", "[room\n", "not valid TOML"),
])
def test_a_bad_folder_is_refused_naming_the_file_and_key(tmp_path, old, new, message):
    folder = _copy(tmp_path)
    _edit(folder, old, new)
    with pytest.raises(FacilityError) as raised:
        read_facility_spec(folder)
    assert str(raised.value).startswith(str(folder / "facility.toml")), raised.value
    assert message in str(raised.value), raised.value


def test_millimetres_written_as_metres_are_named(tmp_path):
    folder = _copy(tmp_path, TESTS / "abb_rail")
    _edit(folder, 'length_unit = "mm"', 'length_unit = "m"')
    with pytest.raises(FacilityError, match='is length_unit "mm"'):
        read_facility_spec(folder)
