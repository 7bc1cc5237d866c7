"""The SPEED+ export read as the Stanford devkits read it: one camera.json, a json per
domain and split, images under <domain>/images."""

import json

import numpy as np
from scipy.io import loadmat

from manifests import read_manifest
from pipeline.config import load_config
from stages.common.tango import KEYPOINTS_M
from stages.export.speedplus import is_validation, write_keypoints


def quat2dcm(q):
    """The public SPEED+ devkit's quat2dcm (scalar first)."""
    q = np.asarray(q) / np.linalg.norm(q)
    q0, q1, q2, q3 = q
    dcm = np.zeros((3, 3))
    dcm[0, 0] = 2 * q0**2 - 1 + 2 * q1**2
    dcm[1, 1] = 2 * q0**2 - 1 + 2 * q2**2
    dcm[2, 2] = 2 * q0**2 - 1 + 2 * q3**2
    dcm[0, 1] = 2 * q1 * q2 + 2 * q0 * q3
    dcm[0, 2] = 2 * q1 * q3 - 2 * q0 * q2
    dcm[1, 0] = 2 * q1 * q2 - 2 * q0 * q3
    dcm[1, 2] = 2 * q2 * q3 + 2 * q0 * q1
    dcm[2, 0] = 2 * q1 * q3 + 2 * q0 * q2
    dcm[2, 1] = 2 * q2 * q3 - 2 * q0 * q1
    return dcm


def devkit_project(q, r, camera, points):
    """The devkit's projection: [quat2dcm(q).T | r], pinhole, OpenCV distortion."""
    camera_points = quat2dcm(q).T @ points.T + np.asarray(r).reshape(3, 1)
    x, y = camera_points[0] / camera_points[2], camera_points[1] / camera_points[2]
    k1, k2, p1, p2, k3 = camera["distCoeffs"]
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2**2 + k3 * r2**3
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    k = np.array(camera["cameraMatrix"])
    return np.stack([k[0, 0] * xd + k[0, 2], k[1, 1] * yd + k[1, 2]], axis=1)


def devkit_keypoints(out):
    """The devkits' loader: ``loadmat(tangoPoints.mat)['tango3Dpoints']``, 3 x N."""
    points = loadmat(str(out / "tangoPoints.mat"))["tango3Dpoints"]
    assert points.shape[0] == 3
    return points.T


def test_every_domain_and_split_projects_like_the_devkit(exported, rendered):
    out = exported["speedplus"]
    camera = json.loads((out / "camera.json").read_text())
    keypoints = devkit_keypoints(out)
    np.testing.assert_array_equal(keypoints, KEYPOINTS_M)
    assert json.loads((out / "keypoints.json").read_text())["points"] == KEYPOINTS_M.tolist()
    assert {"Nu", "Nv", "ppx", "ppy", "fx", "fy", "ccx", "ccy", "cameraMatrix", "distCoeffs"} <= set(camera)
    labels = {r["filename"]: r for r in read_manifest(rendered, "labels").to_pylist()}
    twins = {r["sample_id"]: r for r in read_manifest(rendered, "renders").to_pylist()}
    train = {f"{r['sample_id']}.png": r for r in read_manifest(rendered, "train").to_pylist()}
    expected = {"lightbox": labels, "sunlamp": labels, "twins": {name: twins[row["sample_id"]] for name, row in
                                                               labels.items() if row["sample_id"] in twins},
                "synthetic": train}
    seen = {domain: 0 for domain in expected}
    for domain, splits in (("lightbox", ("test",)), ("sunlamp", ("test",)), ("twins", ("test",)),
                           ("synthetic", ("train", "validation"))):
        for split in splits:
            path = out / domain / f"{split}.json"
            if not path.exists():
                continue
            for entry in json.loads(path.read_text()):
                assert (out / domain / "images" / entry["filename"]).is_file()
                row = expected[domain][entry["filename"]]
                projected = devkit_project(entry["q_vbs2tango_true"], entry["r_Vo2To_vbs_true"], camera, keypoints)
                # the twins and the training set were rendered with this camera: the same keypoints
                np.testing.assert_allclose(projected, row["keypoints_px"], atol=1e-4)
                seen[domain] += 1
    assert seen["lightbox"] + seen["sunlamp"] == len(labels)
    assert seen["twins"] == len(twins) and seen["synthetic"] == len(train) == 6


def test_the_validation_split_is_deterministic_and_of_the_configured_share(exported, rendered):
    out = exported["speedplus"]
    fraction = load_config(None, rendered.config_path).export.validation_fraction
    validation = json.loads((out / "synthetic" / "validation.json").read_text()) \
        if (out / "synthetic" / "validation.json").exists() else []
    names = {e["filename"] for e in validation}
    train = read_manifest(rendered, "train").column("sample_id").to_pylist()
    assert names == {f"{s}.png" for s in train if is_validation(s, fraction)}
    ids = [f"img{i:06d}" for i in range(20000)]
    share = np.mean([is_validation(s, 0.2) for s in ids])
    assert abs(share - 0.2) < 0.01  # a hash split: the configured share, not a fixed count
    assert not any(is_validation(s, 0.0) for s in ids[:100]) and all(is_validation(s, 1.0) for s in ids[:100])


def test_the_keypoint_files_are_the_same_bytes_each_time(tmp_path):
    """SciPy stamps a MAT-file's header with the time; the export does not."""
    points = np.random.default_rng(2).normal(size=(7, 3))
    for name in ("a", "b"):
        (tmp_path / name).mkdir()
        write_keypoints(tmp_path / name, "boulder", points)
    assert (tmp_path / "a" / "tangoPoints.mat").read_bytes() == (tmp_path / "b" / "tangoPoints.mat").read_bytes()
    np.testing.assert_array_equal(devkit_keypoints(tmp_path / "a"), points)
