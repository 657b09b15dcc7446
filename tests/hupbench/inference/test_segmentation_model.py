"""A model with a segmentation head (model=hupnet_seg): its per-pixel cross-entropy against the dataset's seg maps is
a training term that falls, its ONNX file has a ``segmentation`` output that matches PyTorch, and eval (either format)
and predict hand that segmentation to the fits: the probe's fit its probe pixels, the hand's its hand pixels."""

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from helpers.models import make_checkpoint
from helpers.training import tiny_overrides
from hupbench.checkpoint import load_model
from hupbench.config import compose
from hupbench.core.contract import SEGMENT_CLASSES
from hupbench.data import HUPDataset, ReaderConfig
from hupbench.inference import export as E
from hupbench.inference.predict import PredictOptions, run_predict
from hupbench.training.losses import loss_terms
from hupbench.training.run_config import LossConfig, train_config

STEPS = 24


@pytest.fixture(scope="module")
def segmenting(tiny_dataset, tmp_path_factory):
    """(checkpoint, onnx) of an untrained depth-anchored HUPNet with the segmentation head and both fits at the tiny
    dataset's 64 px (its head's random start labels pixels of every class), exported."""
    folder = tmp_path_factory.mktemp("seg")
    K = HUPDataset(tiny_dataset, "test", ReaderConfig(input_size=64))[0]["K"].double().numpy()
    checkpoint = make_checkpoint(folder / "seg.pt", tiny_dataset, name="hupnet", backbone="resnet10", input_channels=4,
                                 depth_anchor=True, segmentation=True, probe_fit="depth", hand_fit="depth",
                                 K_input=K.tolist(), input_size=64)
    onnx_path = Path(E.run_export(E.ExportOptions(checkpoint, folder / "seg.onnx", parity_frames=4),
                                  log=lambda *_: None)["onnx"])
    return checkpoint, onnx_path


def test_the_segmentation_loss_is_the_pixels_cross_entropy():
    output = type("Out", (), {"points3d": torch.zeros(1, 29, 3), "points2d": None,
                              "segmentation": torch.log(torch.tensor([0.5, 0.25, 0.25]))[None, :, None, None]
                              .expand(1, 3, 2, 2)})()
    batch = {"keypoints_2d": torch.zeros(1, 29, 2), "keypoints_3d": torch.zeros(1, 29, 3),
             "seg": torch.tensor([[[0, 1], [2, 2]]])}
    total, terms = loss_terms(output, batch, LossConfig(w_seg=2.0))
    expected = -(np.log(0.5) + 3 * np.log(0.25)) / 4
    assert float(terms["loss_seg"]) == pytest.approx(expected, rel=1e-6)
    assert float(total) == pytest.approx(2.0 * expected, rel=1e-6)


@pytest.mark.slow  # 40 s here; the default set checks the term (above), the seg batches (test_seg_labels.py) and the head
def test_the_segmentation_loss_falls_with_training(tiny_dataset, tmp_path):
    """hupnet_seg trained STEPS steps of 4 frames on the tiny dataset by the real loop: the seg maps reach the loss
    through the frame cache and the augmentation, and the term falls."""
    from hupbench.training.loop import train

    overrides = [o for o in tiny_overrides(tiny_dataset, tmp_path / "run", tmp_path / "cache")
                 if not o.startswith("model=")]
    train(train_config(compose("train", ["model=hupnet_seg", *overrides, f"train.max_steps={STEPS}",
                                         f"train.val_every={STEPS}", f"train.ckpt_every={STEPS}",
                                         "train.bn_recompute_frames=8", "data.reader.rotate_deg=15"])),
          log=lambda *_: None)
    run_dir = tmp_path / "run"
    rows = [json.loads(line) for line in (run_dir / "metrics.jsonl").read_text().splitlines()]
    losses = [row["loss_seg"] for row in rows if "loss_seg" in row]
    assert len(losses) == STEPS and np.isfinite(losses).all()
    assert np.mean(losses[-4:]) < 0.7 * np.mean(losses[:4]), losses


def test_the_exported_segmentation_matches_pytorch_and_reaches_the_fits(segmenting, tiny_dataset, tmp_path,
                                                                           monkeypatch):
    from hupbench.evaluation.prediction import EvalModel
    from hupbench.fits import hand_fit, probe_fit
    from hupbench.inference.runtime import load_onnx_model

    checkpoint, onnx_path = segmenting
    model = load_onnx_model(onnx_path)
    assert model.outputs[-1] == "segmentation"
    reader = HUPDataset(tiny_dataset, "test", ReaderConfig(input_size=64, input_modalities="rgb+depth"))
    batch = torch.stack([reader[i]["image"] for i in range(3)])
    module = E.contract_model(*load_model(checkpoint), str(checkpoint))
    with torch.no_grad():
        torch_seg = dict(zip(module.outputs, module(batch)))["segmentation"].numpy()
    assert torch_seg.shape == (3, 64, 64) and len(np.unique(torch_seg)) > 1   # it labels pixels, not one class
    seen = []

    def stand_in(part):
        def fit(points2d, points3d, images, K_input, settings, probe, pixels=None, start=None, templates=None):
            seen.append((part, pixels))
            return np.asarray(points2d, np.float64), np.asarray(points3d, np.float64), SimpleNamespace(pose=None)
        return fit

    monkeypatch.setattr(probe_fit, "fit_probe", stand_in("probe"))
    monkeypatch.setattr(hand_fit, "fit_hand", stand_in("hand"))
    for path in (checkpoint, onnx_path):
        seen.clear()
        net = EvalModel(path)
        segmentation = net.network(batch).segmentation
        assert np.mean(segmentation != torch_seg) <= E.PARITY_MAX_SEGMENTATION
        net.predict(batch)
        assert [part for part, _ in seen] == ["probe", "hand"]
        for part, pixels in seen:
            np.testing.assert_array_equal(pixels, segmentation == SEGMENT_CLASSES.index(part))
    # predict (onnxruntime, from the frames' files) hands its segmentation on as well
    seen.clear()
    rgb = sorted((tiny_dataset / "test" / "rgb").iterdir())[:3]
    run_predict(PredictOptions(onnx_path, tuple(rgb), tmp_path / "out", overlay=False,
                               depth_dir=tiny_dataset / "test" / "depth"))
    assert [part for part, _ in seen] == ["probe", "hand"]
    for part, pixels in seen:
        assert pixels.shape == (3, 64, 64)
        assert np.mean(pixels != (torch_seg == SEGMENT_CLASSES.index(part))) <= E.PARITY_MAX_SEGMENTATION


def test_eval_of_a_segmenting_checkpoint_times_it_with_its_segmentation(segmenting, tiny_dataset, tmp_path, capsys):
    """eval's latency exports the checkpoint with every output it has (the segmentation too) and times it."""
    from helpers.cli import run_cli

    checkpoint, _ = segmenting
    out = tmp_path / "results.json"
    answer = run_cli(capsys, "eval", checkpoint, tiny_dataset, "--split", "test", "--out", out)
    assert answer.rc == 0, answer.err
    latency = json.loads(out.read_text())["latency_ms_per_image"]
    assert latency["onnxruntime"]["batch1"] > 0 and latency["pytorch"]["batch1"] > 0
