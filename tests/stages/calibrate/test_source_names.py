"""Table 1, the report and calibration.json name a facility's robots and motion capture as
the facility does, and TRON's as the paper does (issue 57, part 6)."""

from pathlib import Path
from types import SimpleNamespace

import pytest

from manifests.sidecars.base import Fields, SidecarError
from manifests.sidecars.calibration import SessionSources
from pipeline.config import load_config
from stages.calibrate.robots import source_names
from stages.common.tables import COLUMNS, columns

FACILITIES = Path(__file__).resolve().parents[2] / "facilities"


def test_a_facility_s_sources_are_named_as_it_names_them():
    config = load_config("smoke")
    tron = SessionSources("virtual", ("kuka", "vicon"), source_names(config))
    assert tron.names == () and tron.to_json() == {"backend": "virtual", "sources": ["kuka", "vicon"]}
    assert columns(SimpleNamespace(session=tron)) == COLUMNS  # "KUKA-only", "Vicon-only": the paper's

    abb = config.replace(facility=config.facility.__class__(path=str(FACILITIES / "abb_rail")))
    named = SessionSources("virtual", ("kuka", "vicon"), source_names(abb))
    labels = [label for _, label in columns(SimpleNamespace(session=named))]
    assert labels == ["camera_arm + target_arm only", "motion capture only", "Data fusion"]
    assert not any("KUKA" in label or "Vicon" in label for label in labels)
    again = SessionSources.from_fields(Fields(named.to_json(), "calibration.json", "session."))
    assert again == named


def test_a_name_for_an_unknown_source_is_refused_naming_the_key():
    with pytest.raises(SidecarError, match="session.names"):
        SessionSources.from_fields(Fields({"backend": "virtual", "sources": ["kuka"], "names": {"lidar": "x"}},
                                          "calibration.json", "session."))
