"""The training loss: HOPE-Net's weighted MSE terms (2D init, 2D, 3D), probe-symmetry aware, and a segmenting
model's per-pixel cross-entropy."""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch

if TYPE_CHECKING:
    from hupbench.training.run_config import LossConfig


def loss_terms(output, batch: dict, weights: LossConfig) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """HOPE-Net's weighted MSE over whichever outputs the model has.

    With ``probe_symmetry: half_turn`` the probe corners' labels are taken up to the half turn about
    the probe's long axis: per sample, the true corners are relabelled by the element of
    ``hupbench.metrics.PROBE_SYMMETRIES`` (identity or half turn) whose 3D corner MSE against the
    prediction is smaller, and the same relabelling is applied to the 2D targets, so all terms agree
    on which corner is which (PoseCNN's ShapeMatch idea for a discrete group). The 3D term is then the
    minimum over the group of the corner MSE plus the unchanged hand MSE; the choice itself carries
    no gradient.

    Args:
        output: HOPENetOutput, RegressorOutput or HUPNetOutput (points2d may be None); 2D (B, 29, 2) normalised, 3D
            (B, 29, 3) metres. batch: "keypoints_2d" and "keypoints_3d" likewise, camera frame, and for a model
            with a ``segmentation`` output (B, 3, S, S) logits, "seg" (B, S, S) int64 class indices
            (:data:`hupbench.core.contract.SEGMENT_CLASSES`): the term "loss_seg", their cross-entropy, weighs
            ``w_seg``.
        weights: the ``loss`` node (the 3D loss is measured in units of ``unit_3d_m`` metres).

    Returns:
        (total loss, {term name: unweighted 0-dim detached tensor}): tensors, so that the loop logs them
        without waiting for the device every step; with half_turn also "probe_half_turned", the fraction
        of samples whose corners were relabelled.
    """
    from hupbench.metrics import PROBE_SYMMETRIES, permute_keypoints, symmetry_costs

    target_2d = batch["keypoints_2d"]
    unit = weights.unit_3d_m
    target_3d = batch["keypoints_3d"] / unit
    choice = None
    if weights.probe_symmetry != "none":
        group = PROBE_SYMMETRIES[weights.probe_symmetry]
        with torch.no_grad():
            costs = symmetry_costs(output.points3d.float() / unit, target_3d, group, squared=True)
            choice = costs.argmin(dim=1)                                            # (B,) group element
        target_3d = permute_keypoints(target_3d, group, choice)
        target_2d = permute_keypoints(target_2d, group, choice)
    terms = {"loss_3d": torch.nn.functional.mse_loss(output.points3d.float() / unit, target_3d)}
    total = weights.w3d * terms["loss_3d"]
    if getattr(output, "points2d_init", None) is not None:
        terms["loss_2d_init"] = torch.nn.functional.mse_loss(output.points2d_init.float(), target_2d)
        total = total + weights.w2d_init * terms["loss_2d_init"]
    if output.points2d is not None:
        terms["loss_2d"] = torch.nn.functional.mse_loss(output.points2d.float(), target_2d)
        total = total + weights.w2d * terms["loss_2d"]
    if getattr(output, "segmentation", None) is not None:
        terms["loss_seg"] = torch.nn.functional.cross_entropy(output.segmentation.float(), batch["seg"])
        total = total + weights.w_seg * terms["loss_seg"]
    logged = {name: value.detach() for name, value in terms.items()}
    if choice is not None:
        logged["probe_half_turned"] = (choice != 0).float().mean()
    return total, logged
