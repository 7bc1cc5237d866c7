"""The ML loaders on the smoke run: a PyTorch Dataset and a Hugging Face dataset over a
workspace and over its SPEED+ export, joined right and in units."""

import numpy as np
import pytest
from torch.utils.data import DataLoader

from manifests import read_manifest
from speedplus.data import PoseDataset, hf_dataset, samples
from speedplus.errors import InputError
from stages.common import geometry as g


def projected(item):
    """The label's keypoints projected with the item's own camera (OpenCV's model)."""
    import cv2

    from stages.common.tango import KEYPOINTS_M

    rotation = g.quat_to_matrix(np.asarray(item["q_vbs2tango_true"], float))
    pixels, _ = cv2.projectPoints(KEYPOINTS_M, cv2.Rodrigues(rotation)[0], np.asarray(item["r_Vo2To_vbs_true"], float),
                                  np.asarray(item["camera_matrix"], float), np.asarray(item["dist"], float))
    return pixels.reshape(-1, 2)


def test_a_workspace_trains_in_five_lines(rendered):
    data = PoseDataset(rendered.root, sets=("twins",), with_mask=True)
    batch = next(iter(DataLoader(data, batch_size=4, shuffle=False)))
    assert batch["image"].shape[0] == 4 and batch["image"].shape[-1] == 3 and str(batch["image"].dtype) == "torch.uint8"
    assert tuple(batch["q_vbs2tango_true"].shape) == (4, 4) and tuple(batch["r_Vo2To_vbs_true"].shape) == (4, 3)
    labels = {r["sample_id"]: r for r in read_manifest(rendered, "labels").to_pylist()}
    renders = {r["sample_id"]: r for r in read_manifest(rendered, "renders").to_pylist()}
    assert len(data) == len(renders)
    for index in range(len(data)):
        item = data[index]
        label = labels[item["sample_id"]]
        np.testing.assert_allclose(item["r_Vo2To_vbs_true"], label["r_Vo2To_vbs_true"], rtol=1e-6)  # metres
        np.testing.assert_allclose(projected(item), item["keypoints_px"], atol=1e-2)
        assert item["mask"].shape == item["image"].shape[:2] and item["mask"].any()
        x_min, y_min, x_max, y_max = item["bbox_px"]
        ys, xs = np.nonzero(item["mask"])
        assert abs(xs.min() - x_min) <= 2 and abs(ys.max() - y_max) <= 2  # the label's box is the mask's
        assert item["domain"] == "synthetic"
        assert renders[item["sample_id"]]["image_path"].endswith(f"{item['sample_id']}.png")


def test_the_testbed_images_join_their_captures(rendered):
    data = PoseDataset(rendered.root, sets=("testbed",))
    captures = {r["sample_id"]: r for r in read_manifest(rendered, "captures").to_pylist()}
    assert len(data) == read_manifest(rendered, "labels").num_rows
    for sample in data.samples:
        assert sample.image == rendered.root / captures[sample.sample_id]["image_path"]
        assert sample.domain in ("lightbox", "sunlamp") and sample.sigma_t_m.shape == (3,)


def test_an_export_reads_the_same_labels(rendered, exported):
    mine = {(s.sample_id, s.domain): s for s in samples(rendered.root, sets=("testbed",))}
    theirs = [s for s in samples(exported["speedplus"]) if s.set in ("lightbox", "sunlamp")]
    assert len(theirs) == len(mine)
    for sample in theirs:
        own = mine[(sample.sample_id, sample.domain)]
        np.testing.assert_allclose(sample.q_vbs2tango_true, own.q_vbs2tango_true)
        np.testing.assert_allclose(sample.r_Vo2To_vbs_true, own.r_Vo2To_vbs_true)
        np.testing.assert_allclose(sample.camera_matrix, own.camera_matrix)
        assert sample.image.is_file()
    item = PoseDataset(exported["speedplus"], sets=("synthetic",))[0]
    assert item["image"].ndim == 3 and "keypoints_px" not in item


def test_a_hugging_face_dataset_of_the_workspace(rendered, tmp_path):
    data = hf_dataset(rendered.root)
    torch_data = PoseDataset(rendered.root)
    assert len(data) == len(torch_data)
    row = data[0]
    assert row["sample_id"] == torch_data[0]["sample_id"]
    assert np.array_equal(np.asarray(row["image"].convert("RGB")), torch_data[0]["image"])
    np.testing.assert_allclose(row["q_vbs2tango_true"], torch_data[0]["q_vbs2tango_true"], rtol=1e-6)
    data.to_parquet(tmp_path / "labels.parquet")  # a Parquet file with the images embedded
    import pyarrow.parquet as pq

    assert pq.read_table(tmp_path / "labels.parquet").num_rows == len(data)


def test_a_folder_that_is_neither_is_named(tmp_path):
    with pytest.raises(InputError, match="neither a workspace"):
        samples(tmp_path)


def test_a_broken_export_json_is_named_by_file_entry_and_key(exported, tmp_path):
    import json
    import shutil

    copy = tmp_path / "export"
    shutil.copytree(exported["speedplus"], copy)
    path = next(p for p in sorted(copy.glob("*/test.json")))
    entries = json.loads(path.read_text())
    entries[1]["r_Vo2To_vbs_true"] = [0.0, "far"]
    path.write_text(json.dumps(entries))
    with pytest.raises(InputError, match=r"test.json: entry 1: key r_Vo2To_vbs_true: expected 3 finite numbers"):
        samples(copy)
