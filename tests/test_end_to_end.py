"""Every stage, end to end, on the smoke profile with the committed reference model; the
report page opened in headless Chromium."""

import itertools
import re
import shutil
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest

from manifests import Workspace, read_manifest
from tests.conftest import speedplus

REPOSITORY = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def finished(smoke_finished):
    return smoke_finished


def test_every_stage_is_done(finished):
    ws, stdout = finished
    assert "Table 2" in stdout
    status = speedplus("status", "--workspace", str(ws.root)).stdout
    for stage in ("plan", "acquire", "calibrate", "fuse", "label", "render", "evaluate", "report"):
        line = next(line for line in status.splitlines() if f" {stage} " in line)
        assert " done " in line, line
    predictions = read_manifest(ws, "predictions").to_pylist()
    assert {p["domain"] for p in predictions} == {"synthetic", "lightbox", "sunlamp"}
    # 8 testbed images and their 8 twins, by the two shipped models on 2 crops (oracle, self)
    assert len(predictions) == 64
    assert {(p["model"], p["crop"]) for p in predictions} == {(m, c) for m in ("reference", "reference_augmented")
                                                              for c in ("oracle_box", "self")}
    # a keypoint model's finite outputs give a pose with what PnP made of them, unless the
    # image cannot support it (the target drawn at it outside the crop, or not its size)
    for p in predictions:
        if p["pose_found"]:
            assert p["pnp_method"] in ("ransac", "all_points") and p["pose_refused"] is None, p
            assert 0 <= p["pnp_inliers"] <= 11 and np.isfinite(p["reprojection_rms_px"])
        else:
            assert p["pose_refused"] and p["pnp_method"] == "none" and p["score_speed"] == pytest.approx(np.pi + 1)
    assert all((p["box_iou"] is None) == (p["crop"] != "self") for p in predictions)
    scores = {row["group"]: row for row in read_manifest(ws, "scores").to_pylist()}
    for model in ("reference", "reference_augmented"):
        assert scores[f"{model}/oracle_box/synthetic/all/all"]["count"] == 8
        assert scores[f"{model}/self/testbed/all/all"]["count"] == 8
    for row in scores.values():  # every figure with its interval
        assert row["mean_score_speed_low"] <= row["mean_score_speed"] <= row["mean_score_speed_high"], row["group"]
    # the augmented model against the plain one, paired on the same images, per crop and domain
    compared = {row["group"]: row for row in read_manifest(ws, "comparisons").to_pylist()}
    for crop, domain in itertools.product(("oracle_box", "self"), ("synthetic", "testbed")):
        row = compared[f"reference_augmented/{crop}/reference/{crop}/{domain}/all/all"]
        assert row["count"] == 8
        own = [p for p in predictions if p["model"] == "reference_augmented" and p["crop"] == crop
               and (p["domain"] == "synthetic") == (domain == "synthetic")]
        # each image's score is its mean over the decoder's seeds, the first the row's own
        assert all(len(p["score_speed_seeds"]) == 4 and p["score_speed_seeds"][0] == p["score_speed"] for p in own)
        plain = {p["prediction_id"].split(":", 2)[2]: np.mean(p["score_speed_seeds"]) for p in predictions
                 if p["model"] == "reference" and p["crop"] == crop}
        differences = [np.mean(p["score_speed_seeds"]) - plain[p["prediction_id"].split(":", 2)[2]] for p in own]
        assert row["mean_difference_speed"] == pytest.approx(np.mean(differences))
    assert not any(row["model"] == "reference" for row in compared.values())


def test_report_references_only_existing_files(finished):
    ws, _ = finished
    page = (ws.root / "report" / "index.html").read_text()
    references = re.findall(r'(?:src|href)="([^"#]+)"', page)
    assert len(references) >= 10
    for reference in references:
        assert not reference.startswith(("http:", "https:", "//")), reference  # no network
        assert (ws.root / "report" / reference).is_file(), reference
    for section in ("Table 1", "Table 2", "Calibration residuals", "Pose distribution", "Rotation-error CDFs",
                    "Provenance", "rejection", "Each model against the reference", "What the figures mean"):
        assert section in page
    assert page.index("Table 2") < page.index("Calibration captures")  # the gap before the thumbnails


def test_report_is_browsable_every_sample_and_calibration_capture_in_it(finished):
    """A table of contents whose anchors all exist, a gallery and a table row for every
    label, and an overlay for every calibration capture with corners, worst first."""
    ws, _ = finished
    page = (ws.root / "report" / "index.html").read_text()
    ids = set(re.findall(r'id="([^"]+)"', page))
    anchors = re.findall(r'href="#([^"]+)"', page)
    assert len(anchors) >= 12 and set(anchors) <= ids
    labels = read_manifest(ws, "labels").column("sample_id").to_pylist()
    for sample_id in labels:
        assert f'id="sample-{sample_id}"' in page and f'href="#sample-{sample_id}"' in page
        assert f'href="../images/dataset/{sample_id}.png"' in page
        assert f'href="../renders/twins/{sample_id}.png"' in page
        # its caption with both scores of the first model, as the predictions hold them
        scored = {p["domain"] == "synthetic": p["score_speed"] for p in read_manifest(ws, "predictions").to_pylist()
                  if p["sample_id"] == sample_id and p["model"] == "reference" and p["crop"] == "oracle_box"}
        assert (f"reference (oracle_box) SPEED score: testbed {scored[False]:.3f}, twin {scored[True]:.3f}"
                in page), sample_id
    samples = [r for r in read_manifest(ws, "calibration_samples").to_pylist() if r["corners_px"] is not None]
    shown = re.findall(r'href="calibration/(cal\d+)\.png"', page)
    assert sorted(shown) == sorted(r["sample_id"] for r in samples)
    rms = [float(v) for v in re.findall(r"(\d+\.\d+) px RMS through the robots", page)]
    assert rms == sorted(rms, reverse=True) and rms
    assert "Solver: " in page and "{" not in page.split("Solver: ")[1].split("<")[0]  # words, not a dict
    assert "paper (TRON)" in page


def test_the_report_opens_with_how_good_the_labels_are(finished):
    """Issue 59: the first section is the labels' accuracy against the truth, under the
    SPEED+ thresholds, the same count the truth gives; then the definitions, then the tables;
    every figure has its caption; a comparison on too few images claims nothing."""
    from manifests.sidecars import read_session
    from stages.common.label_accuracy import label_accuracy

    ws, _ = finished
    page = (ws.root / "report" / "index.html").read_text()
    headings = re.findall(r"<h2[^>]*>([^<]+)</h2>", page)
    assert headings[1:4] == ["How good the labels are", "What the figures mean",
                            "Table 2: domain gap of the models (oracle box)"], headings
    accuracy = label_accuracy(read_manifest(ws, "truth").to_pylist(), read_manifest(ws, "labels").to_pylist(),
                              read_manifest(ws, "poses").to_pylist(), read_session(ws).mockup_scale)
    under, count, _, _ = accuracy.share()
    first = page[page.index("How good the labels are</h2>"):page.index("What the figures mean</h2>")]
    assert f"{under} of {count} labels" in first and "meet both SPEED+ thresholds" in first
    assert "mean SPEED score" in first  # the domain gap, in one line a model
    figures = re.findall(r'<img src="figures/[^"]+"[^>]*>(<figcaption>[^<]+</figcaption>)?', page)
    assert figures and all(figures), "a figure without its caption"
    assert "not shown different from </li>" not in page


def test_report_fits_a_1280_pixel_window(finished, tmp_path):
    """Chromium lays the page out 1280 pixels wide: nothing wider than the window (tables
    scroll in their own box)."""
    ws, _ = finished
    browser = shutil.which("chromium") or shutil.which("chromium-browser")
    assert browser, "Debian's chromium is needed (make setup and .ci/run install it)"
    copy = tmp_path / "report"
    shutil.copytree(ws.root / "report", copy)
    probe = ("<script>window.addEventListener('load', () => { document.body.setAttribute('data-width', "
             "String(document.documentElement.scrollWidth)); });</script>")
    (copy / "index.html").write_text((copy / "index.html").read_text().replace("</body>", probe + "</body>"))
    dom = subprocess.run([browser, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
                          "--window-size=1280,900", "--virtual-time-budget=5000", "--dump-dom",
                          (copy / "index.html").as_uri()], capture_output=True, text=True, timeout=120).stdout
    width = re.search(r'data-width="(\d+)"', dom)
    assert width is not None, dom[-500:]
    assert int(width.group(1)) <= 1280


def test_report_renders_in_headless_chromium(finished, tmp_path):
    ws, _ = finished
    browser = shutil.which("chromium") or shutil.which("chromium-browser")
    assert browser, "Debian's chromium is needed (make setup and .ci/run install it)"
    shot = tmp_path / "report.png"
    subprocess.run([browser, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
                    "--window-size=1280,2400", f"--screenshot={shot}", (ws.root / "report" / "index.html").as_uri()],
                   capture_output=True, timeout=120, check=False)
    image = cv2.imread(str(shot))
    assert image is not None and image.shape[:2] == (2400, 1280)
    grey = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    assert (grey < 128).mean() > 0.02  # text, tables and figures, not a blank page
    assert len(np.unique(image.reshape(-1, 3), axis=0)) > 200  # figures and thumbnails, not only text


def constant_keypoint_model(path, metadata):
    """An ONNX model of kind `keypoints` that answers the same 11 points for any image."""
    import onnx
    from onnx import TensorProto, helper

    from stages.common import geometry as g
    from stages.common import tango

    camera = np.array([[120.0, 0, 31.5], [0, 120.0, 31.5], [0, 0, 1]])
    points = g.project(g.make_transform(np.eye(3), [0, 0, 8.0]), tango.KEYPOINTS_M, camera, np.zeros(5))
    nodes = [
        helper.make_node("Shape", ["image"], ["shape"]),
        helper.make_node("Gather", ["shape", "zero"], ["n"], axis=0),
        helper.make_node("Concat", ["n", "rest"], ["out_shape"], axis=0),
        helper.make_node("Expand", ["points"], ["keypoints"]),
    ]
    nodes[-1].input.append("out_shape")
    graph = helper.make_graph(
        nodes, "constant", [helper.make_tensor_value_info("image", TensorProto.FLOAT, ["n", 3, 64, 64])],
        [helper.make_tensor_value_info("keypoints", TensorProto.FLOAT, ["n", 11, 2])],
        [helper.make_tensor("zero", TensorProto.INT64, [1], [0]),
         helper.make_tensor("rest", TensorProto.INT64, [2], [11, 2]),
         helper.make_tensor("points", TensorProto.FLOAT, [1, 11, 2], points.astype(np.float32).ravel())])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    for key, value in metadata.items():
        entry = model.metadata_props.add()
        entry.key, entry.value = key, value
    onnx.save(model, str(path))


def test_any_model_following_the_contract_can_be_scored(finished, tmp_path):
    ws, _ = finished
    copy = Workspace(tmp_path / "w")
    shutil.copytree(ws.root, copy.root)
    contract = {"speedplus.contract": "1", "speedplus.input_size": "64x64", "speedplus.channels": "rgb",
                "speedplus.normalize": "0,0,0/1,1,1", "speedplus.output": "keypoints",
                "speedplus.keypoints": "tango11", "speedplus.crop": "full"}
    constant_keypoint_model(tmp_path / "mine.onnx", contract)
    result = speedplus("evaluate", "--workspace", str(copy.root), "--model", str(tmp_path / "mine.onnx"), "--force")
    assert result.returncode == 0, result.stderr
    assert "Table 2: mine (" in result.stdout
    everything = read_manifest(copy, "predictions").to_pylist()
    predictions = [p for p in everything if p["model"] == "mine"]
    assert len(predictions) == 16 and {(p["model"], p["crop"]) for p in predictions} == {("mine", "full")}
    assert all(p["score_speed"] > 0 for p in predictions)  # a constant answer is wrong everywhere
    # added beside the shipped models, whose predictions are kept (--force redoes only the one named)
    assert {p["model"] for p in everything} == {"mine", "reference", "reference_augmented"}
    del contract["speedplus.output"]
    constant_keypoint_model(tmp_path / "unlabelled.onnx", contract)
    bad = speedplus("evaluate", "--workspace", str(copy.root), "--model", str(tmp_path / "unlabelled.onnx"),
                    "--force")
    assert bad.returncode == 1 and "speedplus.output" in bad.stderr and "unlabelled.onnx" in bad.stderr


def test_every_manifest_folder_is_read_by_every_parquet_reader(finished):
    """What ML teams do: hand the folder to their own library, unchanged."""
    import duckdb
    import pandas as pd
    import polars as pl
    import pyarrow.dataset as ds

    from manifests.schema import MANIFESTS

    ws, _ = finished
    folders = sorted(p for p in (ws.root / "manifests").iterdir() if p.is_dir() and p.name in MANIFESTS)
    assert {p.name for p in folders} >= {"plan", "captures", "poses", "labels", "renders", "predictions", "scores"}
    for folder in folders:
        rows = read_manifest(ws, folder.name).num_rows
        assert len(pd.read_parquet(folder)) == rows, folder.name
        assert ds.dataset(folder, format="parquet").count_rows() == rows, folder.name
        assert pl.read_parquet(folder).height == rows, folder.name
        assert duckdb.sql(f"select count(*) from read_parquet('{folder}/*')").fetchall()[0][0] == rows, folder.name
