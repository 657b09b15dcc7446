"""The training config's nodes refuse each bad value in their ``__post_init__``, naming the field as train.py's
command line writes it (docs/robustness.md, section train.py: the per-field rows, the line train.py prints,
recorded without running a training). That the command line reaches each node: tests/hupbench/training/test_matrix_train.py.
"""

import functools

import pytest
import torch

from hupbench.core.processes import usable_cores
from helpers.answers import assert_refusal
from hupbench.config import compose
from hupbench.data import DataConfig, ReaderConfig
from hupbench.training.run_config import LossConfig, OptimConfig, Schedule, TrainRun, train_config
from hupbench.training.schedule import warmup_cosine
from hupbench.models.hopenet import HOPENetConfig


def optim(reference_batch=None, scheduler=None, **optimizer) -> OptimConfig:
    """The ``optim`` node as Hydra builds it: Adam (lr 1e-3 unless given) and the warm-up cosine, partials."""
    return OptimConfig(functools.partial(torch.optim.Adam, **({"lr": 1e-3} | optimizer)),
                       functools.partial(warmup_cosine, **(scheduler or {})), reference_batch)


def data(**fields) -> DataConfig:
    return DataConfig(ReaderConfig(), **fields)


def run(**fields) -> TrainRun:
    return TrainRun(**({"model_id": "hopenet", "model": HOPENetConfig(), "data": data(), "optim": optim()} | fields))


# what builds the node, what the line must name (the field and what it must be)
CASES = {
    "batch-size-abc": (lambda: data(batch_size="abc"), ("data.batch_size", "whole number")),
    "max-steps-float": (lambda: Schedule(max_steps=1e12), ("train.max_steps", "whole number")),
    "max-steps-huge": (lambda: Schedule(max_steps=10**12), ("train.max_steps", "from 1 to 1000000000")),
    "stop-after-zero": (lambda: Schedule(stop_after=0), ("train.stop_after", "from 1 to 1000000000 or null")),
    "val-every-zero": (lambda: Schedule(val_every=0), ("train.val_every", "from 1 to 1000000000")),
    "ckpt-every-float": (lambda: Schedule(ckpt_every=2.5), ("train.ckpt_every", "whole number", "2.5")),
    "bn-frames-negative": (lambda: Schedule(bn_recompute_frames=-1), ("train.bn_recompute_frames", ">= 0")),
    "lr-negative": (lambda: optim(lr=-1), ("optim.optimizer.lr", "(0, 1]")),
    "lr-zero": (lambda: optim(lr=0), ("optim.optimizer.lr", "(0, 1]")),
    "lr-huge": (lambda: optim(lr=1e6), ("optim.optimizer.lr", "(0, 1]")),
    "lr-abc": (lambda: optim(lr="abc"), ("optim.optimizer.lr", "(0, 1]")),
    "weight-decay-negative": (lambda: optim(weight_decay=-1), ("optim.optimizer.weight_decay", ">= 0", "-1")),
    "eps-negative": (lambda: optim(eps=-1e-8), ("optim.optimizer.eps", ">= 0")),
    "betas-one": (lambda: optim(betas=[0.9, 1.0]), ("optim.optimizer.betas", "two numbers in [0, 1)")),
    "betas-one-number": (lambda: optim(betas=[0.9]), ("optim.optimizer.betas", "two numbers")),
    "optimizer-unknown-option": (lambda: optim(momentum=0.9), ("optim.optimizer.momentum", "not an option of Adam")),
    "reference-batch-zero": (lambda: optim(reference_batch=0), ("optim.reference_batch", ">= 1 or null")),
    "warmup-negative": (lambda: optim(scheduler={"warmup_steps": -1}), ("optim.scheduler.warmup_steps", ">= 0")),
    "final-lr-fraction-over-one": (lambda: optim(scheduler={"final_lr_fraction": 2}),
                                   ("optim.scheduler.final_lr_fraction", "[0, 1]")),
    "input-size-huge": (lambda: ReaderConfig(input_size=100000), ("data.reader.input_size", "from 16 to 2048")),
    "rotate-negative": (lambda: ReaderConfig(rotate_deg=-5), ("data.reader.rotate_deg", "[0, 180]")),
    "num-workers-negative": (lambda: data(num_workers=-1), ("data.num_workers", "from 0 to 1024")),
    "val-frames-zero": (lambda: data(val_frames=0), ("data.val_frames", ">= 1")),
    "pipeline-unknown": (lambda: data(pipeline="lmdb"), ("data.pipeline", "'cache' or 'jpeg'")),
    "loss-unit-zero": (lambda: LossConfig(unit_3d_m=0), ("loss.unit_3d_m", "> 0")),
    "loss-symmetry-unknown": (lambda: LossConfig(probe_symmetry="mirror"), ("loss.probe_symmetry", "'half_turn'")),
    "threads-zero": (lambda: run(threads=0), ("threads", "from 1 to")),
    # more threads than cores only contend (threads=4096: a 1-step run took more than 300 s)
    "threads-over-cores": (lambda: run(threads=usable_cores() + 1), ("threads", f"from 1 to {usable_cores()}",
                                                                      "the CPU cores this process may use")),
    "seed-negative": (lambda: run(seed=-1), ("seed", "from 0 to 2147483647")),
    "precision-fp16": (lambda: run(precision="fp16"), ("precision", "'auto' or 'fp32' or 'bf16'")),
    "n-keypoints-21": (lambda: run(model=HOPENetConfig(n_keypoints=21)), ("model.n_keypoints", "29")),
    # booleans: a string from the command line was taken as true (channels_last and train.progress: test_matrix_train.py)
    "compile-number": (lambda: run(compile=1), ("compile must be true or false", "got 1")),
    "tensorboard-maybe": (lambda: Schedule(tensorboard="maybe"), ("train.tensorboard must be true or false",)),
}


@pytest.mark.matrix
@pytest.mark.parametrize("case", list(CASES))
def test_matrix_train(case):
    build, needles = CASES[case]
    assert_refusal(build, *needles, prog="train.py")


def test_every_node_of_the_composed_config_is_typed():
    """conf/train.yaml builds into the typed nodes, with the values the YAML gives; the run keeps the resolved
    config that run.json and checkpoints record."""
    cfg = compose("train", ["model=hopenet_r10_128", "train.max_steps=7", "optim.optimizer.lr=0.002"])
    built = train_config(cfg)
    assert isinstance(built.train, Schedule) and built.train.max_steps == 7
    assert isinstance(built.loss, LossConfig) and built.loss.w2d == 100.0  # the model config's loss weights
    assert isinstance(built.data, DataConfig) and isinstance(built.data.reader, ReaderConfig)
    assert built.data.reader.input_size == 128
    assert built.optim.optimizer.func is torch.optim.Adam and built.optim.optimizer.keywords["lr"] == 0.002
    assert isinstance(built.model, HOPENetConfig) and built.model.lift == "camera"
    assert built.config["train"]["max_steps"] == 7 and built.config["model"]["_target_"].endswith("HOPENetConfig")
    assert str(built.folder) == "hupbench_out/runs/hopenet_r10_128"
