"""The collapse guard: every model config, briefly trained, gives 3D keypoints that follow the image.

A model that outputs one layout for every image (HOPE-Net's x and y did: spread ratio 0.02,
docs/results.md) can still lower its loss and its MPJPE. Each config of conf/model/ is trained for
200 steps (400 for the ResNet-50 HOPE-Net) on the tiny dataset's training frames (input shrunk to 64 px) and must make
each camera axis of its predictions vary across those frames at least half as much as the truth
(``hupbench.metrics.spread_ratios``, the same ratios ``hupbench eval`` reports and warns about).
"""

from pathlib import Path

import pytest
import torch

from hupbench.config import compose
from hupbench.data import HUPDataset, ReaderConfig
from hupbench.metrics import SPREAD_RATIO_WARN, spread_ratios

MODEL_CONFIGS = sorted(p.stem for p in (Path(__file__).resolve().parents[2] / "conf" / "model").glob("*.yaml"))
INPUT_SIZE = 64
STEPS = 200
# ResNet-50 HOPE-Net learns depth and y more slowly at batch 8: 200 steps gave spread ratios y 0.43,
# z 0.43 (x passed); it is given 400
STEPS_BY_MODEL = {"hopenet_r50": 400}


def test_every_model_config_is_guarded():
    assert {"hopenet", "hopenet_r10_128", "hupnet", "resnet50"} <= set(MODEL_CONFIGS)


def short_training(model: str, dataset, steps: int = STEPS):
    """The model of a config after ``steps`` training steps (the training code's own data pipeline,
    model build, loss and step; no run folder), in eval mode with fresh batch-norm statistics."""
    from hupbench.config import build
    from hupbench.data import setup_data
    from hupbench.training.loop import build_run_model, train_step
    from hupbench.training.validation import recompute_bn_statistics

    cfg = compose("train", [
        f"model={model}", f"data.root={dataset}", f"data.reader.input_size={INPUT_SIZE}", "data.batch_size=8",
        "data.num_workers=0", "data.val_frames=8", "train.bn_recompute_frames=20", "train.progress=false",
        "data.reader.rotate_deg=0", "data.reader.photometric=0"])
    torch.set_num_threads(2)
    device = torch.device("cpu")
    data = setup_data(cfg, 1, 0, device, log=lambda *_: None)
    net = build_run_model(cfg, data.train_set.ann, data.train_set.ann["K"][0], None, None)
    optimizer = build(cfg.optim.optimizer)(net.parameters())
    scheduler = build(cfg.optim.scheduler)(optimizer, total_steps=steps)
    autocast = {"device_type": "cpu", "dtype": torch.bfloat16, "enabled": False}
    step, epoch = 0, 0
    while step < steps:
        data.sampler.set_position(epoch, 0)
        for batch in data.train_loader:
            train_step(net.train(), optimizer, scheduler, batch, epoch, data, cfg, device, autocast)
            step += 1
            if step == steps:
                break
        epoch += 1
    recompute_bn_statistics(net, data.bn_loader, device, autocast)
    return net.eval()


# the ResNet-50 backbones take 50 to 100 s each here (200 of the default set's ~900 s): they run with -m slow
@pytest.mark.parametrize("model", [pytest.param(m, marks=pytest.mark.slow) if "50" in m else m for m in MODEL_CONFIGS])
def test_short_training_follows_the_image(model, tiny_dataset):
    net = short_training(model, tiny_dataset, STEPS_BY_MODEL.get(model, STEPS))
    frames = HUPDataset(tiny_dataset, "train", ReaderConfig(input_size=INPUT_SIZE))
    batch = torch.utils.data.default_collate([frames[i] for i in range(len(frames))])
    with torch.no_grad():
        predicted = net(batch["image"]).points3d
    ratios = spread_ratios(predicted, batch["keypoints_3d"])
    low = {axis: round(r, 3) for axis, r in ratios.items() if r < SPREAD_RATIO_WARN}
    assert not low, f"{model}: predictions barely vary across frames along {low} (spread ratio < {SPREAD_RATIO_WARN})"
