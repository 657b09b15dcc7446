"""How far predict's output can be trusted: the per-keypoint confidence of a heatmap model (null for a
regression model), and the out-of-distribution check, calibrated at export, on a real photograph.

The photograph is Debian's opencv-doc ``handSrc.jpg`` (install.sh installs the package as test data)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import onnx
import pytest
import torch
from helpers.dot_model import contract_metadata
from helpers.models import make_checkpoint

from hupbench.core.errors import BadValueError
from hupbench.checkpoint import load_model
from hupbench.data import HUPDataset, ReaderConfig
from hupbench.inference import export as E
from hupbench.inference import image_statistics as stats
from hupbench.inference.images import read_image
from hupbench.inference.model_file import NO_CONFIDENCE, read_metadata
from hupbench.inference.predict import PredictOptions, preprocess, run_predict
from hupbench.models.heatmap import heatmap_confidence

#: real hand photographs of Debian's opencv-doc package (Debian 12: /usr/share/doc/opencv-doc/opencv4/html)
HAND_PHOTOS = sorted(Path("/usr/share/doc/opencv-doc").glob("**/hand[SD]*.jpg"))
needs_photo = pytest.mark.skipif(not HAND_PHOTOS, reason="opencv-doc's handSrc.jpg is absent: run install.sh (it "
                                                          "installs opencv-doc as test data)")


# ---------------------------------------------------------------- the pieces, known answers


@pytest.mark.parametrize("shape", [(1, 29, 8, 8), (2, 3, 12, 10)])
def test_heatmap_confidence_known_answers(shape):
    B, N, H, W = shape
    flat = heatmap_confidence(torch.zeros(shape))
    np.testing.assert_allclose(flat.numpy(), np.full((B, N), 9.0 / (H * W)), rtol=1e-5)
    sharp = torch.full(shape, -1e4)
    sharp[..., 3, 4] = 0.0  # one cell holds all the mass
    np.testing.assert_allclose(heatmap_confidence(sharp).numpy(), 1.0, rtol=1e-6)
    split = torch.full(shape, -1e4)
    split[..., 1, 1] = split[..., H - 2, W - 2] = 0.0  # two modes further apart than a 3 x 3 window
    np.testing.assert_allclose(heatmap_confidence(split).numpy(), 0.5, rtol=1e-6)


def test_image_statistics_of_a_known_image():
    image = np.zeros((40, 80, 3), np.float32)
    image[..., 0] = 1.0  # pure red: saturation 1, no edges
    values = dict(zip(stats.STATISTIC_NAMES, stats.image_statistics(image, 32)))
    assert values["mean_r"] == pytest.approx(1.0) and values["mean_g"] == pytest.approx(0.0)
    assert values["std_r"] == pytest.approx(0.0, abs=1e-6) and values["saturation_mean"] == pytest.approx(1.0)
    assert values["log_gradient_mean"] == pytest.approx(np.log(1e-6), abs=1e-3)  # flat: the log's floor


def test_image_statistics_match_a_float64_computation_written_out():
    """The ten statistics against numpy in float64 on the same resized image, HSV saturation as (max - min) / max,
    the gradient and Laplacian by OpenCV's kernels applied here with scipy."""
    from scipy.ndimage import convolve

    rng = np.random.default_rng(3)
    image = rng.random((32, 32, 3)).astype(np.float32)
    x = image.astype(np.float64)
    high, low = x.max(axis=2), x.min(axis=2)
    saturation = np.where(high > 0, (high - low) / np.where(high > 0, high, 1), 0)
    grey = x @ [0.299, 0.587, 0.114]
    sobel = np.array([[-1, 0, 1], [-2, 0, 2], [-1, 0, 1]], np.float64)
    mode = "mirror"  # OpenCV's default border, BORDER_REFLECT_101
    gx, gy = convolve(grey, sobel[:, ::-1], mode=mode), convolve(grey, sobel.T[::-1], mode=mode)
    laplacian = convolve(grey, np.array([[0, 1, 0], [1, -4, 1], [0, 1, 0]], np.float64), mode=mode)
    want = [*x.mean(axis=(0, 1)), *x.std(axis=(0, 1)), saturation.mean(), saturation.std(),
            np.log(np.hypot(gx, gy).mean() + 1e-6), np.log(laplacian.var() + 1e-6)]
    np.testing.assert_allclose(stats.image_statistics(image, 32), want, rtol=1e-5, atol=1e-6)


def test_image_statistics_ignore_padding():
    """The statistics are taken on the image, not on the grey square predict pads it to: a frame and the same
    frame inside a grey border differ, a frame and itself resized do not."""
    rng = np.random.default_rng(0)
    image = rng.random((60, 90, 3)).astype(np.float32)
    a = stats.image_statistics(image, 30)
    np.testing.assert_allclose(stats.image_statistics(np.repeat(np.repeat(image, 2, 0), 2, 1), 30), a, rtol=0.05)


def test_calibration_known_answer_and_round_trip():
    rng = np.random.default_rng(1)
    train = rng.normal(size=(400, 10)) * np.arange(1, 11) + 5.0
    held_out = rng.normal(size=(200, 10)) * np.arange(1, 11) + 5.0
    cal = stats.calibrate(train, held_out, "val")
    assert cal.distance(train.mean(axis=0)[None])[0] == pytest.approx(0.0, abs=1e-9)
    # against scipy's Mahalanobis distance with the documented shrunk covariance, written out here
    from scipy.spatial.distance import mahalanobis

    cov = np.cov(train, rowvar=False)
    shrunk = (1 - stats.SHRINKAGE) * cov + stats.SHRINKAGE * np.trace(cov) / 10 * np.eye(10)
    expected = [mahalanobis(x, train.mean(0), np.linalg.inv(shrunk)) for x in held_out[:5]]
    np.testing.assert_allclose(cal.distance(held_out[:5]), expected, rtol=1e-5)
    distances = cal.distance(held_out)
    assert cal.threshold == pytest.approx(np.percentile(distances, 99))
    assert np.mean(distances > cal.threshold) == pytest.approx(0.01, abs=0.006)
    assert cal.frames == {"train": 400, "threshold": 200, "threshold_split": "val"}
    back = stats.ImageStatistics.from_json(cal.to_json(), "m.onnx")
    np.testing.assert_array_equal(back.precision, cal.precision)
    assert back.threshold == cal.threshold and back.frames == cal.frames
    # the percentile a file names is the one its messages quote, read back rather than assumed
    other = stats.ImageStatistics.from_json(json.dumps(json.loads(cal.to_json()) | {"percentile": 95.0}), "m.onnx")
    assert back.percentile == 99.0 and other.percentile == 95.0
    assert other.describe()["threshold_rule"].startswith("percentile 95 of")
    # a frame 10 standard deviations off along every axis is far beyond it
    assert cal.distance((train.mean(0) + 10 * train.std(0))[None])[0] > 5 * cal.threshold


def test_metadata_without_the_new_keys_still_reads_and_bad_ones_are_named():
    meta = read_metadata(contract_metadata())
    assert meta["outputs"] == ("points2d", "points3d") and meta["image_statistics"] is None
    with pytest.raises(BadValueError, match=r"hupbench.outputs must list \['points2d', 'points3d'\]"):
        read_metadata(contract_metadata(**{"hupbench.outputs": '["points3d", "points2d"]'}))
    with pytest.raises(BadValueError, match="hupbench.image_statistics is not a calibration of 10 image statistics"):
        read_metadata(contract_metadata(**{"hupbench.image_statistics": '{"mean": []}'}))
    cal = stats.calibrate(np.random.default_rng(2).normal(size=(20, 10)), np.zeros((3, 10)), "val")
    bad = json.loads(cal.to_json()) | {"threshold": -1.0}
    with pytest.raises(BadValueError, match="threshold > 0"):
        read_metadata(contract_metadata(**{"hupbench.image_statistics": json.dumps(bad)}), "m.onnx")


# ---------------------------------------------------------------- the depth's range


def test_depth_range_known_answers(tmp_path):
    """The calibration keeps the training frames' lowest and highest median depth; a map's median within them
    widened by DEPTH_MARGIN passes, one a factor 10 off (a unit slip) is refused naming the file."""
    rng = np.random.default_rng(4)
    cal = stats.calibrate(rng.normal(size=(20, 10)), np.zeros((3, 10)), "val", np.array([0.4, np.nan, 0.8]))
    assert cal.depth_median_m == (0.4, 0.8) and stats.DEPTH_MARGIN == 1.5
    back = stats.ImageStatistics.from_json(cal.to_json(), "m.onnx")
    assert back.depth_median_m == (0.4, 0.8) and back.describe()["depth_median_m"] == [0.4, 0.8]
    assert stats.calibrate(rng.normal(size=(20, 10)), np.zeros((3, 10)), "val").depth_median_m is None
    depth = np.zeros((10, 10), np.uint16)
    depth[:3], depth[3:6] = 6000, 9000  # 0.6 m and 0.9 m: the median of the valid values is 0.75 m
    assert stats.depth_median_m(depth * 1e-4) == pytest.approx(0.75)
    cal.check_depth(depth, 1e-4, "d.png")
    cal.check_depth(depth, 1.2 / 0.75 * 1e-4, "d.png")  # 1.2 m = 0.8 x 1.5: the edge, inside
    with pytest.raises(BadValueError, match=r"^d.png: its median depth is 7.5 m at --depth-scale-m 0.001, outside the "
                                            r"0.27-1.20 m the model accepts \(its training frames' medians 0.40-0.80 m, "
                                            r"widened by a factor 1.5\): is the map in another unit\? The dataset's PNGs "
                                            r"hold 0.1 mm \(--depth-scale-m 1e-4\)$"):
        cal.check_depth(depth, 1e-3, "d.png")
    with pytest.raises(BadValueError, match=r"median depth is 0.075 m at --depth-scale-m 1e-05"):
        cal.check_depth(depth, 1e-5, "d.png")
    with pytest.raises(BadValueError, match=r"median depth is nan m"):
        cal.check_depth(np.zeros((4, 4), np.uint16), 1e-4, "d.png")
    bad = json.loads(cal.to_json()) | {"depth_median_m": [0.8, 0.4]}
    with pytest.raises(BadValueError, match=r"depth_median_m \[low, high\] with 0 < low <= high"):
        stats.ImageStatistics.from_json(json.dumps(bad), "m.onnx")


def test_depth_rule_keeps_every_validation_frame_and_refuses_a_unit_off(tiny_dataset):
    """The rule on a dataset's own splits: calibrated on the training frames, every validation frame passes; the
    same frames read with a scale ten times too large or too small (a map in another unit) all fail."""
    import cv2

    from hupbench.core.contract import read_manifest

    scale = read_manifest(tiny_dataset)["depth_scale_m"]

    def maps(split):
        return [cv2.imread(str(p), cv2.IMREAD_UNCHANGED) for p in sorted((tiny_dataset / split / "depth").iterdir())]

    medians = np.array([stats.depth_median_m(m * scale) for m in maps("train")])
    cal = stats.calibrate(np.random.default_rng(0).normal(size=(20, 10)), np.zeros((1, 10)), "val", medians)
    for depth in maps("val"):
        cal.check_depth(depth, scale, "val")
        for wrong in (scale * 10, scale / 10):
            with pytest.raises(BadValueError, match="is the map in another unit"):
                cal.check_depth(depth, wrong, "val")


def test_a_depth_map_of_zeros_is_refused(tmp_path):
    import cv2

    from hupbench.inference.images import read_depth_png

    path = tmp_path / "zero.png"
    cv2.imwrite(str(path), np.zeros((24, 32), np.uint16))
    with pytest.raises(BadValueError, match=rf"^{path}: the depth map is 0 everywhere \(nothing measured\)"):
        read_depth_png(path, (32, 24))
    cv2.imwrite(str(path), np.full((24, 32), 5000, np.uint16))
    assert read_depth_png(path, (32, 24)).max() == 5000


# ---------------------------------------------------------------- exported models


@pytest.fixture(scope="module")
def hupnet(tmp_path_factory, tiny_dataset):
    """(checkpoint, export result) of an untrained HUPNet at the tiny dataset's 64 px."""
    folder = tmp_path_factory.mktemp("hupnet")
    K = HUPDataset(tiny_dataset, "test", ReaderConfig(input_size=64))[0]["K"].double().numpy()
    ckpt = make_checkpoint(folder / "hupnet.pt", tiny_dataset, name="hupnet", backbone="resnet10", canvas_margin=0.25,
                           K_input=K.tolist(), input_size=64)
    return ckpt, E.run_export(E.ExportOptions(ckpt, folder / "hupnet.onnx", parity_frames=4), log=lambda *_: None)


def test_heatmap_model_exports_and_predicts_its_confidence(hupnet, tiny_dataset, tmp_path):
    ckpt, result = hupnet
    proto = onnx.load(result["onnx"])
    assert [o.name for o in proto.graph.output] == ["points2d", "points3d", "confidence"]
    assert json.loads(result["metadata"]["hupbench.outputs"]) == ["points2d", "points3d", "confidence"]
    assert result["parity"]["confidence"] <= E.PARITY_MAX_CONFIDENCE
    frames = sorted((tiny_dataset / "test" / "rgb").iterdir())[:3]
    out = run_predict(PredictOptions(Path(result["onnx"]), frames, tmp_path / "pred"), log=lambda *_: None)
    doc = json.loads(out["json"].read_text())
    assert doc["keypoint_confidence"]["available"] is True and "3 x 3" in doc["keypoint_confidence"]["definition"]
    model, _ = load_model(ckpt)
    images = torch.from_numpy(np.stack([preprocess(read_image(f), 64)[0] for f in frames]))
    with torch.inference_mode():
        expected = model.eval()(images).confidence.numpy()
    got = np.array([r["keypoint_confidence"] for r in doc["images"]])
    assert got.shape == (3, 29) and np.all((got > 0) & (got <= 1))
    np.testing.assert_allclose(got, expected, atol=2e-4)  # rounded to 4 decimals in the JSON


def test_regression_model_has_no_confidence_and_says_why(exported, tiny_dataset, tmp_path):
    _, onnx_path = exported
    frame = min((tiny_dataset / "test" / "rgb").iterdir())
    out = run_predict(PredictOptions(onnx_path, [frame], tmp_path), log=lambda *_: None)
    doc = json.loads(out["json"].read_text())
    assert doc["keypoint_confidence"] == {"available": False, "reason": NO_CONFIDENCE}
    assert doc["images"][0]["keypoint_confidence"] is None
    assert [o.name for o in onnx.load(str(onnx_path)).graph.output] == ["points2d", "points3d"]


def test_export_calibrates_the_check_on_the_dataset(exported, tiny_dataset):
    _, onnx_path = exported
    meta = read_metadata({p.key: p.value for p in onnx.load(str(onnx_path)).metadata_props})
    cal = meta["image_statistics"]
    assert cal.frames == {"train": 20, "threshold": 20, "threshold_split": "val"}
    val = sorted((tiny_dataset / "val" / "rgb").iterdir())
    distances = cal.distance(np.stack([stats.image_statistics(read_image(f), 64) for f in val]))
    assert cal.threshold == pytest.approx(np.percentile(distances, 99))


@needs_photo
def test_ood_warning_fires_on_a_real_photo_and_not_on_a_rendered_frame(exported, tiny_dataset, tmp_path):
    _, onnx_path = exported
    frame = min((tiny_dataset / "test" / "rgb").iterdir())
    lines: list[str] = []
    out = run_predict(PredictOptions(onnx_path, [HAND_PHOTOS[0], frame], tmp_path), log=lines.append)
    photo, rendered = json.loads(out["json"].read_text())["images"]
    assert photo["ood"]["flagged"] is True and photo["ood"]["distance"] > photo["ood"]["threshold"]
    assert rendered["ood"]["flagged"] is False and rendered["ood"]["distance"] <= rendered["ood"]["threshold"]
    assert out["flagged"] == [str(HAND_PHOTOS[0])]
    assert json.loads(out["json"].read_text())["ood_check"]["flagged"] == 1
    warnings = [line for line in lines if "warning" in line]
    assert len(warnings) == 1 and warnings[0].startswith(f"hupbench predict: warning: {HAND_PHOTOS[0]} looks unlike "
                                                         "the training images")
    # the photo's overlay carries the red band
    import cv2

    band = cv2.imread(photo["overlay"])[:4, :, ::-1].reshape(-1, 3).mean(axis=0)
    assert band[0] > 1.5 * band[1] and band[0] > 1.5 * band[2]
