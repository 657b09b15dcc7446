import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from hupbench.checkpoint import Checkpoint, load_model
from hupbench.config import compose
from hupbench.training.run_config import LossConfig, train_config
from hupbench.training import loop
from hupbench.training.loop import resolve_precision, run_train
from hupbench.training.losses import loss_terms
from hupbench.data.loaders import EpochSampler
from hupbench.training.schedule import warmup_cosine
from hupbench.models.hopenet import HOPENetOutput
from helpers import REPO, THREADS


def tiny_cfg(dataset, run_dir, *extra):
    """The real train config shrunk to a few steps on the 64 px tiny dataset."""
    return compose("train", [
        "model=hopenet_r10_128", f"data.root={dataset}", f"run_dir={run_dir}", "data.reader.input_size=64",
        "data.batch_size=4", "data.num_workers=0", "data.val_frames=8", "train.max_steps=4", "train.val_every=2",
        "train.ckpt_every=2", "train.log_every=1", "train.progress=false", "train.tensorboard=false",
        f"threads={THREADS}", "precision=fp32", *extra])


def read_log(run_dir):
    return [json.loads(line) for line in (Path(run_dir) / "metrics.jsonl").read_text().splitlines()]


def test_short_run_writes_everything(tiny_dataset, tmp_path):
    run_dir = tmp_path / "run"
    result = run_train(tiny_cfg(tiny_dataset, run_dir, "train.tensorboard=true"), log=lambda *_: None)
    assert result["complete"] and result["steps"] == 4 and result["samples_seen"] == 16
    for name in ("run.json", "metrics.jsonl", "summary.json", "checkpoints/last.pt", "checkpoints/best.pt"):
        assert (run_dir / name).is_file(), name
    assert any(p.name.startswith("events.out.tfevents") for p in (run_dir / "tb").iterdir())
    info = json.loads((run_dir / "run.json").read_text())
    assert info["config"]["model"]["_target_"] == "hupbench.models.hopenet.HOPENetConfig" and info["precision"] == "fp32"
    assert len(info["git_commit"]) >= 40 and info["packages"]["torch"].startswith("2.13")
    log = read_log(run_dir)
    vals = [r for r in log if r["event"] == "val"]
    assert [r["step"] for r in vals] == [0, 2, 4]
    assert all(set(r["val_mpjpe_mm"]) == {"all", "hand", "probe"} and r["val_frames"] == 8 for r in vals)
    # "all" is the keypoint-weighted mean of the 21 hand joints and 8 corners
    v = vals[-1]["val_mpjpe_mm"]
    assert v["all"] == pytest.approx((21 * v["hand"] + 8 * v["probe"]) / 29)
    assert [r["step"] for r in log if r["event"] == "train"] == [1, 2, 3, 4]
    assert all(r["wall_s"] >= r["train_wall_s"] > 0 for r in log if r["event"] == "train")
    # the checkpoint rebuilds the model by itself, with the training split's mean layout as its prior
    model, payload = load_model(run_dir / "checkpoints" / "last.pt")
    assert payload["step"] == 4 and payload["input_size"] == 64
    assert payload["K_input"][0][0] == pytest.approx(120.0)  # 64 px dataset, fx 120, no resize
    assert torch.equal(model.prior3d.mean, torch.tensor(payload["model_config"]["points3d_mean"]))
    # the model unprojects through the camera the checkpoint records
    assert payload["model_config"] == model.config.saved() and payload["model_config"]["K_input"] == payload["K_input"]
    assert 0.3 < float(model.prior3d.mean[:, 2].mean()) < 1.0  # metres in front of the camera


def test_train_reads_the_typed_run(tiny_dataset, tmp_path):
    """train(run) takes every value from the typed run, not from the composed config it records: a run whose
    data node says batch 2 and whose schedule says 3 steps trains 3 steps of 2 frames and validates on 4
    frames, while run.config (the recorded config) still says batch 4, 4 steps and 8 validation frames."""
    from dataclasses import replace

    run = train_config(tiny_cfg(tiny_dataset, tmp_path / "run"))
    run = replace(run, data=replace(run.data, batch_size=2, val_frames=4),
                  train=replace(run.train, max_steps=3, val_every=3, ckpt_every=3))
    assert run.config["data"]["batch_size"] == 4 and run.config["train"]["max_steps"] == 4
    result = loop.train(run, log=lambda *_: None)
    assert (result["steps"], result["samples_seen"], result["val_mpjpe_mm"]["frames"]) == (3, 6, 4)


def test_resume_gives_the_same_next_losses(tiny_dataset, tmp_path):
    straight = tmp_path / "straight"
    run_train(tiny_cfg(tiny_dataset, straight, "train.max_steps=6", "train.ckpt_every=100"), log=lambda *_: None)
    pieces = tmp_path / "pieces"
    first = run_train(tiny_cfg(tiny_dataset, pieces, "train.max_steps=6", "train.ckpt_every=100",
                               "train.stop_after=3"), log=lambda *_: None)
    assert not first["complete"] and not (pieces / "summary.json").exists()
    assert Checkpoint.read(pieces / "checkpoints" / "last.pt").step == 3
    second = run_train(tiny_cfg(tiny_dataset, pieces, "train.max_steps=6", "train.ckpt_every=100"),
                       log=lambda *_: None)
    assert second["complete"] and second["steps"] == 6
    losses = {r["step"]: r["loss"] for r in read_log(straight) if r["event"] == "train"}
    resumed = {r["step"]: r["loss"] for r in read_log(pieces) if r["event"] == "train"}
    assert sorted(resumed) == [1, 2, 3, 4, 5, 6]  # nothing lost, nothing logged twice
    for step in range(1, 7):
        assert resumed[step] == pytest.approx(losses[step], rel=1e-6, abs=1e-9), step
    a = Checkpoint.read(straight / "checkpoints" / "last.pt").model
    b = Checkpoint.read(pieces / "checkpoints" / "last.pt").model
    for key in a:
        torch.testing.assert_close(a[key], b[key], rtol=1e-5, atol=1e-7)


def test_recompute_bn_statistics_gives_exact_averages():
    from hupbench.training.validation import recompute_bn_statistics

    torch.manual_seed(0)
    net = torch.nn.Sequential(torch.nn.Conv2d(3, 4, 3), torch.nn.BatchNorm2d(4))
    net[1].running_mean.fill_(50.0)  # stale statistics, as after fast-moving weights
    frames = torch.randn(12, 3, 8, 8) * 2 + 1
    loader = [{"image": frames[:4]}, {"image": frames[4:8]}, {"image": frames[8:]}]
    assert recompute_bn_statistics(net.eval(), loader, torch.device("cpu"), {"device_type": "cpu",
                                                                             "enabled": False}) == 12
    assert not net.training and net[1].momentum == 0.1
    with torch.no_grad():
        features = net[0](frames)  # (12, 4, 6, 6)
    # equal batches: the cumulative average of the batch means is the mean over all frames
    torch.testing.assert_close(net[1].running_mean, features.mean(dim=(0, 2, 3)), rtol=1e-5, atol=1e-6)


def hopenet_loss(output, batch, weights: dict):
    """:func:`loss_terms` with a loss config of ``weights`` and the logged terms as Python floats."""
    total, terms = loss_terms(output, batch, LossConfig(**weights))
    return total, {name: float(value) for name, value in terms.items()}


def test_hopenet_loss_known_values():
    target = {"keypoints_2d": torch.zeros(1, 29, 2), "keypoints_3d": torch.zeros(1, 29, 3)}
    out = HOPENetOutput(torch.full((1, 29, 2), 0.5), torch.full((1, 29, 2), 0.1), torch.full((1, 29, 3), 0.02))
    weights = {"w2d_init": 2.0, "w2d": 3.0, "w3d": 1.0, "unit_3d_m": 0.01}
    total, terms = hopenet_loss(out, target, weights)
    assert terms["loss_2d_init"] == pytest.approx(0.25)
    assert terms["loss_2d"] == pytest.approx(0.01)
    assert terms["loss_3d"] == pytest.approx(4.0)  # 2 cm off in every coordinate, measured in cm
    assert float(total) == pytest.approx(2 * 0.25 + 3 * 0.01 + 4.0)


def _half_turned(points: torch.Tensor) -> torch.Tensor:
    """The same keypoints with the 8 probe corners relabelled by the half turn (ix, iy, iz) -> (1-ix, 1-iy, iz)."""
    out = points.clone()
    out[:, 21:] = points[:, 21:][:, [6, 7, 4, 5, 2, 3, 0, 1]]
    return out


def test_symmetric_probe_loss_is_zero_for_the_half_turned_truth():
    gen = torch.Generator().manual_seed(0)
    target = {"keypoints_2d": torch.rand(3, 29, 2, generator=gen) * 2 - 1,
              "keypoints_3d": torch.rand(3, 29, 3, generator=gen) * 0.1 + torch.tensor([0.0, 0.0, 0.5])}
    # frames 0 and 2 predict the half-turned labelling (in 2D and 3D), frame 1 the truth itself
    turned = {k: _half_turned(v) for k, v in target.items()}
    p2 = torch.stack([turned["keypoints_2d"][0], target["keypoints_2d"][1], turned["keypoints_2d"][2]])
    p3 = torch.stack([turned["keypoints_3d"][0], target["keypoints_3d"][1], turned["keypoints_3d"][2]])
    weights = {"w2d_init": 1.25, "w2d": 1.25, "w3d": 1.0, "unit_3d_m": 0.01}

    def loss(symmetry):
        p2_, p3_ = p2.clone().requires_grad_(True), p3.clone().requires_grad_(True)
        total, terms = hopenet_loss(HOPENetOutput(p2_, p2_, p3_), target, {**weights, "probe_symmetry": symmetry})
        return total, terms, p3_

    total, terms, _ = loss("half_turn")
    assert float(total.detach()) == pytest.approx(0.0, abs=1e-12)
    assert terms["probe_half_turned"] == pytest.approx(2 / 3)
    plain, plain_terms, _ = loss("none")
    assert float(plain.detach()) > 1.0 and "probe_half_turned" not in plain_terms
    # the default (no key) is "none"
    default_total, _ = hopenet_loss(HOPENetOutput(p2, p2, p3), target, weights)
    assert float(default_total) == pytest.approx(float(plain.detach()))
    # gradients flow through the chosen labelling: move one predicted corner and the loss grows from it
    p3_moved = p3.clone()
    p3_moved[0, 21, 0] += 0.01
    p3_moved.requires_grad_(True)
    total, _ = hopenet_loss(HOPENetOutput(p2, p2, p3_moved), target, {**weights, "probe_symmetry": "half_turn"})
    total.backward()
    grad = p3_moved.grad
    assert float(total.detach()) == pytest.approx(1.0 / (3 * 29 * 3))   # 1 cm in one of 261 coordinates, cm^2
    assert grad[0, 21, 0] > 0 and torch.count_nonzero(grad) == 1


def test_symmetric_probe_loss_picks_by_3d_and_relabels_2d_consistently():
    # 3D half-turned, 2D exactly the truth: the 3D choice (half turn) also relabels the 2D targets,
    # so the 2D terms now see the swapped corners: the loss is the 2D terms only, and equals the
    # plain loss with 3D and 2D swapped roles
    target = {"keypoints_2d": torch.rand(1, 29, 2) * 2 - 1, "keypoints_3d": torch.rand(1, 29, 3) * 0.1}
    out = HOPENetOutput(target["keypoints_2d"], target["keypoints_2d"], _half_turned(target["keypoints_3d"]))
    weights = {"w2d_init": 1.0, "w2d": 1.0, "w3d": 1.0, "unit_3d_m": 0.01, "probe_symmetry": "half_turn"}
    total, terms = hopenet_loss(out, target, weights)
    assert terms["loss_3d"] == pytest.approx(0.0, abs=1e-12) and terms["probe_half_turned"] == 1.0
    expected = torch.nn.functional.mse_loss(target["keypoints_2d"], _half_turned(target["keypoints_2d"]))
    assert terms["loss_2d"] == pytest.approx(float(expected)) and float(expected) > 0


def test_schedule_warms_up_and_decays():
    opt = torch.optim.SGD([torch.zeros(1, requires_grad=True)], lr=1.0)
    sched = warmup_cosine(opt, total_steps=1000, warmup_steps=100, final_lr_fraction=0.1)
    lrs = []
    for _ in range(1000):
        lrs.append(sched.get_last_lr()[0])
        opt.step()
        sched.step()
    assert lrs[0] == pytest.approx(0.01) and lrs[99] == pytest.approx(1.0)
    assert max(lrs) == pytest.approx(1.0) and lrs[-1] == pytest.approx(0.1, abs=1e-4)
    assert all(a >= b for a, b in zip(lrs[100:], lrs[101:]))


def test_sampler_ranks_are_disjoint_and_resume_mid_epoch():
    whole = list(EpochSampler(50, 4, seed=1))
    assert len(whole) == 48 and len(set(whole)) == 48
    ranks = [list(EpochSampler(50, 4, seed=1, world=2, rank=r)) for r in range(2)]
    assert set(ranks[0]).isdisjoint(ranks[1]) and len(ranks[0]) == len(ranks[1]) == 24
    late = EpochSampler(50, 4, seed=1)
    late.set_position(0, 5)
    assert list(late) == whole[20:]
    late.set_position(1, 0)
    assert list(late) != whole


@pytest.mark.parametrize("overrides,error,match", [
    (["device=cuda"], RuntimeError, "device=cuda was asked for but CUDA is not available"),
    (["data.batch_size=64"], ValueError, "fewer than one batch of 64"),
    (["model.n_keypoints=21"], ValueError, r"model.n_keypoints must be 29 \(21 hand joints \+ 8 probe corners"),
])
def test_bad_config_fails_before_training(tiny_dataset, tmp_path, overrides, error, match):
    run_dir = tmp_path / "run"
    if torch.cuda.is_available() and overrides == ["device=cuda"]:
        pytest.skip("CUDA is present")
    with pytest.raises(error, match=match):
        run_train(tiny_cfg(tiny_dataset, run_dir, *overrides), log=lambda *_: None)
    assert not (run_dir / "checkpoints").exists()


def test_dataset_problems_fail_before_training(tiny_dataset, tmp_path):
    with pytest.raises(FileNotFoundError, match="has no manifest.json"):
        run_train(tiny_cfg(tmp_path, tmp_path / "run"), log=lambda *_: None)
    bad = tmp_path / "bad"
    shutil.copytree(tiny_dataset, bad)
    manifest = json.loads((bad / "manifest.json").read_text())
    manifest["keypoint_names"] = manifest["keypoint_names"][:21]
    (bad / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(ValueError, match="has 21 keypoints; the models are built for 29"):
        run_train(tiny_cfg(bad, tmp_path / "run2"), log=lambda *_: None)
    assert not (tmp_path / "run").exists() and not (tmp_path / "run2").exists()


def test_resume_drops_a_log_line_cut_short(tiny_dataset, tmp_path):
    """A run killed (or stopped by a full disk) while appending to metrics.jsonl leaves half a line; the resumed
    run drops it with the lines after its checkpoint instead of failing on it or keeping it."""
    run_dir = tmp_path / "run"
    run_train(tiny_cfg(tiny_dataset, run_dir, "train.stop_after=2"), log=lambda *_: None)
    with open(run_dir / "metrics.jsonl", "a") as f:
        f.write('{"event": "train", "loss": 0.5, "st')
    result = run_train(tiny_cfg(tiny_dataset, run_dir), log=lambda *_: None)
    assert result["complete"]
    log = read_log(run_dir)
    assert [(r["event"], r["step"]) for r in log] == [("val", 0), ("train", 1), ("train", 2), ("val", 2),
                                                      ("train", 3), ("train", 4), ("val", 4)]
    # a damaged line in the middle is not a cut: refused, naming the file and the line
    lines = (run_dir / "metrics.jsonl").read_text().splitlines()
    (run_dir / "metrics.jsonl").write_text("\n".join([lines[0], "garbage", *lines[1:]]) + "\n")
    (run_dir / "summary.json").unlink()
    with pytest.raises(ValueError, match=r"metrics.jsonl: line 2 is not a metrics record"):
        run_train(tiny_cfg(tiny_dataset, run_dir), log=lambda *_: None)


def test_unknown_model_is_named():
    with pytest.raises(Exception, match="Could not find 'model/hopenet_r99'"):
        compose("train", ["model=hopenet_r99"])


def test_checkpoint_from_another_model_is_refused(tiny_dataset, tmp_path):
    other = tmp_path / "other"
    run_train(tiny_cfg(tiny_dataset, other, "model=resnet50_128", "data.reader.input_size=64",
                       "train.max_steps=1"), log=lambda *_: None)
    with pytest.raises(ValueError, match=r"trained with another config.*model\._target_"):
        run_train(tiny_cfg(tiny_dataset, tmp_path / "run", f"train.resume={other}/checkpoints/last.pt"),
                  log=lambda *_: None)
    with pytest.raises(ValueError, match="already holds a checkpoint"):
        run_train(tiny_cfg(tiny_dataset, other, "model=resnet50_128", "data.reader.input_size=64",
                           "train.max_steps=1", "train.resume=never"), log=lambda *_: None)


def test_a_checkpoint_from_before_a_config_key_existed_resumes_at_that_key_s_old_behaviour():
    """A checkpoint written before data.reader.depth_sensor, fresh_sensor_noise and loss.w_seg existed (its config
    lacks them) is of the same config as a run with their values that do what runs did then; another value is a
    difference."""
    from hupbench.training.resume import ADDED_KEYS, _config_diff

    now = {"data": {"batch_size": 32, "reader": {"input_size": 128, "depth_sensor": "dataset",
                                                 "fresh_sensor_noise": False}}, "loss": {"w3d": 1.0, "w_seg": 1.0}}
    before = {"data": {"batch_size": 32, "reader": {"input_size": 128}}, "loss": {"w3d": 1.0}}
    assert set(ADDED_KEYS) == {"data.reader.depth_sensor", "data.reader.fresh_sensor_noise", "loss.w_seg"}
    assert _config_diff(before, now) == []
    assert _config_diff(before, {**now, "loss": {"w3d": 1.0, "w_seg": 0.5}}) == [
        "loss.w_seg: checkpoint '<absent>', now 0.5"]
    other = {"data": {"batch_size": 32, "reader": {"input_size": 128, "depth_sensor": "hololens2_ahat",
                                                   "fresh_sensor_noise": False}}, "loss": {"w3d": 1.0}}
    assert _config_diff(before, other) == ["data.reader.depth_sensor: checkpoint '<absent>', now 'hololens2_ahat'"]
    assert _config_diff(now, before) == ["data.reader.depth_sensor: checkpoint 'dataset', now '<absent>'",
                                         "data.reader.fresh_sensor_noise: checkpoint False, now '<absent>'",
                                         "loss.w_seg: checkpoint 1.0, now '<absent>'"]


MODEL_CONFIGS = sorted(p.stem for p in (REPO / "conf" / "model").glob("*.yaml"))


@pytest.mark.parametrize("batch", [1, 4])
@pytest.mark.parametrize("model", MODEL_CONFIGS)
def test_every_model_config_composes_and_builds(model, batch):
    """Each config of conf/model/ is a typed node that builds its model once training fills in the input
    camera (the default one, resized), the input channels of its data.reader.input_modalities and the probe
    box of a rigid probe head."""
    from dataclasses import fields, replace

    from hupbench.input_geometry import INPUT_MODALITIES
    from hupbench.models.build import build_model

    run = train_config(compose("train", [f"model={model}"]))
    size = run.data.reader.input_size
    assert size in (128, 224, 256)
    f, c = 480.0 * size / 256, (128.0 + 0.5) * size / 256 - 0.5
    filled = {"K_input": [[f, 0.0, c], [0.0, f, c], [0.0, 0.0, 1.0]], "input_size": size,
              "probe_half_extents": [0.036, 0.015, 0.0825] if getattr(run.model, "probe_head", None) == "rigid"
              else None}
    channels = INPUT_MODALITIES[run.data.reader.input_modalities]
    config = replace(run.model, input_channels=channels,
                     **{k: v for k, v in filled.items() if k in {f.name for f in fields(run.model)}})
    net = build_model(config.saved())
    assert net.config == config
    with torch.no_grad():
        out = net.eval()(torch.rand(batch, channels, size, size))
    assert out.points3d.shape == (batch, 29, 3)
    if config.name == "hopenet":
        assert out.points2d_init.shape == out.points2d.shape == (batch, 29, 2)
    elif config.name == "hupnet":
        assert out.points2d.shape == (batch, 29, 2)
    else:
        assert out.points2d is None  # the paper's baseline regresses 3D only


@pytest.mark.slow
def test_train_py_multirun(tiny_dataset, tmp_path):
    """python train.py -m sweeps two models, each job in its own folder with its own run.json."""
    args = [sys.executable, str(REPO / "train.py"), "-m", "model=hopenet_r10_128,resnet50_128",
            f"data.root={tiny_dataset}", f"out_root={tmp_path}", "data.reader.input_size=64", "data.batch_size=4",
            "data.num_workers=0", "data.val_frames=4", "train.max_steps=1", "train.progress=false"]
    done = subprocess.run(args, capture_output=True, text=True, cwd=tmp_path, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    summaries = sorted(tmp_path.glob("multirun/**/summary.json"))
    assert len(summaries) == 2
    names = {json.loads((s.parent / "run.json").read_text())["config"]["model_id"] for s in summaries}
    assert names == {"hopenet_r10_128", "resnet50_128"}


@pytest.mark.slow
def test_torchrun_two_processes_gloo(tiny_dataset, tmp_path):
    """2-process DDP on CPU: rank-0 files only, reduced validation equals one process's, checkpoint loads alone."""
    single = tmp_path / "single"
    run_train(tiny_cfg(tiny_dataset, single, "train.max_steps=1"), log=lambda *_: None)
    ddp = tmp_path / "ddp"
    args = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc-per-node", "2",
            str(REPO / "train.py"), "model=hopenet_r10_128", f"data.root={tiny_dataset}", f"run_dir={ddp}",
            "data.reader.input_size=64", "data.batch_size=4", "data.num_workers=0", "data.val_frames=8",
            "train.max_steps=2", "train.val_every=2", "train.ckpt_every=2", "train.log_every=1",
            "train.progress=false", "train.tensorboard=false", "threads=1"]
    done = subprocess.run(args, capture_output=True, text=True, cwd=tmp_path, timeout=600,
                          env={**__import__("os").environ, "OMP_NUM_THREADS": "1"})
    assert done.returncode == 0, done.stderr[-3000:]
    log = read_log(ddp)
    assert [r["step"] for r in log if r["event"] == "val"] == [0, 2]  # written once, by rank 0
    assert [r["samples_seen"] for r in log if r["event"] == "train"] == [8, 16]  # 2 ranks x batch 4
    # the same initial weights (same seed): the all-reduced MPJPE over 4 + 4 frames equals one process over 8
    first_ddp = log[0]["val_mpjpe_mm"]
    first_single = read_log(single)[0]["val_mpjpe_mm"]
    for key in ("all", "hand", "probe"):
        assert first_ddp[key] == pytest.approx(first_single[key], rel=1e-5)
    assert log[0]["val_frames"] == 8
    summary = json.loads((ddp / "summary.json").read_text())
    assert summary["world_size"] == 2 and summary["steps"] == 2
    model, payload = load_model(ddp / "checkpoints" / "last.pt")
    assert payload["world_size"] == 2 and not any(k.startswith("module.") for k in payload["model"])
    with torch.no_grad():
        assert model(torch.rand(1, 3, 64, 64)).points3d.shape == (1, 29, 3)


@pytest.fixture(scope="module")
def small_dataset(tmp_path_factory):
    """64 px, 28 views x 2 distances x 2 backgrounds per grasp. The grasps are the hand-set grasp turned about the probe
    axis by 0 and 20 degrees (train), 10 (val) and 30 (test): validation asks for interpolation between
    training grasps, which a few minutes of training can learn."""
    import numpy as np

    from hupbench.datagen.dataset.spec import DatasetSpec
    from hupbench.datagen.dataset.writer import GenerateRun, generate
    from hupbench.core.geometry import axis_angle_to_matrix, matrix_to_axis_angle
    from hupbench.core.io import save_npz
    from hupbench.datagen.render.preview import handset_grasp
    from hupbench.datagen.dataset.sphere import SphereSpec

    from helpers.datasets import TINY_SPEC

    g = handset_grasp()
    poses, trans = [], []
    for degrees in (0.0, 20.0, 10.0, 30.0):
        Rz = axis_angle_to_matrix(np.array([0.0, 0.0, np.deg2rad(degrees)]))
        pose = g.hand_pose.copy()
        pose[:3] = matrix_to_axis_angle(Rz @ axis_angle_to_matrix(g.hand_pose[:3]))
        poses.append(pose)
        trans.append(Rz @ g.hand_trans)
    grasps = save_npz(tmp_path_factory.mktemp("grasps4") / "grasps.npz", {
        "hand_pose": np.array(poses), "hand_trans": np.array(trans), "grasp_id": np.arange(4, dtype=np.int64)})
    root = tmp_path_factory.mktemp("small") / "dataset"
    spec = DatasetSpec(**(TINY_SPEC | {"splits": {"train": 2, "val": 1, "test": 1}, "z_ego_m": (0.5, 0.8),
                                       "sphere": SphereSpec(r_circ_m=0.25)}))
    generate(GenerateRun(spec, root, grasps, progress=False), {"test": "small_dataset"}, log=lambda *_: None)
    return root


@pytest.mark.slow
def test_short_run_lowers_validation_mpjpe(small_dataset, tmp_path):
    """A few minutes of CPU training must take validation MPJPE on an unseen grasp well below its start
    (the start is already the training split's mean layout, not an arbitrary guess)."""
    cfg = tiny_cfg(small_dataset, tmp_path / "run", "data.batch_size=16", "data.val_frames=null",
                   "train.max_steps=240", "train.val_every=80", "train.ckpt_every=240", "train.log_every=20",
                   "data.reader.rotate_deg=0")
    result = run_train(cfg, log=lambda *_: None)
    first, last = result["first_val_mpjpe_mm"]["all"], result["val_mpjpe_mm"]["all"]
    print(f"validation MPJPE {first:.1f} -> {last:.1f} mm")
    assert last < 0.6 * first, (first, last)


def test_learning_rate_scales_linearly_with_the_global_batch():
    from hupbench.training.schedule import learning_rate

    base = train_config(compose("train", ["model=hopenet_r10_128", "data.batch_size=32"])).optim
    assert learning_rate(base, 32) == pytest.approx(1e-3)            # reference_batch null: as given
    scaled = train_config(compose("train", ["model=hopenet_r10_128", "optim.reference_batch=64"])).optim
    assert learning_rate(scaled, 256) == pytest.approx(4e-3)
    assert learning_rate(scaled, 512) == pytest.approx(8e-3)


def test_the_optimiser_gets_the_scaled_rate(tiny_dataset, tmp_path):
    run_dir = tmp_path / "run"
    run_train(tiny_cfg(tiny_dataset, run_dir, "train.max_steps=1", "optim.reference_batch=8"), log=lambda *_: None)
    lrs = [r["lr"] for r in read_log(run_dir) if r["event"] == "train"]
    # batch 4 against a reference of 8: half of 1e-3; a 1-step run ends at the cosine's last value
    # (final_lr_fraction 0.02), which is the rate logged after step 1
    assert lrs == [pytest.approx(0.5e-3 * 0.02)]


@pytest.mark.slow
def test_compiled_training_matches_eager(tiny_dataset, tmp_path):
    """torch.compile changes how, not what: the first loss (same weights, same batch) agrees with an eager run's
    to 1e-4; after Adam's steps, whose per-parameter normalisation magnifies fused kernels' rounding, to 1 %."""
    eager, compiled = tmp_path / "eager", tmp_path / "compiled"
    run_train(tiny_cfg(tiny_dataset, eager, "train.max_steps=3"), log=lambda *_: None)
    run_train(tiny_cfg(tiny_dataset, compiled, "train.max_steps=3", "compile=true"), log=lambda *_: None)
    a = [r["loss"] for r in read_log(eager) if r["event"] == "train"]
    b = [r["loss"] for r in read_log(compiled) if r["event"] == "train"]
    assert len(a) == len(b) == 3 and a[0] == pytest.approx(b[0], rel=1e-4)
    assert a[1:] == pytest.approx(b[1:], rel=1e-2)


def test_error_line_is_one_line_naming_the_file():
    """train.py's error line: a DataLoader worker's exception (re-raised by torch with the worker's traceback
    in its message) becomes the worker's own message; an OSError loses its "[Errno N]"; lines are joined."""
    from hupbench.error_lines import error_line

    worker = RuntimeError("Caught FileNotFoundError in DataLoader worker process 0.\nOriginal Traceback (most recent "
                          "call last):\n  File \"data.py\", line 9, in __getitem__\n    raise FileNotFoundError(...)\n"
                          "FileNotFoundError: /d/train/rgb/000000.jpg does not exist (a frame the annotations list)\n")
    assert error_line(worker) == "/d/train/rgb/000000.jpg does not exist (a frame the annotations list)"
    assert error_line(PermissionError(30, "cannot write /r/.hupbench.lock: Read-only file system")) == \
        "cannot write /r/.hupbench.lock: Read-only file system"
    assert error_line(ValueError("first\n  second\n")) == "first second"


@pytest.mark.parametrize("avx512_bf16, amx, expected", [(False, False, "fp32"), (True, False, "bf16"),
                                                         (False, True, "bf16")])
def test_precision_auto_is_bf16_only_on_a_cpu_that_runs_it_natively(monkeypatch, avx512_bf16, amx, expected):
    """auto reads the CPU's bf16 support (an AVX2-only CPU emulates bf16, 12x slower than fp32); fp32 and bf16
    are taken as given."""
    monkeypatch.setattr(torch.cpu, "_is_avx512_bf16_supported", lambda: avx512_bf16)
    monkeypatch.setattr(torch.cpu, "_is_amx_tile_supported", lambda: amx)
    cpu = torch.device("cpu")
    assert resolve_precision("auto", cpu) == expected
    assert resolve_precision("fp32", cpu) == "fp32" and resolve_precision("bf16", cpu) == "bf16"


@pytest.mark.parametrize("supported, expected", [(False, "fp32"), (True, "bf16")])
def test_precision_auto_on_a_gpu_asks_cuda(monkeypatch, supported, expected):
    monkeypatch.setattr(torch.cuda, "is_bf16_supported", lambda *a, **k: supported)
    assert resolve_precision("auto", torch.device("cuda", 0)) == expected


def test_precision_auto_is_printed_and_recorded(tiny_dataset, tmp_path, monkeypatch):
    """A run with precision=auto says what it chose on its first line and records it in run.json."""
    monkeypatch.setattr(loop, "native_bf16", lambda device: False)
    run_dir, lines = tmp_path / "run", []
    run_train(tiny_cfg(tiny_dataset, run_dir, "train.max_steps=1", "precision=auto"), log=lines.append)
    assert json.loads((run_dir / "run.json").read_text())["precision"] == "fp32"
    assert any("on cpu in fp32 (precision=auto)" in line for line in lines), lines



def test_a_model_that_fits_the_hand_records_one_training_hand_per_grasp(tiny_dataset, tmp_path):
    """hand_fit: depth: the checkpoint's config holds the training split's hands, the first frame of each grasp
    (the hand fit's starts, hupbench.fits.hand_fit.training_hands); a model without the hand's fit holds none."""
    import numpy as np

    from hupbench.core.contract import read_annotations
    from hupbench.data import read_manifest
    from hupbench.fits.hand_fit import training_hands

    run_dir = tmp_path / "fit"
    run_train(tiny_cfg(tiny_dataset, run_dir, "+model.hand_fit=depth", "data.reader.input_modalities=rgb+depth",
                       "train.max_steps=1", "train.val_every=1", "train.ckpt_every=1"), log=lambda *_: None)
    saved = load_model(run_dir / "checkpoints" / "last.pt")[1]["model_config"]["hand_templates"]
    ann = read_annotations(tiny_dataset, "train", ("keypoints_3d_cam", "grasp_id"),
                           read_manifest(tiny_dataset, "train"))
    expected = training_hands(ann["keypoints_3d_cam"], ann["grasp_id"])
    assert len(np.unique(ann["grasp_id"])) == len(expected) >= 1
    np.testing.assert_allclose(saved, expected, atol=1e-6)
    plain = tiny_cfg(tiny_dataset, tmp_path / "plain", "train.max_steps=1", "train.val_every=1", "train.ckpt_every=1")
    run_train(plain, log=lambda *_: None)
    assert load_model(tmp_path / "plain" / "checkpoints" / "last.pt")[1]["model_config"]["hand_templates"] is None
