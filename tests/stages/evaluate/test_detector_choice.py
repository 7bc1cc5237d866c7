"""Which detector starts the own crop: (auto, the default) the workspace's own, else the
shipped one for Tango, else none (the search); the one named; or none (search); a
detector of another target is refused by name."""

from pathlib import Path

import pytest

from manifests import Workspace
from pipeline.config import load_config
from speedplus.errors import InputError
from stages.evaluate.stage import REPOSITORY, SHIPPED_DETECTOR, detector_path, preflight
from tests.stages.evaluate.test_scorer import fixed_box_detector


def test_auto_takes_the_workspace_s_detector_before_the_shipped_one_and_search_names_none(tmp_path):
    workspace = Workspace(tmp_path / "w")
    config = load_config("smoke")  # auto, the default
    shipped = (REPOSITORY / SHIPPED_DETECTOR).resolve()
    assert detector_path(config, workspace) == (shipped if shipped.is_file() else None)
    own = workspace.resolve(workspace.model_relpath("detector"))
    own.parent.mkdir(parents=True)
    fixed_box_detector(own, (5, 5, 10, 10))
    assert detector_path(config, workspace) == own
    assert detector_path(load_config("smoke", overrides=["evaluate.detector=search"]), workspace) is None
    named = tmp_path / "mine.onnx"
    fixed_box_detector(named, (5, 5, 10, 10))
    assert detector_path(load_config("smoke", overrides=[f"evaluate.detector={named}"]), workspace) == named


def test_a_detector_of_another_target_or_none_at_all_is_refused_by_name(tmp_path, monkeypatch):
    workspace = Workspace(tmp_path / "w")
    other = tmp_path / "other.onnx"
    fixed_box_detector(other, (5, 5, 10, 10))
    import onnx

    proto = onnx.load(str(other))
    entry = proto.metadata_props.add()
    entry.key, entry.value = "speedplus.target", "cubesat3u"
    onnx.save(proto, str(other))
    with pytest.raises(InputError, match=r"other.onnx: a detector of target 'cubesat3u'.*'tango'"):
        preflight(load_config("smoke", overrides=[f"evaluate.detector={other}"]), workspace)
    missing = Path(tmp_path / "absent.onnx")
    with pytest.raises(InputError, match="absent.onnx: detector file not found"):
        preflight(load_config("smoke", overrides=[f"evaluate.detector={missing}"]), workspace)
