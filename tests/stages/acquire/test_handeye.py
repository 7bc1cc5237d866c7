"""Hand-eye folders described by dataset.toml: real data (Ali et al.'s KUKA set, Tabb's DS1)
read through the documented format, both set-ups, and every bad input refused by name."""

import shutil
from pathlib import Path

import numpy as np
import pytest

from bench.handeye import KUKA_TOML
from manifests import Workspace, read_manifest
from speedplus.errors import FileError, InputError
from stages.acquire.handeye import HandEyeReplay, read_dataset_toml
from stages.common import geometry as g
from tests.conftest import speedplus
from tests.stages.acquire.test_replay import acquire

EXTERNAL = Path(__file__).resolve().parents[4] / "shared" / "external"
KUKA = EXTERNAL / "ali2019_kuka_1"
TABB = EXTERNAL / "tabb_ds1"

#: 12 of the 30 views that rotate about several axes (the first 11 only translate)
VARIED = [1, 6, 12, 13, 14, 16, 18, 21, 22, 24, 27, 30]


def kuka_folder(directory: Path, images: int | list[int] = 30, camera_on: str = "flange",
                toml: str | None = None) -> Path:
    """Ali et al.'s folder (the first ``images`` views, or those numbered) as a lab would
    describe it: its files plus a dataset.toml."""
    directory.mkdir(parents=True)
    numbers = list(range(1, images + 1)) if isinstance(images, int) else images
    for index in numbers:
        shutil.copyfile(KUKA / f"{index:02d}.png", directory / f"{index:02d}.png")
    recorded = (KUKA / "RobotPosesVec.txt").read_text().splitlines()
    lines = [recorded[index - 1] for index in numbers]
    (directory / "RobotPosesVec.txt").write_text("\n".join(lines) + "\n")
    (directory / "dataset.toml").write_text(toml or KUKA_TOML.format(camera_on=camera_on))
    return directory


def test_kuka_folder_maps_flange_poses_for_both_setups(tmp_path):
    source = kuka_folder(tmp_path / "kuka", images=4)
    recorded = np.loadtxt(KUKA / "RobotPosesVec.txt").reshape(-1, 4, 4)[:4]
    for camera_on in ("flange", "world"):
        toml = source / "dataset.toml"
        toml.write_text(KUKA_TOML.format(camera_on=camera_on).replace("*.png", "0*.png"))
        ws = acquire(source, tmp_path, "handeye", f"w_{camera_on}")
        rows = read_manifest(ws, "captures").to_pylist()
        assert [r["source_image"] for r in rows] == ["01.png", "02.png", "03.png", "04.png"]
        for row, base_from_flange in zip(rows, recorded, strict=True):
            camee = g.transform_from_qt(row["kuka_world_from_camee_q"], row["kuka_world_from_camee_t"])
            targetee = g.transform_from_qt(row["kuka_world_from_targetee_q"], row["kuka_world_from_targetee_t"])
            moving, still = (camee, targetee) if camera_on == "flange" else (targetee, camee)
            np.testing.assert_allclose(moving[:3, 3], base_from_flange[:3, 3], atol=1e-12)
            np.testing.assert_allclose(moving[:3, :3], g.project_to_so3(base_from_flange[:3, :3]), atol=1e-9)
            np.testing.assert_allclose(still, np.eye(4), atol=1e-15)
            assert row["image_conversion"] is None  # PNGs are copied byte for byte
            assert (ws.root / row["image_path"]).read_bytes() == (source / row["source_image"]).read_bytes()


def test_xyzabc_layout_in_millimetres_and_flange_from_base(tmp_path):
    recorded = np.loadtxt(KUKA / "RobotPosesVec.txt").reshape(-1, 4, 4)[:3]
    source = kuka_folder(tmp_path / "kuka", images=3)
    flange_from_base = np.stack([g.invert(m) for m in recorded])
    xyzabc = g.transform_to_kuka(flange_from_base)
    (source / "poses.csv").write_text("sample,x,y,z,a,b,c\n" + "".join(
        f"{k},{','.join(repr(float(v)) for v in row)}\n" for k, row in enumerate(xyzabc)))
    (source / "dataset.toml").write_text(KUKA_TOML.format(camera_on="flange").replace(
        'file = "RobotPosesVec.txt"\nlayout = "rowmajor4x4"\ntransform = "base_from_flange"\nlength_unit = "m"',
        'file = "poses.csv"\nlayout = "xyzabc"\ntransform = "flange_from_base"\nlength_unit = "mm"'))
    poses = HandEyeReplay(read_dataset_toml(source), Workspace(tmp_path / "w")).base_from_flange
    np.testing.assert_allclose(poses[:, :3, 3], recorded[:, :3, 3], atol=1e-9)
    np.testing.assert_allclose(poses[:, :3, :3], g.project_to_so3(recorded[:, :3, :3]), atol=1e-8)


def test_tabb_through_dataset_toml_gives_the_tabb_captures(tmp_path):
    copy = tmp_path / "ds1"
    shutil.copytree(TABB, copy)
    (copy / "dataset.toml").write_text(
        'format_version = 1\n[robot]\nfile = "robot_cali.txt"\nlayout = "counted4x4"\ntransform = "flange_from_base"\n'
        'length_unit = "mm"\n[images]\nglob = "images/image*.png"\n'
        '[pattern]\nkind = "chessboard"\nsize = [8, 6]\nsquare_m = 0.0285\n')
    as_handeye = read_manifest(acquire(copy, tmp_path, "handeye", "a"), "captures")
    as_tabb = read_manifest(acquire(TABB, tmp_path, "tabb", "b"), "captures")
    assert as_handeye.num_rows == 88
    assert as_handeye.to_pylist() == as_tabb.to_pylist()


def edit(path: Path, old: str, new: str) -> None:
    text = path.read_text()
    assert old in text, old
    path.write_text(text.replace(old, new, 1))


@pytest.fixture()
def small_kuka(tmp_path):
    return kuka_folder(tmp_path / "kuka", images=3)


@pytest.mark.parametrize("file, old, new, message", [
    ("dataset.toml", "format_version = 1", "format_version = 2", r"dataset.toml: format_version must be 1"),
    ("dataset.toml", 'layout = "rowmajor4x4"', 'layout = "rowmajor"', r"dataset.toml: \[robot\] layout must be"),
    ("dataset.toml", "[setup]", "[setup]\nexposure = 3", r"dataset.toml: \[setup\] unknown key exposure"),
    ("dataset.toml", "[setup]", "[setup]\ncamera_onn = 3",
     r"\[setup\] unknown key camera_onn \(did you mean camera_on\?\)"),
    ("dataset.toml", 'camera_on = "flange"', 'camera_on = "hand"', r"\[setup\] camera_on must be flange or world"),
    ("dataset.toml", 'file = "RobotPosesVec.txt"', 'file = "../RobotPosesVec.txt"', r"\[robot\] file .* inside"),
    ("dataset.toml", "square_m = 0.02", "square_m = 20", r"\[pattern\] square_m must be .* metres"),
    ("dataset.toml", "square_m = 0.02", "square_m = 0.02\ncolour = 1", r"\[pattern\] unknown key\(s\) colour"),
    ("dataset.toml", 'length_unit = "m"', 'length_unit = "mm"', r"RobotPosesVec.txt: translation: every position "
                                                                r"lies within .* implausible for mm.*in m\?"),
    ("dataset.toml", "[images]", "[camera]\nwidth = 964\nheight = 604\n[images]",
     r"01.png: 1928 x 1208 px, but .*dataset.toml declares the camera \[camera\] width x height = 964 x 604"),
    ("RobotPosesVec.txt", "1.000000000\t", "1.5\t", r"RobotPosesVec.txt: line 1: rotation is not orthonormal"),
    ("RobotPosesVec.txt", "\t0.523998047\t", "\tx\t", r"RobotPosesVec.txt: line 1: not a number"),
    ("RobotPosesVec.txt", "\t0.523998047\t", "\t", r"RobotPosesVec.txt: line 1: expected 16 numbers .* got 15"),
    ("RobotPosesVec.txt", "\t1.000000000\n", "\t0.5\n", r"RobotPosesVec.txt: line 1: last row must be 0 0 0 1"),
    ("dataset.toml", 'glob = "*.png"', 'glob = ""', r"dataset.toml: \[images\] glob '' must be a non-empty pattern"),
    ("dataset.toml", 'layout = "rowmajor4x4"', 'layout = "counted4x4"',
     r"RobotPosesVec.txt: announces 1 matrices but holds 2.9375"),  # a row-major file read as counted
])
def test_bad_dataset_inputs_name_the_file_and_key(small_kuka, tmp_path, file, old, new, message):
    edit(small_kuka / file, old, new)
    with pytest.raises(InputError, match=message):
        HandEyeReplay(read_dataset_toml(small_kuka), Workspace(tmp_path / "w"))


@pytest.mark.parametrize("first_line", ["inf", "nan", "-3", "2.5"])
def test_a_counted_file_must_start_with_a_count(small_kuka, tmp_path, first_line):
    edit(small_kuka / "dataset.toml", 'layout = "rowmajor4x4"', 'layout = "counted4x4"')
    (small_kuka / "RobotPosesVec.txt").write_text(f"{first_line}\n" + (KUKA / "RobotPosesVec.txt").read_text())
    with pytest.raises(FileError, match="RobotPosesVec.txt: line 1: must start with the number of poses"):
        HandEyeReplay(read_dataset_toml(small_kuka), Workspace(tmp_path / "w"))


def test_counts_missing_corrupt_and_escaping_images_are_refused(small_kuka, tmp_path):
    (small_kuka / "03.png").unlink()
    with pytest.raises(FileError, match=r"2 images match \[images\] glob '\*.png' but RobotPosesVec.txt holds 3"):
        HandEyeReplay(read_dataset_toml(small_kuka), Workspace(tmp_path / "w"))
    data = (KUKA / "03.png").read_bytes()
    (small_kuka / "03.png").write_bytes(data[: len(data) // 3])
    with pytest.raises(FileError, match=r"03.png: truncated or corrupt image"):
        acquire(small_kuka, tmp_path, "handeye")
    (small_kuka / "03.png").unlink()
    (small_kuka / "03.png").symlink_to("/etc/hostname")
    with pytest.raises(FileError, match=r"image '03.png' leads outside"):
        HandEyeReplay(read_dataset_toml(small_kuka), Workspace(tmp_path / "w"))


def test_the_cli_names_the_key_with_exit_1_and_no_traceback(small_kuka, tmp_path):
    edit(small_kuka / "dataset.toml", 'transform = "base_from_flange"', 'transform = "base_to_flange"')
    result = speedplus("acquire", "-w", str(tmp_path / "w"), "--backend", "replay", "--format", "handeye",
                       "--source", str(small_kuka))
    assert result.returncode == 1
    assert "[robot] transform must be base_from_flange or flange_from_base" in " ".join(result.stderr.split())
    assert "Traceback" not in result.stderr
