"""Checkpoints and exported models for tests: an untrained HOPE-Net on a dataset, exported once per session."""

from pathlib import Path

import numpy as np
import torch
from hupbench.core.io import file_sha256
from hupbench.checkpoint import Checkpoint
from hupbench.inference import export as E
from hupbench.models.build import build_model

from hupbench.core import keypoints as kp
from hupbench.data import HUPDataset, ReaderConfig

INPUT_SIZE = 64


def make_checkpoint(path, dataset, **model_cfg):
    """An untrained model (ResNet-10 backbone by default) with the train split's mean layout as its 3D prior."""
    torch.manual_seed(0)
    with np.load(dataset / "train" / "annotations.npz") as ann:
        mean = ann["keypoints_3d_cam"].mean(axis=0)
    cfg = {"name": "hopenet", "backbone": "resnet10", "points3d_mean": mean.tolist()} | model_cfg
    if cfg.get("n_keypoints", kp.NUM_KEYPOINTS) != kp.NUM_KEYPOINTS:
        cfg["points3d_mean"] = None
    model = build_model(cfg)
    K = HUPDataset(dataset, "test", ReaderConfig(input_size=INPUT_SIZE))[0]["K"].double().numpy()
    return Checkpoint(
        model_config=model.config.saved(), model=model.state_dict(), step=0, input_size=INPUT_SIZE,
        K_input=K.tolist(), config={"run_name": "tiny_hopenet"},
        dataset={"path": str(dataset), "manifest_sha256": file_sha256(dataset / "manifest.json")}).save(path)


def fitting_onnx(folder, dataset):
    """An exported untrained model with both fits (probe_fit, hand_fit: depth) that recalls the first test frame's
    truth (points3d_scale 1e-3: the untrained network adds a fraction of a millimetre), so that both fits find their
    points there, and its training split's hands (the hand fit's starts, as training records them); the ONNX file's
    path."""
    from hupbench.fits.hand_fit import training_hands

    with np.load(dataset / "test" / "annotations.npz") as ann:
        truth = ann["keypoints_3d_cam"][0]
    with np.load(dataset / "train" / "annotations.npz") as ann:
        hands = training_hands(ann["keypoints_3d_cam"], ann["grasp_id"])
    ckpt = make_checkpoint(folder / "fit.pt", dataset, input_channels=4, probe_fit="depth", hand_fit="depth",
                           points3d_mean=truth.tolist(), points3d_scale=1e-3, hand_templates=hands.tolist())
    return Path(E.run_export(E.ExportOptions(ckpt, folder / "fit.onnx", parity_frames=2), log=lambda *_: None)["onnx"])


def checkpoint_with_other_K(path, dataset):
    """A camera-lift HOPE-Net (its model holds the input camera as an ``intrinsics`` buffer) whose stored K_input
    has twice the focal lengths of that buffer's camera: a checkpoint edited, or mixing two runs."""
    K = HUPDataset(dataset, "test", ReaderConfig(input_size=INPUT_SIZE))[0]["K"].double().numpy()
    make_checkpoint(path, dataset, lift="camera", K_input=K.tolist(), input_size=INPUT_SIZE)
    payload = torch.load(path, map_location="cpu", weights_only=True)
    payload["K_input"] = (K * np.array([[2.0], [2.0], [1.0]])).tolist()
    torch.save(payload, path)
    return path


def exported_model(tmp_path_factory, dataset):
    """(checkpoint, onnx) of an untrained HOPE-Net, exported once per session (shared with test_eval)."""
    folder = tmp_path_factory.getbasetemp() / "exported_hopenet_r10_64"
    ckpt, onnx_path = folder / "model.pt", folder / "model.onnx"
    if not onnx_path.is_file():
        folder.mkdir(exist_ok=True)
        make_checkpoint(ckpt, dataset)
        E.run_export(E.ExportOptions(ckpt, onnx_path), log=lambda *_: None)
    return ckpt, onnx_path
