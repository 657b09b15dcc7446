"""hupbench export: the ONNX contract (names, shapes, dynamic batch, opset, metadata), parity, atomicity, bad input."""

import hashlib
import json
import shutil
import subprocess
import sys

import numpy as np
import onnx
import pytest
import torch
from helpers import REPO
from helpers.models import INPUT_SIZE, make_checkpoint

from hupbench.core import keypoints as kp
from hupbench.checkpoint import Checkpoint, load_model
from hupbench.cli import main
from hupbench.data import HUPDataset, ReaderConfig
from hupbench.inference import export as E
from hupbench.inference.model_file import META
from hupbench.inference.runtime import load_onnx_model
from hupbench.models.baseline import RegressorOutput
from hupbench.models.coords import pixels_to_normalized


def _images(dataset, n):
    reader = HUPDataset(dataset, "test", ReaderConfig(input_size=INPUT_SIZE))
    return torch.stack([reader[i]["image"] for i in range(n)])


def test_onnx_contract(exported, tiny_dataset):
    ckpt, onnx_path = exported
    payload = Checkpoint.read(ckpt).record()
    proto = onnx.load(str(onnx_path))
    assert {o.domain: o.version for o in proto.opset_import}[""] == E.OPSET == 18
    (inp,) = proto.graph.input
    dims = [d.dim_param or d.dim_value for d in inp.type.tensor_type.shape.dim]
    assert (inp.name, dims) == ("image", ["batch", 3, INPUT_SIZE, INPUT_SIZE])
    assert [o.name for o in proto.graph.output] == ["points2d", "points3d"]
    props = {p.key: p.value for p in proto.metadata_props}
    assert sorted(props) == sorted(META + k for k in (
        "onnx_schema", "input_size", "K_input", "keypoint_names", "skeleton_edges", "model_config", "run_name",
        "git_commit", "input_modalities", "image_statistics", "graph_sha256"))  # no hupbench.outputs: the two base outputs
    assert props["hupbench.graph_sha256"] == hashlib.sha256(proto.graph.SerializeToString()).hexdigest()
    assert props["hupbench.onnx_schema"] == "1"
    assert props["hupbench.input_size"] == str(INPUT_SIZE)
    np.testing.assert_allclose(json.loads(props["hupbench.K_input"]), payload["K_input"])
    assert json.loads(props["hupbench.keypoint_names"]) == list(kp.KEYPOINT_NAMES)
    assert json.loads(props["hupbench.skeleton_edges"]) == [list(e) for e in kp.SKELETON_EDGES]
    assert json.loads(props["hupbench.model_config"]) == payload["model_config"]
    assert props["hupbench.run_name"] == "tiny_hopenet"
    assert len(props["hupbench.git_commit"]) >= 7
    # no temporary file left beside the export
    assert sorted(p.name for p in onnx_path.parent.iterdir()) == ["model.onnx", "model.pt"]


def test_dynamic_batch_and_parity_on_real_images(exported, tiny_dataset):
    ckpt, onnx_path = exported
    module = E.contract_model(*load_model(ckpt), str(ckpt))
    session = load_onnx_model(onnx_path).session
    for batch in (1, 3):
        images = _images(tiny_dataset, batch)
        points2d, points3d = session.run(None, {"image": images.numpy()})
        assert points2d.shape == (batch, 29, 2) and points3d.shape == (batch, 29, 3)
        assert points2d.dtype == np.float32 and points3d.dtype == np.float32
    diff = E.parity(module, onnx_path, _images(tiny_dataset, 8))
    assert diff["frames"] == 8
    assert diff["points3d_mm"] <= E.PARITY_MAX_3D_MM
    assert diff["points2d_px"] == pytest.approx(diff["points2d_norm"] * INPUT_SIZE / 2)
    # the 3D outputs are real depths (the prior layout is tenths of a metre away), so the 0.1 mm
    # tolerance is tested at the scale of real outputs
    with torch.inference_mode():
        assert float(module(_images(tiny_dataset, 1))[1][..., 2].mean()) > 0.1


def test_the_runtime_s_threads_sleep_between_runs(exported):
    """onnxruntime's intra-op threads spin while waiting by default, taking a small CPU's cores from the fits that
    run after the network (CHANGELOG, issue 36: end to end at batch 1 84 -> 48 ms): the session is made without."""
    _, onnx_path = exported
    options = load_onnx_model(onnx_path, threads=2).session.get_session_options()
    assert options.get_session_config_entry("session.intra_op.allow_spinning") == "0"


def test_projection_without_2d_head():
    class Fixed3D(torch.nn.Module):
        def forward(self, image):
            p = torch.tensor([[0.1, -0.05, 0.5], [0.0, 0.0, -0.2]]).expand(image.shape[0], 2, 3)
            return RegressorOutput(None, p)

    K = [[120.0, 0.0, 32.0], [0.0, 120.0, 32.0], [0.0, 0.0, 1.0]]
    points2d, _ = E.ContractModule(Fixed3D(), K, 64)(torch.zeros(2, 3, 64, 64))
    # u = 120 * 0.1 / 0.5 + 32 = 56, v = 120 * -0.05 / 0.5 + 32 = 20 -> x = 113 / 64 - 1, y = 41 / 64 - 1
    np.testing.assert_allclose(points2d[0, 0].numpy(), [113 / 64 - 1, 41 / 64 - 1], rtol=1e-6)
    np.testing.assert_allclose(points2d[0, 0].numpy(),
                               pixels_to_normalized(torch.tensor([56.0, 20.0]), 64, 64).numpy(), rtol=1e-6)
    # a point behind the camera is projected at the minimum depth instead of dividing by <= 0
    assert bool(torch.isfinite(points2d).all())
    np.testing.assert_allclose(points2d[1, 1].numpy(), [1 / 64, 1 / 64], atol=1e-6)  # (0, 0, z) hits cx, cy


def test_failed_parity_leaves_no_file(exported, tmp_path, monkeypatch):
    ckpt, onnx_path = exported
    # reuse the real export bytes (fast) and demand an impossible tolerance
    monkeypatch.setattr(E, "export_onnx", lambda module, path, metadata, opset=18: shutil.copyfile(onnx_path, path))
    monkeypatch.setattr(E, "PARITY_MAX_3D_MM", -1.0)
    out = tmp_path / "sub" / "model.onnx"
    with pytest.raises(RuntimeError, match="ONNX parity check failed"):
        E.run_export(E.ExportOptions(ckpt, out), log=lambda *_: None)
    assert list(out.parent.iterdir()) == []


def test_bad_input(exported, tiny_dataset, tmp_path, capsys):
    ckpt, onnx_path = exported
    with pytest.raises(ValueError, match=r"needs a hupbench checkpoint \(.pt\), got 'model.onnx'"):
        E.ExportOptions(onnx_path)
    with pytest.raises(ValueError, match="must end in .onnx"):
        E.ExportOptions(ckpt, tmp_path / "x.bin")
    with pytest.raises(FileNotFoundError, match="does not exist"):
        E.run_export(E.ExportOptions(tmp_path / "missing.pt"))
    foreign = tmp_path / "foreign.pt"
    torch.save({"weights": torch.zeros(3)}, foreign)
    with pytest.raises(ValueError, match="not a hupbench checkpoint"):
        E.run_export(E.ExportOptions(foreign))
    with pytest.raises(FileNotFoundError, match="for the parity check does not exist"):
        E.run_export(E.ExportOptions(ckpt, tmp_path / "x.onnx", dataset=tmp_path / "no_dataset"))
    with pytest.raises(FileNotFoundError, match="no manifest.json"):
        E.run_export(E.ExportOptions(ckpt, tmp_path / "x.onnx", dataset=tmp_path))
    hand_only = make_checkpoint(tmp_path / "hand21.pt", tiny_dataset, n_keypoints=21)
    with pytest.raises(ValueError, match="predicts 21 keypoints"):
        E.run_export(E.ExportOptions(hand_only, tmp_path / "x.onnx"))
    assert main(["export", str(foreign)]) == 1
    assert "hupbench export: error:" in capsys.readouterr().err
    assert not list(tmp_path.glob("*.onnx"))


def test_runtime_refuses_foreign_onnx(tmp_path):
    from onnx import TensorProto, helper

    graph = helper.make_graph([helper.make_node("Identity", ["x"], ["y"])], "g",
                              [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1])],
                              [helper.make_tensor_value_info("y", TensorProto.FLOAT, [1])])
    path = tmp_path / "foreign.onnx"
    onnx.save(helper.make_model(graph), str(path))
    with pytest.raises(ValueError, match="not a hupbench ONNX export"):
        load_onnx_model(path)
    (tmp_path / "garbage.onnx").write_bytes(b"not a protobuf at all")
    with pytest.raises(ValueError, match="garbage.onnx"):
        load_onnx_model(tmp_path / "garbage.onnx")


@pytest.mark.slow
def test_export_regressor_without_2d_head(tiny_dataset, tmp_path):
    ckpt = make_checkpoint(tmp_path / "reg.pt", tiny_dataset, name="resnet_regressor")
    result = E.run_export(E.ExportOptions(ckpt), log=lambda *_: None)
    assert result["onnx"] == str(tmp_path / "reg.onnx")
    assert result["parity"]["points3d_mm"] <= E.PARITY_MAX_3D_MM
    points2d, points3d = load_onnx_model(result["onnx"]).session.run(None, {"image": _images(tiny_dataset, 2).numpy()})
    K = np.asarray(Checkpoint.read(ckpt).K_input)
    uv = (points3d @ K.T)[..., :2] / points3d[..., 2:]
    np.testing.assert_allclose(points2d, (2 * uv + 1) / INPUT_SIZE - 1, atol=1e-5)


@pytest.mark.parametrize("model_cfg", [
    {"name": "hupnet", "backbone": "resnet10", "canvas_margin": 0.25},
    {"name": "hopenet", "backbone": "resnet10", "lift": "camera", "unet_image_channels": 8},
], ids=["hupnet", "hopenet_camera_lift"])
def test_export_models_that_unproject_through_the_camera(model_cfg, tiny_dataset, tmp_path):
    """The models that carry K_input export with parity, and their ONNX 3D projects onto their ONNX 2D."""
    K = HUPDataset(tiny_dataset, "test", ReaderConfig(input_size=INPUT_SIZE))[0]["K"].double().numpy()
    ckpt = make_checkpoint(tmp_path / "cam.pt", tiny_dataset, **model_cfg, K_input=K.tolist(), input_size=INPUT_SIZE)
    result = E.run_export(E.ExportOptions(ckpt), log=lambda *_: None)
    assert result["parity"]["points3d_mm"] <= E.PARITY_MAX_3D_MM
    points2d, points3d = load_onnx_model(result["onnx"]).session.run(["points2d", "points3d"],
                                                                      {"image": _images(tiny_dataset, 3).numpy()})
    uv = (points3d @ K.T)[..., :2] / points3d[..., 2:]
    if model_cfg["name"] == "hupnet":  # HOPE-Net's 3D carries the U-Net's own 2D correction
        np.testing.assert_allclose(points2d, (2 * uv + 1) / INPUT_SIZE - 1, atol=1e-4)
    assert np.isfinite(points3d).all() and points3d.shape == (3, 29, 3)


def test_export_prints_no_exporter_noise(tmp_path):
    """The exporter's torchvision-registry message and torch's LeafSpec FutureWarning mean nothing to a
    user (we use no torchvision operator): export_onnx shows neither. A fresh process, as torch's
    loggers write to the stderr they found at import."""
    script = (
        "from hupbench.inference import export as E\n"
        "from hupbench.models.build import build_model\n"
        "net = build_model({'name': 'resnet_regressor', 'backbone': 'resnet10', 'n_keypoints': 29})\n"
        "K = [[60.0, 0.0, 16.0], [0.0, 60.0, 16.0], [0.0, 0.0, 1.0]]\n"
        f"E.export_onnx(E.ContractModule(net, K, 32), {str(tmp_path / 'm.onnx')!r}, {{}})\n")
    done = subprocess.run([sys.executable, "-W", "default", "-c", script], capture_output=True, text=True,
                          cwd=REPO, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "torchvision is not installed" not in done.stderr + done.stdout
    assert "LeafSpec" not in done.stderr + done.stdout
    assert (tmp_path / "m.onnx").is_file()


@pytest.mark.parametrize(("diff", "failed"), [
    ({"points3d_mm": 0.01, "points2d_norm": 1e-5, "confidence": None}, []),
    ({"points3d_mm": float("nan"), "points2d_norm": 1e-5, "confidence": 0.0},
     ["the ONNX or PyTorch outputs hold NaN or inf on real images"]),
    ({"points3d_mm": 0.5, "points2d_norm": 1e-5, "confidence": 0.01},
     ["points3d differ by up to 0.5000 mm (> 0.1 mm) between onnxruntime and PyTorch",
      "the keypoint confidence differs by up to 1.00e-02 (> 0.001) between onnxruntime and PyTorch"])])
def test_parity_failures_say_what_is_beyond_the_allowed(diff, failed):
    assert E.parity_failures(diff) == failed
