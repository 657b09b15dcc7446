"""A dataset with a depth sensor (the clinic track's hololens2_ahat): the sensor depth is written beside the clean
depth and recorded in the manifest, the reader gives the same bytes from the clean depth (every model reads the same
sensor depth), a fresh draw per epoch differs, verify names a frame whose sensor depth is not the preset's, and a
sensor without the maps it is made from is refused where the config enters."""

from __future__ import annotations

import json
import shutil

import cv2
import numpy as np
import pytest

from hupbench.core.contract import SENSOR_DEPTH, read_manifest
from hupbench.core.depth_sensor import PRESETS
from hupbench.core.errors import BadValueError
from hupbench.data.loaders import EpochSampler, FrameBatches
from hupbench.data.reader import HUPDataset, ReaderConfig, read_depth
from hupbench.datagen.dataset.verify import verify


def reader(root, split="train", **fields):
    return HUPDataset(root, split, ReaderConfig(input_size=48, input_modalities="rgb+depth", **fields))


def test_the_sensor_depth_is_written_beside_the_clean_depth_and_recorded(tiny_clinic):
    root, _ = tiny_clinic
    manifest = read_manifest(root)
    assert manifest["modalities"] == ["rgb", "depth", "seg", SENSOR_DEPTH]
    recorded = manifest["depth_sensor"]
    assert recorded["preset"] == "hololens2_ahat"
    assert recorded["parameters"] == PRESETS["hololens2_ahat"].parameters()
    clean = read_depth(root / "train" / "depth" / "000000.png")
    sensor = read_depth(root / "train" / SENSOR_DEPTH / "000000.png")
    assert (clean > 0).all()  # the clinic's room: depth everywhere
    assert 0.01 < (sensor == 0).mean() < 0.9  # the sensor's holes
    both = (sensor > 0) & (clean > 0)
    assert not np.array_equal(sensor[both], clean[both])


def test_the_reader_makes_the_stored_sensor_depth_byte_for_byte_and_a_fresh_draw_differs(tiny_clinic):
    root, _ = tiny_clinic
    stored, made, clean = reader(root), reader(root, fresh_sensor_noise=True), reader(root, depth_sensor="none")
    assert stored.depth_files == (SENSOR_DEPTH,) and made.depth_files == ("depth", "seg")
    for i in range(len(stored)):
        assert np.array_equal(stored.depth_frame(i), made.depth_frame(i)), i
        assert (made.depth_frame(i, draw=1) != stored.depth_frame(i)).mean() > 0.05, i
        assert np.array_equal(clean.depth_frame(i), read_depth(clean.path(i, "depth"))), i


def test_fresh_noise_gives_each_epoch_its_own_draw(tiny_clinic):
    root, _ = tiny_clinic
    batches = FrameBatches(reader(root, fresh_sensor_noise=True), fresh=True)
    n = len(batches)
    sampler = EpochSampler(n, 4, seed=0, tag_epoch=True)
    first = list(sampler)
    sampler.set_position(1, 0)
    second = list(sampler)
    assert max(first) < n <= min(second)  # epoch 1's indices carry the epoch
    rows = [0, 1, 2]
    epoch0 = batches.__getitems__(rows)
    epoch1 = batches.__getitems__([r + n for r in rows])
    assert epoch0["index"].tolist() == epoch1["index"].tolist() == rows
    assert np.array_equal(epoch0["image"], epoch1["image"])
    assert (epoch0["depth"] != epoch1["depth"]).float().mean() > 0.05


def test_verify_names_a_frame_whose_sensor_depth_is_the_clean_depth(tiny_clinic, tmp_path):
    root, _ = tiny_clinic
    copy = tmp_path / "dataset"
    shutil.copytree(root, copy)
    assert verify(copy, workers=1, log=lambda *_: None)["ok"]
    shutil.copyfile(copy / "train" / "depth" / "000001.png", copy / "train" / SENSOR_DEPTH / "000001.png")
    result = verify(copy, workers=1, log=lambda *_: None)
    found = [p for p in result["problems"] if p["kind"] == "sensor_depth"]
    assert [(p["split"], p["frame_id"]) for p in found] == [("train", 1)]


def test_a_sensor_without_its_maps_is_refused(tiny_clinic, tmp_path):
    from helpers.datasets import clinic_spec

    with pytest.raises(BadValueError, match="dataset.depth_sensor=hololens2_ahat is made from the clean depth and "
                                            "the seg labels"):
        clinic_spec(modalities=("rgb", "depth"))
    with pytest.raises(BadValueError, match="data.reader.depth_sensor must be .dataset. or .none. or"):
        ReaderConfig(depth_sensor="kinect_v1")
    root, _ = tiny_clinic
    copy = tmp_path / "dataset"
    shutil.copytree(root, copy)
    manifest = json.loads((copy / "manifest.json").read_text())
    manifest["modalities"] = ["rgb", "depth"]
    manifest.pop("depth_sensor")
    (copy / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(BadValueError, match="data.reader.fresh_sensor_noise draws a depth sensor's noise, but"):
        reader(copy, fresh_sensor_noise=True)
    with pytest.raises(BadValueError, match=r"depth_sensor=azure_kinect_nfov reads the seg maps, which .* lacks"):
        reader(copy, depth_sensor="azure_kinect_nfov")


def test_a_depth_png_of_another_dtype_in_sensor_depth_is_named_by_verify(tiny_clinic, tmp_path):
    root, _ = tiny_clinic
    copy = tmp_path / "dataset"
    shutil.copytree(root, copy)
    target = copy / "test" / SENSOR_DEPTH / sorted(p.name for p in (copy / "test" / SENSOR_DEPTH).iterdir())[0]
    cv2.imwrite(str(target), np.zeros((48, 48), np.uint8))
    result = verify(copy, workers=1, log=lambda *_: None)
    assert any(p["kind"] == "image_format" and SENSOR_DEPTH in p["file"] for p in result["problems"])


def test_an_exported_depth_model_names_the_sensor_its_training_read(tiny_clinic, tmp_path):
    """Trained on the clinic track's own depth ("dataset"), the model file says hololens2_ahat and its depth check
    is calibrated on that sensor's depth; a run that read another preset or the clean depth says so."""
    import onnx
    import torch

    from helpers.models import make_checkpoint
    from hupbench.inference import export as E

    root, _ = tiny_clinic
    ckpt = make_checkpoint(tmp_path / "rgbd.pt", root, input_channels=4)
    result = E.run_export(E.ExportOptions(ckpt, tmp_path / "rgbd.onnx", parity_frames=2), log=lambda *_: None)
    props = {p.key: p.value for p in onnx.load(str(result["onnx"])).metadata_props}
    assert props["hupbench.depth_sensor"] == "hololens2_ahat"
    payload = torch.load(ckpt, map_location="cpu", weights_only=True)
    for asked, named in (("none", "none"), ("azure_kinect_nfov", "azure_kinect_nfov"), ("dataset", "hololens2_ahat")):
        payload["config"]["data"] = {"reader": {"depth_sensor": asked}}
        assert E.trained_depth_sensor(payload, root) == named
