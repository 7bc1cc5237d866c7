"""The benchmarks the docs cite run (issue 59): each on a tiny setting, checked for running and
writing its table, not for its figures (``bench honesty``: tests/bench/test_honesty.py).
None of them writes into the repository here: results go to a temporary folder, and the
model cards they fill are copies."""

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import bench.common
from stages.common.detector import DETECTOR_NAME

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def results(tmp_path, monkeypatch):
    monkeypatch.setattr(bench.common, "RESULTS", tmp_path / "results")
    return tmp_path / "results"


def _rows(results: Path, name: str) -> list[dict]:
    return json.loads((results / f"{name}.json").read_text())["rows"]


def test_bench_detector_measures_the_boxes_of_a_finished_workspace(smoke_finished, results, tmp_path):
    from bench import detector

    copy = tmp_path / f"{DETECTOR_NAME}.onnx"  # named: the shipped card is not written
    shutil.copy(ROOT / "models" / f"{DETECTOR_NAME}.onnx", copy)
    detector.main(str(smoke_finished[0].root), str(copy))
    rows = _rows(results, "detector")
    assert {row["domain"] for row in rows} >= {"synthetic", "testbed"} and all(row["images"] > 0 for row in rows)


def test_bench_model_cards_writes_table_2_into_copies_of_the_cards(smoke_finished, results, tmp_path, monkeypatch):
    from bench import model_cards

    models = tmp_path / "models"
    shutil.copytree(ROOT / "models", models)
    monkeypatch.setattr(model_cards, "MODELS", models)
    shipped = {p.name: p.read_bytes() for p in (ROOT / "models").glob("*.json")}
    model_cards.main(str(smoke_finished[0].root))
    rows = _rows(results, "model_cards")
    assert rows and {row["crop"] for row in rows} <= {"oracle_box", "self"}
    card = json.loads((models / f"{rows[0]['model']}.json").read_text())
    assert card["table2"]["profile"] == "smoke" and card["table2"]["groups"]
    assert {p.name: p.read_bytes() for p in (ROOT / "models").glob("*.json")} == shipped


def test_bench_paper_table_sets_a_workspaces_table_2_beside_the_papers(smoke_finished, results):
    """docs/models.md's Table 2 at the paper's scale comes from this bench: every model and
    crop's cells per configuration and overall, each mean inside its own interval, and the
    paper's orderings judged."""
    import re

    from bench import paper_table
    from manifests import read_manifest

    workspace = smoke_finished[0]
    paper_table.main(str(workspace.root))
    rows = _rows(results, "paper_table")
    predictions = read_manifest(workspace, "predictions").to_pylist()
    assert {(row["model"], row["crop"]) for row in rows} == {(p["model"], p["crop"]) for p in predictions}
    twins = {p["sample_id"] for p in predictions if p["domain"] == "synthetic"}
    for row in rows:
        if row["view"] == "all":
            assert row["images"] == len(twins)
        for column in ("synthetic", "testbed", "gap"):
            mean, low, high = map(float, re.match(r"([+-]?[\d.]+) \[([+-]?[\d.]+), ([+-]?[\d.]+)\]",
                                                  row[column]).groups())
            assert low <= mean <= high, row
    orderings = _rows(results, "paper_table_orderings")
    assert orderings and {row["paper's sign holds"] for row in orderings} <= {"yes", "not shown", "opposite"}
    with pytest.raises(SystemExit, match="usage"):
        paper_table.main()


@pytest.mark.skipif(not (ROOT / ".git").exists(), reason="bench pipeline checks out a commit")
def test_bench_pipeline_times_a_commit_against_this_tree(results, tmp_path):
    from bench import pipeline

    pipeline.main("HEAD", "--profile", "smoke", "--until", "plan", "--root", str(tmp_path / "timed"))
    rows = {row["what"]: row for row in _rows(results, "pipeline")}
    assert rows["plan [s]"]["before"] > 0 and rows["plan [s]"]["after"] > 0 and "total [s]" in rows
    assert not (tmp_path / "timed" / "tree").exists()  # the commit's worktree is removed


def test_bench_image_costs_times_a_commits_images_against_this_trees(results):
    """Issue 60: twins, training images and captures, the commit's code and this tree's in
    turns, with the commit's worktree removed after."""
    import subprocess

    from bench import image_costs

    image_costs.main("HEAD", "--profile", "smoke", "--images", "2", "--rounds", "1")
    rows = {row["code"]: row for row in _rows(results, "image_costs")}
    assert set(rows) == {"HEAD", "this tree", "HEAD / this tree"}
    for code in ("HEAD", "this tree"):
        # two images cannot weigh both kinds: the sample's mean, and the row says so
        assert rows[code]["CPU-s a twin"].endswith("(n=2)")
        assert rows[code]["CPU-s a training image"].endswith("(n=2) (the sample's share)")
        assert rows[code]["CPU-s a capture"].endswith("(n=2)")
    assert float(rows["HEAD / this tree"]["CPU-s a twin"].rstrip("x")) > 0
    assert float(rows["HEAD / this tree"]["CPU-s a capture"].rstrip("x")) > 0
    listed = subprocess.run(["git", "worktree", "list"], cwd=ROOT, capture_output=True, text=True).stdout
    assert "speedplus-image-costs-" not in listed
    with pytest.raises(SystemExit, match="cannot check out 'no-such-commit'"):
        image_costs.main("no-such-commit", "--profile", "smoke", "--images", "2", "--rounds", "1")
    with pytest.raises(SystemExit, match="option --images wants a value"):
        image_costs.main("HEAD", "--images")
    with pytest.raises(SystemExit, match="--kinds takes some of twin, training, capture"):
        image_costs.main("HEAD", "--kinds", "twin,twins")


def test_a_training_images_cost_is_weighed_at_the_profiles_share_of_earth_backgrounds():
    """Not at the sample's share: six images, two over the Earth (4.0 +- 1.0 CPU-s), four over
    black space (1.5 +- 0.5), weigh 2.75 at half and half, the sample's mean being 2.33."""
    from bench.image_costs import _at_share

    training = [[3.0, True], [5.0, True], [1.0, False], [1.0, False], [1.0, False], [3.0, False]]
    mean, error = _at_share(training, 0.5)
    assert mean == pytest.approx(2.75) and error == pytest.approx((0.25 * 2 / 2 + 0.25 * 1 / 4) ** 0.5)
    assert _at_share(training, 0.0) == pytest.approx((1.5, 0.5))
    assert _at_share(training[1:], 0.5) is None  # one image over the Earth has no spread


def test_bench_honesty_rehearses_a_facility_folder_and_a_target(results, tmp_path):
    """The guide's rehearsal (``--facility DIR``, writing DIR/rehearsal.json) and the accuracy
    figures of a target folder (``--target DIR``), one smoke facility each."""
    from bench import honesty
    from manifests.rehearsal import read_rehearsal

    facility = tmp_path / "abb_rail"
    shutil.copytree(ROOT / "tests" / "facilities" / "abb_rail", facility)
    (facility / "rehearsal.json").unlink(missing_ok=True)
    honesty.main("--facility", str(facility), "5", str(tmp_path / "rehearsed"), "--profile", "smoke")
    record = read_rehearsal(facility)
    assert record.labels == 8 and record.profile == "smoke" and 0 <= record.under_speedplus <= 8
    honesty.main("5", str(tmp_path / "targets"), "--target", str(ROOT / "examples" / "targets" / "cubesat3u"),
                 "--profile", "smoke")
    assert _rows(results, "rehearsal_abb-rail")
    rows = _rows(results, "honesty_targets")
    assert any(row.get("target") == "cubesat3u" and row.get("seed") == 5 for row in rows), rows


def test_bench_cluster_projects_speedplus_own_scale_from_the_paper_profiles_costs(results):
    """Issue 60, part 4: SPEED+'s 9,531 captures and 59,960 synthetic images at the paper
    profile's measured CPU-seconds an image, over one core, one 16-core machine and the
    clusters of docs/cluster.md, at the scaling's efficiency."""
    from bench.cluster import SPEEDPLUS_CAPTURES, SPEEDPLUS_SYNTHETIC, speedplus_scale

    paper = {"CPU-s per capture": 7.0, "CPU-s per twin": 1.5}
    speedplus_scale(paper, 0.8)
    rows = {row["machine"]: row for row in _rows(results, "speedplus_scale")}
    cpu_hours = (SPEEDPLUS_CAPTURES * 7.0 + SPEEDPLUS_SYNTHETIC * 1.5) / 3600
    assert rows["1 core"]["hours"] == pytest.approx(cpu_hours)
    for nodes in (1, 4, 16):
        assert rows[f"{nodes} x 16 cores"]["hours"] == pytest.approx(cpu_hours / (nodes * 16 * 0.8))


def test_bench_unmodelled_calibrates_render_free_facilities(results):
    """docs/accuracy.md cites ``python -m bench unmodelled``: one facility, two of its rows.
    The robots calibrated from PnP-sized noise alone carry over to the dataset to tenths of a
    millimetre, and on facility 25 every unmodelled source on costs them more (0.38 against
    0.81 mm; on 21 the calibration's models take nearly all of it: 0.35 and 0.34)."""
    from bench import unmodelled

    unmodelled.main("25", "none,all")
    rows = {row["unmodelled errors on"]: row for row in _rows(results, "unmodelled")}
    assert set(rows) == {"none", "all"}
    assert rows["none"]["dataset E_T (mm)"] < 0.5 < rows["all"]["dataset E_T (mm)"]
    with pytest.raises(SystemExit, match="unknown row 'sag'"):
        unmodelled.main("25", "none,sag")


def test_bench_unmodelled_covering_calibration_poses_cut_the_rotation_tail(results):
    """docs/accuracy.md cites ``bench unmodelled ... all,uncovered``: on facility 23, whose
    dataset loads the target arm's shoulder three times beyond calibration poses drawn round
    the board alone, the plan's calibration poses at the dataset's arm configurations
    (``plan.calibration_cover``) take the rotation tail away."""
    from bench import unmodelled

    unmodelled.main("23", "all,uncovered")
    covered, uncovered = _rows(results, "unmodelled")
    assert "calibration_cover = 0" in uncovered["calibrate"] and covered["calibrate"] == "as shipped"
    assert covered["dataset E_R (deg)"] < 0.8 * uncovered["dataset E_R (deg)"]
    assert uncovered["dataset under 0.169 deg"] < 1.0 == covered["dataset under 0.169 deg"]


def test_bench_acquire_reads_a_workspaces_corners_and_compares_two(smoke_labelled, results, tmp_path):
    """``bench acquire WORKSPACE`` and ``bench acquire BEFORE AFTER`` (docs/architecture.md
    section 5): one acquisition against itself moved no corner; against a copy with one
    image shifted a pixel, that image's corners moved and the mean shift shows it."""
    import cv2
    import numpy as np

    from bench import acquire
    from manifests import read_manifest

    root = smoke_labelled.root
    acquire.main(str(root))
    assert _rows(results, "acquire_detection")[0]["value"] > 0
    acquire.main(str(root), str(root))
    rows = {row["metric"]: row["value"] for row in _rows(results, "acquire_corners_moved")}
    assert rows["moved, after against before: median / 95th percentile (px)"] == "0.000 / 0.000"
    copy = tmp_path / "shifted"
    shutil.copytree(root, copy)
    first = next(r for r in read_manifest(smoke_labelled, "captures").to_pylist() if r["session"] == "calibration")
    image = cv2.imread(str(copy / first["image_path"]), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(copy / first["image_path"]), np.roll(image, 1, axis=1))  # one pixel to the right
    acquire.main(str(root), str(copy))
    rows = {row["metric"]: row["value"] for row in _rows(results, "acquire_corners_moved")}
    assert float(rows["mean shift x, y +- standard error (px)"].split(" ")[0]) > 0.0


def test_a_rehearsal_of_another_profile_keeps_the_folders_card(tmp_path, monkeypatch):
    """A folder's card is what the tests hold its labels to: a default-profile rehearsal of a
    folder that keeps a smoke card leaves it, and says where its own went; one of the same
    profile, settings and target replaces it."""
    import dataclasses

    from bench.rehearsal import keep_or_replace
    from manifests.rehearsal import read_rehearsal

    monkeypatch.setattr(bench.common, "RESULTS", tmp_path / "results")
    folder = tmp_path / "abb_rail"
    shutil.copytree(Path(__file__).resolve().parents[1] / "facilities" / "abb_rail", folder)
    smoke = read_rehearsal(folder)
    assert smoke.profile == "smoke"
    default = dataclasses.replace(smoke, profile="default", mean_e_t_mm=0.28)
    said = keep_or_replace(folder, default, read_rehearsal(folder))
    assert read_rehearsal(folder) == smoke and "kept" in said
    elsewhere = tmp_path / "results" / "rehearsal_card_abb_rail_default.json"
    assert json.loads(elsewhere.read_text())["mean_e_t_mm"] == 0.28
    assert "rehearsal_card_abb_rail_default.json" in said
    again = dataclasses.replace(smoke, mean_e_t_mm=9.0)
    assert "the facility's card" in keep_or_replace(folder, again, read_rehearsal(folder))
    assert read_rehearsal(folder) == again


def test_a_malformed_card_is_refused_before_the_first_build(tmp_path):
    """The folder's card is read before any capture: a malformed one ends the bench at once,
    naming the file and key, and nothing is built."""
    folder = tmp_path / "abb_rail"
    shutil.copytree(Path(__file__).resolve().parents[1] / "facilities" / "abb_rail", folder)
    card = json.loads((folder / "rehearsal.json").read_text())
    card["profile"] = 7
    (folder / "rehearsal.json").write_text(json.dumps(card))
    root = tmp_path / "root"
    result = subprocess.run([sys.executable, "-m", "bench", "honesty", "--facility", str(folder), "71", str(root)],
                            capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert result.returncode == 1, result.stderr
    assert "rehearsal.json" in result.stderr and "profile" in result.stderr and "Traceback" not in result.stderr
    assert not root.exists()
