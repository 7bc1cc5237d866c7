"""Configuration: profiles, overrides, documentation, and errors that name the key."""

import dataclasses
import typing
from pathlib import Path

import numpy as np
import pytest

from core.config import PROFILES, ConfigError, write_config
from pipeline.config import SECTION_TYPES, load_config


@pytest.mark.parametrize("profile", PROFILES)
def test_profiles_load(profile):
    config = load_config(profile)
    assert config.profile == profile


def test_profile_sizes():
    smoke, default, paper = (load_config(p) for p in PROFILES)
    assert (smoke.plan.n_calibration, smoke.plan.n_dataset) == (16, 8)
    assert (smoke.camera.width_px, smoke.camera.height_px) == (320, 200)
    assert (default.plan.n_calibration, default.plan.n_dataset) == (64, 48)
    assert (default.camera.width_px, default.camera.height_px) == (960, 600)
    assert (paper.plan.n_calibration, paper.plan.n_dataset) == (64, 495)
    assert (paper.camera.width_px, paper.camera.height_px) == (1920, 1200)


def test_every_field_is_typed_and_documented_with_a_unit():
    for name, section in SECTION_TYPES.items():
        assert dataclasses.is_dataclass(section) and section.__dataclass_params__.frozen, name
        hints = typing.get_type_hints(section)
        for field in dataclasses.fields(section):
            hint = hints[field.name]
            if hint in (int, float, str, bool):  # the default is of the declared type
                assert isinstance(field.default, hint) or (hint is float and type(field.default) is int), \
                    f"{name}.{field.name}: default {field.default!r} is not {hint.__name__}"
            if typing.get_origin(hint) is typing.Literal:  # the default is one of the choices
                assert field.default in typing.get_args(hint), f"{name}.{field.name}: default {field.default!r}"
            assert field.metadata.get("help"), f"{name}.{field.name} has no documentation"
            assert "unit" in field.metadata, f"{name}.{field.name} has no unit"


def test_intrinsics_scale_with_resolution():
    full, half = load_config("paper").camera, load_config("default").camera
    np.testing.assert_allclose(full.camera_matrix()[0, 0], 2988.5795)
    np.testing.assert_allclose(half.camera_matrix()[0, 0] * 2, full.camera_matrix()[0, 0])
    # pixel centres at integer coordinates: the image centre maps to the image centre
    centre_full = (full.camera_matrix()[0, 2] + 0.5) / full.width_px
    centre_half = (half.camera_matrix()[0, 2] + 0.5) / half.width_px
    assert centre_full == pytest.approx(centre_half)


def test_overrides_are_typed():
    config = load_config("smoke", overrides=["plan.n_dataset=20", "plan.dataset_range_m=[7, 9]",
                                             "testbed.robot_model=KR16-2", "plan.lights=['sunlamp']"])
    assert config.plan.n_dataset == 20
    assert config.plan.dataset_range_m == (7.0, 9.0)
    assert config.plan.lights == ("sunlamp",)


@pytest.mark.parametrize(
    "override, message",
    [
        ("plan.n_calib=3", "unknown configuration key 'plan.n_calib' (did you mean plan.n_calibration?)"),
        ("plann.seed=3", "unknown configuration key 'plann'"),
        ("plan.n_dataset=many", "plan.n_dataset: expected an integer, got 'many'"),
        ("plan.n_dataset=2.5", "plan.n_dataset: expected an integer"),
        ("plan.dataset_range_m=[1, 2, 3]", "plan.dataset_range_m: expected [] (SPEED+'s, in the target's diameters) "
                                           "or [min, max]"),
        ("plan.dataset_range_m=[9, 7]", "plan.dataset_range_m: expected 0 <= min <= max"),
        ("camera.width_px=1000", "does not have the aspect"),
        ("plan.lights=['moon']", "plan.lights"),
        ("virtual.rr_depth=0", "virtual.rr_depth: expected at least 1, got 0"),
        ("virtual.spp=32", "virtual.spp: 32 does not fill the sampler's grid of 5 rows (it would render 35); "
                           "use 30 or 35"),
        ("evaluate.threads=-1", "evaluate.threads: expected at least 0, got -1"),
        ("evaluate.ransac_seed=-2", "evaluate.ransac_seed: expected at least 0, got -2"),
        ("render.spp=-5", "render.spp: expected at least 1, got -5"),  # the bad value echoed, one key named
        ("render.train_resolution_scale=9", "render.train_resolution_scale: expected (0, 4], got 9"),
        ("export.format=shirt", "plan.mode is 'poses'"),  # the setting that decides
        ("plan", "expected section.key=value"),
    ],
)
def test_bad_overrides_name_the_key(override, message):
    with pytest.raises(ConfigError) as error:
        load_config("smoke", overrides=[override])
    assert message in str(error.value)


def test_unknown_profile():
    with pytest.raises(ConfigError, match="unknown profile 'fast'"):
        load_config("fast")


def test_config_file_errors_name_the_file(tmp_path):
    bad = tmp_path / "mine.toml"
    bad.write_text("[plan]\nn_dataset = 'x'\n")
    with pytest.raises(ConfigError, match=r"mine.toml: plan.n_dataset: expected an integer"):
        load_config(config_file=bad)
    bad.write_text("[plan\n")
    with pytest.raises(ConfigError, match="mine.toml: not valid TOML"):
        load_config(config_file=bad)
    with pytest.raises(ConfigError, match="missing.toml: file not found"):
        load_config(config_file=tmp_path / "missing.toml")


def test_resolved_config_round_trips_through_toml(tmp_path):
    config = load_config("smoke", overrides=["plan.seed=99"])
    write_config(config, tmp_path / "config.toml")
    assert load_config(config_file=tmp_path / "config.toml") == config


@pytest.mark.parametrize("template", ["../{sample_id}.png", "/tmp/{sample_id}.png", "img.png", "{id}.png"])
def test_a_label_filename_that_could_leave_the_export_folder_is_refused(template):
    with pytest.raises(ConfigError, match="label.filename_template"):
        load_config("smoke", overrides=[f"label.filename_template={template!r}"])


def test_each_section_holds_its_own_rules():
    """Every section's rules live beside its fields: each dataclass defines ``check``, and
    loading has no rules of its own but calls them."""
    import inspect

    from core.config import loading
    from pipeline.config import SECTION_TYPES

    for name, section in SECTION_TYPES.items():
        assert "check" in vars(section), f"{name}: no check() beside its fields"
        assert list(inspect.signature(section.check).parameters) == ["self", "config"]
    source = inspect.getsource(loading._check)
    assert "raise" not in source and "ConfigError" not in source


def test_a_facility_folders_camera_must_be_the_configurations(tmp_path):
    """The folder's [camera] states the sensor; [camera] gives the intrinsics. They must agree:
    the configuration load refuses a mismatch, naming the folder's file and both keys."""
    import shutil

    folder = tmp_path / "lab"
    shutil.copytree(Path(__file__).resolve().parents[1] / "facilities" / "abb_rail", folder)
    text = (folder / "facility.toml").read_text()
    (folder / "facility.toml").write_text(text.replace(
        "[sun_lamp]", '[camera]\nsensor = "mono"\nsize_px = [2448, 2048]\npixel_pitch = 0.00345\n\n[sun_lamp]', 1))
    with pytest.raises(ConfigError) as refused:
        load_config("smoke", overrides=[f"facility.path={folder}"])
    message = str(refused.value)
    assert str(folder / "facility.toml") in message and "camera.size_px" in message
    assert "camera.reference_width_px" in message
    agreeing = ["camera.reference_width_px=2448", "camera.reference_height_px=2048", "camera.pixel_pitch_m=3.45e-6",
                "camera.width_px=1224", "camera.height_px=1024", "camera.cx_px=1224", "camera.cy_px=1024"]
    assert load_config("smoke", overrides=[f"facility.path={folder}", *agreeing]).camera.reference_width_px == 2448
