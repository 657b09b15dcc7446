"""Your own probe end to end: a linear probe built with trimesh, written as STL, through grasps -> a tiny
dataset -> verify -> a few training steps."""

import json

import numpy as np
import pytest
from helpers.datasets import annotations
from helpers.training import tiny_cfg

from hupbench.datagen.dataset.grasps_file import probe_of_dataset
from hupbench.datagen.assets.probe_mesh import linear_probe_mesh
from hupbench.datagen.dataset.verify import verify
from hupbench.core.errors import BadValueError
from hupbench.config import compose
from hupbench.training.loop import run_train
from hupbench.verbs.generate import run_generate
from hupbench.verbs.grasps import run_grasps

# three pinned candidates: the test checks the plumbing, not how many refined grasps pass the thresholds
GRASPS = ["generate.theta_vol_deg=[[0,0,0],[0,0,180]]", "generate.starts_per_theta=2", "generate.pinned_ids=[0,1,2]",
          "refine.iterations=20", "generate.short_refine_iterations=10", "sheet.tile_px=48", "threads=1"]
TINY = ["dataset.splits={train:1,val:1,test:1}", "dataset.z_ego_m=[0.5]", "dataset.n_backgrounds=1",
        "dataset.n_gloves=1", "dataset.sphere.r_circ_m=0.4", "dataset.sphere.exclude=[poles]", "dataset.width=64",
        "dataset.height=64", "workers=1", "progress=false"]


@pytest.fixture(scope="module")
def linear_grasps(tmp_path_factory):
    folder = tmp_path_factory.mktemp("custom_probe")
    stl = folder / "linear.stl"
    linear_probe_mesh().export(stl)
    LINES.clear()
    run_grasps(compose("grasps", [f"out_dir={folder / 'grasps'}", f"probe.mesh={stl}", *GRASPS]), log=LINES.append)
    return stl, folder / "grasps" / "grasps.npz"


#: what the grasps run of the linear probe printed
LINES: list[str] = []


def test_grasps_says_what_it_does_before_the_long_steps(linear_grasps):
    """First that the result depends on the CPU, then the mesh's size before its signed distance is derived
    (a dense mesh kept the run silent for minutes), then the candidates."""
    stl, _ = linear_grasps
    assert "depend on this CPU's floating point" in LINES[0]
    assert LINES[1].startswith(f"probe: {stl}: 32 triangles; deriving its signed distance")
    assert LINES[3].startswith("generating 2 x 2 candidates")


@pytest.fixture(scope="module")
def linear_dataset(linear_grasps, tmp_path_factory):
    """A tiny dataset of the linear probe. Read only."""
    stl, grasps = linear_grasps
    root = tmp_path_factory.mktemp("linear") / "dataset"
    run_generate(compose("generate", [f"out_dir={root}", f"grasps_path={grasps}", f"probe.mesh={stl}", *TINY]),
                 log=lambda *_: None)
    return root


def test_linear_probe_grasps_dataset_verify_train(linear_grasps, linear_dataset, tmp_path):
    stl, grasps = linear_grasps
    with np.load(grasps) as data:
        assert data["probe_mesh_faces"].shape == (32, 3) and "probe_mesh_record" in data.files
        assert np.load(grasps)["hand_pose"].shape == (3, 48)
    root = linear_dataset
    manifest = json.loads((root / "manifest.json").read_text())
    record = manifest["probe"]
    assert record["kind"] == "mesh" and record["path"] == str(stl.resolve()) and record["unit"] == "m"
    probe = probe_of_dataset(root)
    assert probe.record == record and probe_of_dataset(manifest).record == record
    # the 8 corners in the annotations are the linear probe's box, moved into each camera
    ann = annotations(root, splits=("train",))["train"]
    T = ann["T_cam_world"][0]
    corners_cam = probe.corners_probe @ T[:3, :3].T + T[:3, 3]
    np.testing.assert_allclose(ann["keypoints_3d_cam"][0, 21:], corners_cam, atol=1e-6)
    assert np.ptp(probe.corners_probe[:, 2]) == pytest.approx(0.155, abs=1e-6)
    # verify measures the probe's pixels against the linear probe (it would find them off the procedural one)
    checked = verify(root, workers=1, log=lambda *_: None, progress=False)
    assert checked["ok"], checked["problems"][:3]
    result = run_train(tiny_cfg(root, tmp_path / "run", tmp_path / "cache"), log=lambda *_: None)
    assert result["complete"] and result["steps"] == 2


def test_generate_refuses_grasps_of_another_probe(linear_grasps, tmp_path):
    _, grasps = linear_grasps
    with pytest.raises(BadValueError, match=r"was made for probe.mesh=.*linear.stl .* but this run names the "
                                            r"procedural probe"):
        run_generate(compose("generate", [f"out_dir={tmp_path / 'ds'}", f"grasps_path={grasps}", *TINY]),
                     log=lambda *_: None)


def test_a_fitting_model_of_the_linear_probe_fits_it_and_refuses_the_default_probe(linear_dataset, tiny_dataset,
                                                                                   tmp_path):
    """A model with the fits trained on the linear probe's dataset knows that probe (checkpoint and model file, which
    carries its signed distance): its probe fit poses the linear probe from the depth, and data of the default
    probe is refused in one line by eval's and predict's check."""
    from helpers.models import make_checkpoint

    from hupbench.core import keypoints as kp
    from hupbench.data import HUPDataset, ReaderConfig
    from hupbench.evaluation.prediction import EvalModel
    from hupbench.fits import check_fitted_probe
    from hupbench.fits.probe_fit import fit_probe
    from hupbench.inference import export as E
    from hupbench.inference.runtime import load_onnx_model

    record = json.loads((linear_dataset / "manifest.json").read_text())["probe"]
    ckpt = make_checkpoint(tmp_path / "fit.pt", linear_dataset, input_channels=4, probe_fit="depth")
    net = EvalModel(ckpt)
    onnx_path = E.run_export(E.ExportOptions(ckpt, tmp_path / "fit.onnx", parity_frames=2), log=lambda *_: None)["onnx"]
    model = load_onnx_model(onnx_path)
    for known in (net.fit_probe, model.fit_probe):
        assert known.record == record and not known.has_marker
    np.testing.assert_array_equal(model.fit_probe.grid, net.fit_probe.grid)
    check_fitted_probe(net.model_config, record, "LINEAR/manifest.json", model.fit_probe)
    with pytest.raises(BadValueError, match=r"TINY/manifest.json: the data shows the probe 'procedural' \(procedural\)"
                                            r".* knows only the probe '.*linear.stl' \(mesh\) of its model file"):
        check_fitted_probe(net.model_config, json.loads((tiny_dataset / "manifest.json").read_text()).get("probe"),
                           "TINY/manifest.json", model.fit_probe)
    # the probe's fit from the true corners moved 5 mm and turned 9 degrees: it lands on the linear probe the depth
    # shows (median over the test frames)
    reader = HUPDataset(linear_dataset, "test", ReaderConfig(input_size=64, input_modalities="rgb+depth"))
    images = np.stack([reader[i]["image"].numpy() for i in range(len(reader))])
    truth = np.stack([reader[i]["keypoints_3d"].numpy() for i in range(len(reader))]).astype(np.float64)
    centre = truth[:, kp.CORNER_SLICE].mean(1, keepdims=True)
    turn = np.array([[np.cos(0.15), -np.sin(0.15), 0.0], [np.sin(0.15), np.cos(0.15), 0.0], [0.0, 0.0, 1.0]])
    start = truth.copy()
    start[:, kp.CORNER_SLICE] = (truth[:, kp.CORNER_SLICE] - centre) @ turn.T + centre + [0.005, -0.004, 0.003]
    errors = {}
    for name, probe in (("own", model.fit_probe), ("procedural", None)):
        _, fitted, report = fit_probe(np.zeros(truth.shape[:2] + (2,)), start, images, net.K_input, probe=probe)
        errors[name] = np.median(np.linalg.norm(fitted - truth, axis=-1)[:, kp.CORNER_SLICE].mean(1)) * 1000
    before = np.median(np.linalg.norm(start - truth, axis=-1)[:, kp.CORNER_SLICE].mean(1)) * 1000
    # its own probe: half the frames within half a millimetre (those with few measured points slide along its flat
    # sides); the procedural probe's shape does not fit this depth
    assert errors["own"] < 0.5 * before < errors["procedural"], (before, errors)
