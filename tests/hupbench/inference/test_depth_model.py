"""A model that reads depth (data.reader.input_modalities=rgb+depth) through export and predict: the ONNX file has a
second input with its metadata, predict reads a depth PNG per image exactly as the training reader does, and every
missing or mismatched depth map is refused naming it."""

import json
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
import onnx
import pytest
import torch

from helpers.cli import assert_clean_error, run_cli
from helpers.models import fitting_onnx, make_checkpoint
from hupbench.checkpoint import load_model
from hupbench.data import HUPDataset, ReaderConfig
from hupbench.inference import export as E
from hupbench.inference.predict import PredictOptions, preprocess_depth, run_predict


@pytest.fixture(scope="module")
def rgbd_model(tmp_path_factory, tiny_dataset):
    """(checkpoint, onnx) of an untrained HOPE-Net that reads RGB and depth, at the tiny dataset's 64 px."""
    folder = tmp_path_factory.mktemp("rgbd")
    ckpt = make_checkpoint(folder / "rgbd.pt", tiny_dataset, input_channels=4)
    result = E.run_export(E.ExportOptions(ckpt, folder / "rgbd.onnx", parity_frames=4), log=lambda *_: None)
    return ckpt, Path(result["onnx"]), result


def frames(dataset, n=4):
    rgb = sorted((dataset / "test" / "rgb").iterdir())[:n]
    return rgb, dataset / "test" / "depth"


def test_export_writes_a_depth_input_and_its_metadata(rgbd_model):
    _, onnx_path, result = rgbd_model
    proto = onnx.load(str(onnx_path))
    inputs = {i.name: [d.dim_param or d.dim_value for d in i.type.tensor_type.shape.dim] for i in proto.graph.input}
    assert list(inputs) == ["image", "depth"] and inputs["depth"][1:] == [1, 64, 64] and inputs["image"][1:] == [3, 64, 64]
    props = {p.key: p.value for p in proto.metadata_props}
    assert props["hupbench.input_modalities"] == "rgb+depth"
    assert json.loads(props["hupbench.depth_input"])["units"] == "metres"
    assert json.loads(props["hupbench.model_config"])["input_channels"] == 4
    assert result["parity"]["points3d_mm"] < E.PARITY_MAX_3D_MM  # on the dataset's images and depth maps


def test_predict_from_images_and_depth_pngs_equals_pytorch_on_the_reader(rgbd_model, tiny_dataset, tmp_path):
    ckpt, onnx_path, _ = rgbd_model
    images, depth_dir = frames(tiny_dataset)
    result = run_predict(PredictOptions(onnx_path, images, tmp_path / "out", depth_dir=depth_dir))
    assert result["failed"] == 0
    reader = HUPDataset(tiny_dataset, "test", ReaderConfig(input_size=64, input_modalities="rgb+depth"))
    module = E.contract_model(*load_model(ckpt), str(ckpt))
    with torch.no_grad():
        _, points3d = module(torch.stack([reader[i]["image"] for i in range(len(images))]))
    for record, path, p3 in zip(result["records"], images, points3d.numpy()):
        assert record["depth"] == str(depth_dir / f"{path.stem}.png")
        np.testing.assert_allclose(record["keypoints_3d_m"], p3, atol=1e-4)  # 0.1 mm
    doc = json.loads(result["json"].read_text())
    assert doc["model"]["input_modalities"] == "rgb+depth"

    # the depth is read: the same images over flat depth maps (at each map's median, a depth it was trained on)
    # give other 3D points
    flat = tmp_path / "flat"
    flat.mkdir()
    for path in images:
        real = cv2.imread(str(depth_dir / f"{path.stem}.png"), cv2.IMREAD_UNCHANGED)
        cv2.imwrite(str(flat / f"{path.stem}.png"), np.full((64, 64), np.median(real[real > 0]), np.uint16))
    other = run_predict(PredictOptions(onnx_path, images, tmp_path / "out_flat", depth_dir=flat, overlay=False))
    moved = [np.abs(np.subtract(a["keypoints_3d_m"], b["keypoints_3d_m"])).max()
             for a, b in zip(result["records"], other["records"])]
    assert min(moved) > 1e-4


def test_export_records_the_training_depth_range(rgbd_model, tiny_dataset):
    """The calibration predict checks depth maps against: the lowest and highest median depth of the training
    frames' maps, in metres."""
    from hupbench.core.contract import read_manifest
    from hupbench.inference.image_statistics import depth_median_m
    from hupbench.inference.images import read_depth_png

    _, _, result = rgbd_model
    scale = read_manifest(tiny_dataset)["depth_scale_m"]
    medians = [depth_median_m(read_depth_png(p) * scale) for p in sorted((tiny_dataset / "train" / "depth").iterdir())]
    assert result["image_statistics"]["depth_median_m"] == [round(min(medians), 4), round(max(medians), 4)]


def test_depth_is_resized_like_the_reader():
    """predict's depth input equals the training reader's depth channel at a smaller input (nearest pixel)."""
    from hupbench.input_geometry import depth_channel, pad_and_resize

    depth = np.random.default_rng(0).integers(0, 9000, (48, 64)).astype(np.uint16)
    ours = preprocess_depth(depth, 1e-4, 32)
    square = np.zeros((64, 64), np.uint16)
    square[8:56] = depth
    reader = depth_channel(pad_and_resize(square, 32, interpolation=cv2.INTER_NEAREST)[0], 1e-4)
    assert ours.shape == (1, 32, 32) and np.array_equal(ours[0], reader)


def test_depth_errors_name_the_file(rgbd_model, exported, tiny_dataset, tmp_path, capsys):
    _, onnx_path, _ = rgbd_model
    images, depth_dir = frames(tiny_dataset, 3)
    answer = run_cli(capsys, "predict", onnx_path, *images, "--out", tmp_path / "a")
    assert_clean_error(answer, str(onnx_path), "reads RGB and depth", "--depth")
    answer = run_cli(capsys, "predict", exported[1], *images, "--out", tmp_path / "b", "--depth", depth_dir)
    assert_clean_error(answer, "reads RGB only", "--depth", "input_modalities=rgb+depth")
    answer = run_cli(capsys, "predict", onnx_path, *images, "--out", tmp_path / "c", "--depth", images[0])
    assert_clean_error(answer, "--depth", str(images[0]), "not a folder")
    answer = run_cli(capsys, "predict", onnx_path, *images, "--out", tmp_path / "c", "--depth", depth_dir,
                     "--depth-scale-m", "0")
    assert_clean_error(answer, "--depth-scale-m", "(0, 1]")

    # per image: a missing map, one of another size, an 8-bit one; the others are predicted
    bad = tmp_path / "depth"
    bad.mkdir()
    stored = cv2.imread(str(depth_dir / f"{images[0].stem}.png"), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(bad / f"{images[0].stem}.png"), stored)
    cv2.imwrite(str(bad / f"{images[1].stem}.png"), cv2.resize(stored, (32, 32), interpolation=cv2.INTER_NEAREST))
    answer = run_cli(capsys, "predict", onnx_path, *images, "--out", tmp_path / "d", "--depth", bad)
    assert answer.rc == 1 and "Traceback" not in answer.err
    records = json.loads((tmp_path / "d" / "predictions.json").read_text())["images"]
    assert [r["ok"] for r in records] == [True, False, False]
    assert "32 x 32 px, its image 64 x 64 px" in records[1]["error"] and str(bad) in records[1]["error"]
    assert "no such depth map" in records[2]["error"] and f"{images[2].stem}.png" in records[2]["error"]
    cv2.imwrite(str(bad / f"{images[2].stem}.png"), (stored // 256).astype(np.uint8))
    answer = run_cli(capsys, "predict", onnx_path, images[2], "--out", tmp_path / "e", "--depth", bad)
    records = json.loads((tmp_path / "e" / "predictions.json").read_text())["images"]
    assert answer.rc == 1 and "single-channel 16-bit, got uint8" in records[0]["error"]


# one fit alone (10 s each here) runs with the slow tests: both fits together check each one's use and their order,
# and CI keeps under 20 minutes
@pytest.mark.parametrize("asked", [pytest.param(("probe",), marks=pytest.mark.slow),
                                   pytest.param(("hand",), marks=pytest.mark.slow), ("probe", "hand")])
def test_a_model_that_fits_is_fitted_by_eval_and_predict_alike(tiny_dataset, tmp_path, monkeypatch, asked):
    """probe_fit / hand_fit: depth travel in the checkpoint and the ONNX metadata, and eval (either format) and
    predict run hupbench.fits.probe_fit and hand after the network, the probe's first, on its output and
    its RGB-D input (the fits themselves: test_probe_fit.py, test_hand_fit.py); here stand-in fits move the corners
    by 1 cm and the hand by 2 cm so that their use and order are seen. The model's own fit settings
    (model.fit_settings) travel with it and are what each fit gets."""
    from hupbench.core import keypoints as kp
    from hupbench.evaluation import evaluate
    from hupbench.fits import hand_fit, probe_fit

    fits = {f"{part}_fit": "depth" for part in asked}
    own = {asked[-1]: {"iterations": 5}}
    hands = np.arange(2 * 21 * 3, dtype=np.float64).reshape(2, 21, 3) / 1000.0 if "hand" in asked else None
    ckpt = make_checkpoint(tmp_path / "fit.pt", tiny_dataset, input_channels=4, fit_settings=own,
                           hand_templates=None if hands is None else hands.tolist(), **fits)
    onnx_path = Path(E.run_export(E.ExportOptions(ckpt, tmp_path / "fit.onnx", parity_frames=2),
                                  log=lambda *_: None)["onnx"])
    props = {p.key: p.value for p in onnx.load(str(onnx_path)).metadata_props}
    saved = json.loads(props["hupbench.model_config"])
    assert {key: saved[key] for key in ("probe_fit", "hand_fit")} == {
        key: fits.get(key, "none") for key in ("probe_fit", "hand_fit")}
    assert saved["fit_settings"] == own
    calls, steps, starts = [], [], []

    def stand_in(part, where, by):
        def fit(points2d, points3d, images, K_input, settings, probe, pixels=None, start=None, templates=None):
            calls.append((part, images.shape, float(np.asarray(points3d)[0, kp.CORNER_SLICE].mean())))
            steps.append((part, settings.iterations))
            if part == "hand":
                starts.append(np.asarray(templates))
            moved = np.array(points3d, dtype=np.float64)
            moved[:, where] += by
            return np.array(points2d, dtype=np.float64), moved, SimpleNamespace(pose=None)
        return fit

    monkeypatch.setattr(probe_fit, "fit_probe", stand_in("probe", kp.CORNER_SLICE, 0.01))
    monkeypatch.setattr(hand_fit, "fit_hand", stand_in("hand", kp.HAND_SLICE, 0.02))
    images, depth_dir = frames(tiny_dataset, 2)
    result = run_predict(PredictOptions(onnx_path, images, tmp_path / "out", depth_dir=depth_dir))
    reader = HUPDataset(tiny_dataset, "test", ReaderConfig(input_size=64, input_modalities="rgb+depth"))
    batch = torch.stack([reader[i]["image"] for i in range(len(images))])
    with torch.no_grad():
        raw = E.contract_model(*load_model(ckpt), str(ckpt))(batch)[1].double().numpy()
    expected = raw.copy()
    expected[:, kp.CORNER_SLICE] += 0.01 if "probe" in asked else 0.0
    expected[:, kp.HAND_SLICE] += 0.02 if "hand" in asked else 0.0
    for net in (evaluate.EvalModel(ckpt), evaluate.EvalModel(onnx_path)):
        np.testing.assert_allclose(net.predict(batch)[1], expected, atol=1e-4)
    for record, row in zip(result["records"], expected):
        np.testing.assert_allclose(record["keypoints_3d_m"], row, atol=1e-4)
    assert calls and all(shape[1:] == (4, 64, 64) for _, shape, _ in calls)
    assert [part for part, _, _ in calls[:len(asked)]] == list(asked)    # the probe's fit first
    if asked == ("probe", "hand"):  # the hand's fit sees the probe the probe's fit left
        assert np.isclose(calls[1][2], calls[0][2] + 0.01, atol=1e-6)
    assert {iterations for part, iterations in steps if part == asked[-1]} == {5}   # predict's and eval's alike
    # the hand fit's training hands travel in both formats too, and predict and eval hand them to it
    assert all(np.array_equal(got, hands) for got in starts) and (len(starts) > 0) == ("hand" in asked)


def test_the_model_file_names_its_training_depth_and_predict_warns_of_a_z_buffer(rgbd_model, tiny_dataset, tmp_path):
    """Trained on the tiny dataset's clean depth, the file says "none"; the same graph saying it was trained on a
    HoloLens 2's AHAT depth makes predict warn of each depth map without a hole (a z-buffer) and beyond its wrap."""
    _, onnx_path, _ = rgbd_model
    proto = onnx.load(str(onnx_path))
    props = {p.key: p for p in proto.metadata_props}
    assert props["hupbench.depth_sensor"].value == "none"
    props["hupbench.depth_sensor"].value = "hololens2_ahat"
    ahat = tmp_path / "ahat.onnx"
    onnx.save(proto, str(ahat))
    images, _ = frames(tiny_dataset, n=2)
    depth = tmp_path / "depth"
    depth.mkdir()
    cv2.imwrite(str(depth / f"{images[0].stem}.png"), np.full((64, 64), 6000, np.uint16))  # 0.6 m, no hole
    far = np.full((64, 64), 6000, np.uint16)
    far[:16] = 13000  # a wall at 1.3 m behind: an AHAT camera reads it as 0.3 m
    far[16:20] = 0
    cv2.imwrite(str(depth / f"{images[1].stem}.png"), far)
    lines = []
    result = run_predict(PredictOptions(ahat, images, tmp_path / "out", depth_dir=depth, overlay=False),
                         log=lines.append)
    assert result["failed"] == 0  # warned, not refused
    assert any("was trained on the depth of a hololens2_ahat camera" in line for line in lines)
    holes = [line for line in lines if "no pixel of the depth map is 0" in line]
    wrap = [line for line in lines if "beyond 1 m, which a hololens2_ahat depth camera does not give" in line]
    assert len(holes) == 1 and images[0].stem in holes[0]
    assert len(wrap) == 1 and images[1].stem in wrap[0]


def test_depth_input_warnings_of_each_preset():
    from hupbench.core.depth_sensor import PRESETS, depth_input_warnings

    sensor_like = np.full((32, 32), 0.6)
    sensor_like[0, :5] = 0.0
    for sensor in PRESETS.values():
        assert depth_input_warnings(sensor_like, sensor) == []
        assert len(depth_input_warnings(np.full((32, 32), 0.6), sensor)) == 1
    assert depth_input_warnings(np.where(sensor_like > 0, 2.0, 0.0), PRESETS["hololens2_ahat"])  # past its wrap
    assert not depth_input_warnings(np.where(sensor_like > 0, 2.0, 0.0), PRESETS["azure_kinect_nfov"])  # in range


def test_predict_of_a_fitting_model_fits_without_torch(tiny_dataset, tmp_path):
    """A model with both fits (probe_fit, hand_fit: depth) carries its probe in its file (hupbench.fit_probe), and
    predict runs it, fits included, in a fresh interpreter that never imports torch: its poses are those of the fits
    after the network, as eval computes them."""
    import subprocess
    import sys

    from hupbench.fits import after_network
    from hupbench.fits.known_probe import default_fit_probe
    from hupbench.inference.runtime import load_onnx_model, run_onnx

    onnx_path = fitting_onnx(tmp_path, tiny_dataset)   # it recalls the first frame's truth
    model = load_onnx_model(onnx_path)
    assert len(model.model_config["hand_templates"]) >= 1   # the hand's fit starts from a training hand, torch-free
    assert model.fit_probe.record == default_fit_probe().record
    assert np.array_equal(model.fit_probe.grid, default_fit_probe().grid)
    images, depth_dir = frames(tiny_dataset, 3)
    out = tmp_path / "out"
    code = (
        "import sys\n"
        "from hupbench.cli import main\n"
        f"rc = main(['predict', {str(onnx_path)!r}, *{[str(p) for p in images]!r}, '--depth', {str(depth_dir)!r}, "
        f"'--out', {str(out)!r}, '--no-overlay'])\n"
        "assert rc == 0, rc\n"
        "heavy = sorted(m for m in sys.modules if m == 'torch' or m.startswith(('torch.', 'torchvision', 'kornia')))\n"
        "print('IMPORTED', heavy)\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, check=False)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "IMPORTED []" in proc.stdout, proc.stdout
    records = json.loads((out / "predictions.json").read_text())["images"]
    reader = HUPDataset(tiny_dataset, "test", ReaderConfig(input_size=64, input_modalities="rgb+depth"))
    batch = np.stack([reader[i]["image"].numpy() for i in range(len(images))])
    network = run_onnx(model, batch[:, :3], batch[:, 3:])
    _, fitted = after_network(model.model_config, *network, batch, model.K_input, fitted=model.fit_probe)
    moved = np.abs(fitted - network[1]).max(axis=2)[0] > 1e-4                          # the first frame's 29 points
    assert moved[:21].any() and moved[21:].any(), "both fits move the recalled first frame's points"
    for record, p3 in zip(records, fitted):
        np.testing.assert_allclose(record["keypoints_3d_m"], p3, atol=1e-4)
