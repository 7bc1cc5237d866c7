"""The ONNX model contract, crops, heatmap decoding and pose recovery."""

import cv2
import numpy as np
import pytest

from speedplus.errors import InputError
from stages.common import geometry as g
from stages.common import tango
from stages.common.keypoint_pnp import decode_heatmaps, pose_from_keypoints
from stages.common.model_contract import ModelContract, parse_contract
from stages.common.model_input import crop_window, normalise, normalise_uint8, prepare

CONTRACT = ModelContract(192, 192, "rgb", (0.5, 0.5, 0.5), (0.25, 0.25, 0.25), "heatmaps", tango.KEYPOINTS_M.copy(),
                         "oracle_box")
K = np.array([[1494.3, 0, 479.5], [0, 1494.2, 299.5], [0, 0, 1.0]])
DIST = np.array([-0.2238, 0.5141, -0.000665, -0.000214, -0.1312])


def test_contract_round_trips_through_metadata():
    parsed = parse_contract(CONTRACT.metadata(), "m.onnx")
    assert parsed.metadata() == CONTRACT.metadata()
    assert parsed.metadata()["speedplus.keypoints"] == "tango11"


@pytest.mark.parametrize(("key", "value", "message"), [
    ("speedplus.output", None, "'speedplus.output' missing"),
    ("speedplus.output", "boxes", "expected keypoints or heatmaps or pose"),
    ("speedplus.input_size", "192", "WIDTHxHEIGHT"),
    ("speedplus.channels", "bgr", "rgb or gray"),
    ("speedplus.normalize", "0.5,0.5/0.2,0.2,0.2", "3 means / 3 positive"),
    ("speedplus.keypoints", "[[0, 0, 1]]", "at least 4 points"),
    ("speedplus.crop", "detector", "full or oracle_box"),
    ("speedplus.contract", "2", "expected 1"),
])
def test_contract_errors_name_the_key(key, value, message):
    metadata = CONTRACT.metadata()
    if value is None:
        del metadata[key]
    else:
        metadata[key] = value
    with pytest.raises(InputError, match="m.onnx") as error:
        parse_contract(metadata, "m.onnx")
    assert message in str(error.value) and key in str(error.value)


def test_heatmap_peaks_decode_to_sub_pixel_positions():
    rng = np.random.default_rng(0)
    h, w = 48, 48
    truth = rng.uniform(3, 44, (2, 11, 2))
    ys, xs = np.mgrid[0:h, 0:w]
    heatmaps = np.exp(-((xs - truth[..., 0, None, None]) ** 2 + (ys - truth[..., 1, None, None]) ** 2) / 2.0)
    points, confidence = decode_heatmaps(heatmaps.astype(np.float32), 192, 192)
    # heatmap pixel centres spread evenly over the input: x_in = (x_hm + 0.5) * 4 - 0.5
    np.testing.assert_allclose(points, (truth + 0.5) * 4 - 0.5, atol=0.35)
    assert np.all(confidence > 0.75)  # the peak is within half a heatmap pixel of the nearest centre


def test_pose_from_keypoints_recovers_the_pose_despite_outliers():
    rng = np.random.default_rng(1)
    for q in g.random_quats(rng, 5):
        cam_from_target = g.transform_from_qt(q, [0.3, -0.2, 8.0])
        pixels = g.project(cam_from_target, tango.KEYPOINTS_M, K, DIST)
        pixels[[2, 7]] += rng.uniform(30, 60, (2, 2))  # two wild keypoints
        solution = pose_from_keypoints(pixels, tango.KEYPOINTS_M, K, DIST, reprojection_px=3.0)
        assert solution.method == "ransac" and solution.inliers == 9
        assert g.quat_angular_distance(solution.q, q) < 1e-6
        np.testing.assert_allclose(solution.t, [0.3, -0.2, 8.0], atol=1e-5)
        # the RMS covers every keypoint: the two wild ones dominate it
        assert 30 / np.sqrt(11) < solution.rms_px < 90 / np.sqrt(11) * np.sqrt(2)


def test_finite_keypoints_always_give_a_pose():
    rng = np.random.default_rng(2)
    cases = [np.zeros((11, 2)), np.full((11, 2), 479.5), np.column_stack([np.linspace(0, 900, 11), np.full(11, 300)]),
             rng.uniform(-1e5, 1e5, (11, 2))]
    cases += [rng.uniform(0, 960, (11, 2)) for _ in range(20)]
    for pixels in cases:
        solution = pose_from_keypoints(pixels, tango.KEYPOINTS_M, K, DIST, reprojection_px=3.0,
                                       confidence=rng.uniform(0, 1, 11))
        assert solution is not None
        assert np.all(np.isfinite(solution.q)) and np.all(np.isfinite(solution.t)) and np.isfinite(solution.rms_px)
        assert abs(np.linalg.norm(solution.q) - 1) < 1e-9 and 0 <= solution.inliers <= 11
    nan = np.zeros((11, 2))
    nan[:8] = np.nan  # only three finite keypoints: nothing to solve
    assert pose_from_keypoints(nan, tango.KEYPOINTS_M, K, DIST, reprojection_px=3.0) is None
    nan[3] = (400.0, 300.0)  # four: a pose
    assert pose_from_keypoints(nan, tango.KEYPOINTS_M, K, DIST, reprojection_px=3.0) is not None


def test_without_a_consensus_every_point_counts_by_its_confidence():
    rng = np.random.default_rng(3)
    errors = {"uniform": [], "weighted": []}
    for q in g.random_quats(rng, 8):
        cam_from_target = g.transform_from_qt(q, [0.1, 0.2, 7.0])
        pixels = g.project(cam_from_target, tango.KEYPOINTS_M, K, DIST) + rng.normal(0, 4.0, (11, 2))
        wild = rng.choice(11, 3, replace=False)
        pixels[wild] += rng.uniform(40, 80, (3, 2))
        confidence = np.full(11, 0.9)
        confidence[wild] = 0.05  # the heatmaps were unsure there
        for name, weights in (("uniform", None), ("weighted", confidence)):
            solution = pose_from_keypoints(pixels, tango.KEYPOINTS_M, K, DIST, reprojection_px=0.5,
                                           confidence=weights)
            assert solution.method == "all_points"  # noise of 4 px: no consensus within 0.5 px
            errors[name].append(g.quat_angular_distance(solution.q, q))
    assert np.median(errors["weighted"]) < 0.5 * np.median(errors["uniform"])
    assert np.degrees(np.median(errors["weighted"])) < 3.0


def test_prepare_maps_pixels_both_ways():
    image = np.zeros((600, 960, 3), np.uint8)
    box = np.array([400.0, 250.0, 520.0, 330.0])
    image[290, 460] = (0, 0, 255)  # one red pixel (BGR) at the box centre
    pixels, image_from_input = prepare(image, CONTRACT, box)
    assert pixels.shape == (192, 192, 3)
    x0, y0, w, h = crop_window(CONTRACT, 960, 600, box)
    assert w == h == 150 and abs((x0 + (w - 1) / 2) - 460) <= 0.5 and abs((y0 + (h - 1) / 2) - 290) <= 0.5
    # the brightest input pixel lies where the map sends the red pixel
    peak = np.unravel_index(pixels[..., 0].argmax(), pixels.shape[:2])
    at = np.linalg.inv(image_from_input) @ [460, 290, 1.0]
    assert abs(peak[1] - at[0]) <= 1 and abs(peak[0] - at[1]) <= 1
    full = ModelContract(240, 150, "gray", (0.5,), (0.25,), "keypoints", tango.KEYPOINTS_M.copy(), "full")
    pixels, image_from_input = prepare(image, full, None)
    assert pixels.shape == (150, 240, 1)
    np.testing.assert_allclose(image_from_input @ [-0.5, -0.5, 1], [-0.5, -0.5, 1])  # image corners agree
    np.testing.assert_allclose(image_from_input @ [239.5, 149.5, 1], [959.5, 599.5, 1])


@pytest.mark.parametrize("box", [[400.0, 250.0, 520.0, 330.0],  # inside the image
                                 [-60.0, 500.0, 90.0, 640.0],  # over two edges
                                 [-900.0, -900.0, -700.0, -760.0],  # outside: black
                                 [-100.0, -300.0, 1100.0, 900.0]])  # larger than the image
def test_a_crop_is_the_integer_shift_of_the_image_black_outside(box):
    """The window is cut without resampling: the pixels are those of an exact integer-shift
    warp (what the shipped scores were computed with), then resized."""
    image = np.random.default_rng(1).integers(0, 256, (600, 960, 3), dtype=np.uint8)
    pixels, _ = prepare(image, CONTRACT, np.array(box))
    x0, y0, w, h = crop_window(CONTRACT, 960, 600, np.array(box))
    shifted = cv2.warpAffine(image, np.array([[1.0, 0, -x0], [0, 1.0, -y0]]), (w, h), flags=cv2.INTER_NEAREST,
                             borderMode=cv2.BORDER_CONSTANT)
    interpolation = cv2.INTER_AREA if w > 192 else cv2.INTER_LINEAR
    np.testing.assert_array_equal(pixels, cv2.resize(shifted, (192, 192), interpolation=interpolation)[..., ::-1])


@pytest.mark.parametrize(("shape", "mean", "std"), [((3, 17, 23, 3), (0.485, 0.456, 0.406), (0.229, 0.224, 0.225)),
                                                    ((17, 23, 3), (0.5, 0.5, 0.5), (0.25, 0.25, 0.25)),
                                                    ((2, 9, 5, 1), (0.3,), (0.7,))])
def test_normalising_bytes_by_table_gives_the_same_floats(shape, mean, std):
    contract = ModelContract(shape[-2], shape[-3], "rgb" if shape[-1] == 3 else "gray", mean, std, "heatmaps",
                             tango.KEYPOINTS_M.copy(), "full")
    pixels = np.random.default_rng(2).integers(0, 256, shape, dtype=np.uint8)
    pixels.flat[:2] = (0, 255)
    expected = normalise(pixels.astype(np.float32) / 255.0, contract)
    found = normalise_uint8(pixels, contract)
    assert found.dtype == np.float32 and found.flags.c_contiguous and found.shape == expected.shape
    np.testing.assert_array_equal(found, expected)


def test_oracle_crop_needs_a_box():
    with pytest.raises(InputError, match="needs the label's box"):
        prepare(np.zeros((10, 10, 3), np.uint8), CONTRACT, None)


def _conv_heatmap_model(path, turns: str | None, pool: tuple[int, int] = (4, 4), keypoints_m=tango.KEYPOINTS_M) -> None:
    """A heatmap model with random (asymmetric) 3x3 kernels and 4x4 max pooling: not
    rotation-equivariant by itself."""
    import onnx
    from onnx import TensorProto, helper

    weights = np.random.default_rng(0).normal(size=(11, 3, 3, 3)).astype(np.float32)
    nodes = [helper.make_node("Conv", ["image", "w"], ["c"], pads=[1, 1, 1, 1]),
             helper.make_node("MaxPool", ["c"], ["heatmaps"], kernel_shape=list(pool), strides=list(pool))]
    graph = helper.make_graph(nodes, "conv", [helper.make_tensor_value_info("image", TensorProto.FLOAT,
                                                                            ["n", 3, 32, 32])],
                              [helper.make_tensor_value_info("heatmaps", TensorProto.FLOAT,
                                                             ["n", 11, 32 // pool[0], 32 // pool[1]])],
                              [helper.make_tensor("w", TensorProto.FLOAT, weights.shape, weights.ravel())])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    contract = ModelContract(32, 32, "rgb", (0.5,) * 3, (0.25,) * 3, "heatmaps", np.array(keypoints_m, float),
                             "oracle_box", int(turns or 1))
    for key, value in contract.metadata().items():
        entry = model.metadata_props.add()
        entry.key, entry.value = key, value
    onnx.save(model, str(path))


def test_quarter_turns_make_heatmaps_turn_with_the_image(tmp_path):
    from stages.common.pose_model import PoseModel

    batch = np.random.default_rng(1).normal(size=(2, 3, 32, 32)).astype(np.float32)
    turned = np.ascontiguousarray(np.rot90(batch, 1, axes=(2, 3)))
    for turns in ("4", None):
        _conv_heatmap_model(tmp_path / "m.onnx", turns)
        model = PoseModel(tmp_path / "m.onnx")
        assert model.contract.turns == int(turns or 1)
        upright, of_turned = model.infer(batch)[0], model.infer(turned)[0]
        equivariant = np.allclose(np.rot90(upright, 1, axes=(2, 3)), of_turned, atol=1e-4)
        assert equivariant == (turns == "4")
        # evaluate.turns off: one pass, whatever the model asks
        single = model.infer(batch, turns=False)[0]
        assert np.allclose(single, model.session.run(None, {"image": batch})[0])


@pytest.mark.parametrize("change", [{"speedplus.turns": "3"}, {"speedplus.turns": "4", "speedplus.input_size": "64x32"},
                                    {"speedplus.turns": "4", "speedplus.output": "keypoints"}])
def test_quarter_turns_only_for_square_heatmap_models(change):
    with pytest.raises(InputError, match="speedplus.turns"):
        parse_contract({**CONTRACT.metadata(), **change}, "m.onnx")


def test_quarter_turns_of_non_square_heatmaps_are_an_error_naming_the_model(tmp_path):
    from stages.common.pose_model import PoseModel

    _conv_heatmap_model(tmp_path / "wide.onnx", "4", pool=(4, 8))
    model = PoseModel(tmp_path / "wide.onnx")
    with pytest.raises(InputError, match=r"wide\.onnx: speedplus.turns=4 needs square heatmaps"):
        model.infer(np.zeros((1, 3, 32, 32), np.float32))


@pytest.mark.parametrize("turns", ["4", None])
def test_heatmaps_of_another_keypoint_count_are_an_error_naming_the_model(tmp_path, turns):
    from stages.common.pose_model import PoseModel

    _conv_heatmap_model(tmp_path / "five.onnx", turns, keypoints_m=tango.KEYPOINTS_M[:5])  # 11 heatmaps
    model = PoseModel(tmp_path / "five.onnx")
    with pytest.raises(InputError, match=r"five\.onnx: speedplus.output=heatmaps needs \(N, 5, h, w\)"):
        model.infer(np.zeros((1, 3, 32, 32), np.float32))


@pytest.mark.parametrize("fixed", [1, 4])
def test_a_model_of_a_fixed_batch_size_gets_batches_of_that_size(tmp_path, fixed):
    """torch.onnx.export without dynamic axes fixes the batch: 6 images go in chunks of
    ``fixed``, the last padded, and give what the model of any batch size gives."""
    import onnx

    from stages.common.pose_model import PoseModel

    _conv_heatmap_model(tmp_path / "any.onnx", None)
    model = onnx.load(tmp_path / "any.onnx")
    for value in [*model.graph.input, *model.graph.output]:
        value.type.tensor_type.shape.dim[0].Clear()
        value.type.tensor_type.shape.dim[0].dim_value = fixed
    onnx.save(model, tmp_path / "fixed.onnx")
    batch = np.random.default_rng(2).normal(size=(6, 3, 32, 32)).astype(np.float32)
    with pytest.raises(Exception, match="Got: 6 Expected: " + str(fixed)):  # what a plain session does
        PoseModel(tmp_path / "fixed.onnx").session.run(None, {"image": batch})
    chunked = PoseModel(tmp_path / "fixed.onnx")
    assert chunked.fixed_batch == fixed
    np.testing.assert_allclose(chunked.infer(batch)[0], PoseModel(tmp_path / "any.onnx").infer(batch)[0], atol=1e-5)
    chunked.check()  # a blank input of the contract's shape passes


def test_a_model_failing_on_its_own_input_shape_is_an_input_error(tmp_path):
    from stages.common.pose_model import PoseModel

    _conv_heatmap_model(tmp_path / "five.onnx", None, keypoints_m=tango.KEYPOINTS_M[:5])  # 11 heatmaps
    with pytest.raises(InputError, match=r"five\.onnx: speedplus.output=heatmaps needs"):
        PoseModel(tmp_path / "five.onnx").check()


@pytest.mark.parametrize("exported_batch", [1, 3])
def test_a_plain_torch_export_of_a_fixed_batch_scores_as_torch_computes(tmp_path, exported_batch):
    """What a user does: ``torch.onnx.export`` without dynamic axes (the batch is the dummy's),
    then the contract's metadata. Five images go through in batches of the export's size,
    and give torch's own heatmaps."""
    import onnx
    import torch

    from stages.common.pose_model import PoseModel

    torch.manual_seed(0)
    net = torch.nn.Sequential(torch.nn.Conv2d(3, 11, 3, padding=1), torch.nn.MaxPool2d(4)).eval()
    path = tmp_path / "theirs.onnx"
    torch.onnx.export(net, (torch.zeros(exported_batch, 3, 32, 32),), str(path), input_names=["image"],
                      output_names=["heatmaps"], opset_version=17, dynamo=False)
    proto = onnx.load(str(path))
    proto.ir_version = min(proto.ir_version, 10)  # what onnxruntime reads
    contract = ModelContract(32, 32, "rgb", (0.5,) * 3, (0.25,) * 3, "heatmaps", tango.KEYPOINTS_M.copy(), "full")
    for key, value in contract.metadata().items():
        entry = proto.metadata_props.add()
        entry.key, entry.value = key, value
    onnx.save(proto, str(path))
    model = PoseModel(path)
    assert model.fixed_batch == exported_batch
    model.check()
    batch = np.random.default_rng(3).normal(size=(5, 3, 32, 32)).astype(np.float32)
    with torch.no_grad():
        expected = net(torch.from_numpy(batch)).numpy()
    np.testing.assert_allclose(model.infer(batch)[0], expected, atol=1e-5)
