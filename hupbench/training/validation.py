"""Validation: MPJPE of a model on a split (hand / probe / all, mm), and batch-norm statistics
recomputed from un-augmented frames."""

from __future__ import annotations

import torch

from hupbench.core import keypoints as kp
from hupbench.data import model_images


@torch.no_grad()
def recompute_bn_statistics(model: torch.nn.Module, loader, device: torch.device, autocast: dict) -> int:
    """Replace every batch norm's running statistics by exact averages over ``loader`` (precise BN), so that
    eval-mode outputs (validation, ``hupbench eval``, ONNX) are those of the current weights: running
    averages lag weights that Adam moves fast. Training is unaffected (train mode uses batch statistics).

    Returns:
        the number of frames averaged.
    """
    norms = [m for m in model.modules() if isinstance(m, torch.nn.modules.batchnorm._BatchNorm)]
    if not norms:
        return 0
    was_training = model.training
    momenta = [m.momentum for m in norms]
    for m in norms:
        m.reset_running_stats()
        m.momentum = None  # cumulative average over the batches below
    model.train()
    frames = 0
    for batch in loader:
        with torch.autocast(**autocast):
            model(model_images(batch["image"], device, depth=batch.get("depth")))
        frames += len(batch["image"])
    for m, momentum in zip(norms, momenta):
        m.momentum = momentum
    model.train(was_training)
    return frames


@torch.no_grad()
def validate(model: torch.nn.Module, loader, device: torch.device, autocast: dict, world: int = 1) -> dict:
    """Absolute camera-frame MPJPE over a validation loader, reduced across ranks.

    Returns:
        {"all": mm (mean over all 29 keypoints and frames), "hand": mm (21 joints),
        "probe": mm (8 corners), "frames": int}.
    """
    from hupbench.metrics import keypoint_errors_mm

    was_training = model.training
    model.eval()
    sums = torch.zeros(kp.NUM_KEYPOINTS, dtype=torch.float64)
    count = torch.zeros((), dtype=torch.float64)
    for batch in loader:
        images = model_images(batch["image"], device, depth=batch.get("depth"))
        with torch.autocast(**autocast):
            points3d = model(images).points3d.float()
        errors = keypoint_errors_mm(points3d.cpu().double(), batch["keypoints_3d"].double())  # (B, 29)
        sums += errors.sum(dim=0)
        count += errors.shape[0]
    if world > 1:
        reduce_device = device if device.type == "cuda" else torch.device("cpu")
        packed = torch.cat([sums, count[None]]).to(reduce_device)
        torch.distributed.all_reduce(packed)
        sums, count = packed[:-1].cpu(), packed[-1].cpu()
    model.train(was_training)
    per_keypoint = sums / count.clamp(min=1)
    return {"all": float(per_keypoint.mean()), "hand": float(per_keypoint[: kp.NUM_HAND].mean()),
            "probe": float(per_keypoint[kp.NUM_HAND:].mean()), "frames": int(count)}
