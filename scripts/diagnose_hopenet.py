"""Where a trained HOPE-Net's 3D collapses: what it outputs, what it is fed, where its gradients go.

For a checkpoint and a dataset split (eval mode, un-augmented frames, the first ``--frames`` frames
spread evenly over the split) it prints:

1. spread ratios (std over frames of the prediction / of the truth, per axis, mean over keypoints;
   ``hupbench.metrics.spread_ratios``) of the initial 2D points, the refined 2D points (both against
   the true 2D in normalised input units) and the 3D points; MPJPE and 2D error;
2. the lifter's sensitivity: how far the 3D output moves (mm) when every refined 2D point is moved
   by 1 % of the image width in x (finite difference through the Graph U-Net alone);
3. the gradient each loss term sends into the backbone's pooled feature (L2 norm per frame,
   median), with the run's own loss weights: which term the backbone learns from.

Usage: python scripts/diagnose_hopenet.py CHECKPOINT DATASET [--split val] [--frames 256]
"""

from __future__ import annotations

import argparse

import numpy as np
import torch


def main() -> None:
    from hupbench.checkpoint import load_model
    from hupbench.data import HUPDataset, ReaderConfig
    from hupbench.metrics import mpjpe_split_mm, spread_ratios

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoint")
    parser.add_argument("dataset")
    parser.add_argument("--split", default="val")
    parser.add_argument("--frames", type=int, default=256)
    args = parser.parse_args()
    model, payload = load_model(args.checkpoint)
    model.eval()
    if model.config.name != "hopenet":
        raise SystemExit(f"{args.checkpoint} holds a {model.config.name!r} model, not HOPE-Net")
    size = int(payload["input_size"])
    reader = HUPDataset(args.dataset, args.split, ReaderConfig(input_size=size))
    rows = np.linspace(0, len(reader) - 1, min(args.frames, len(reader))).round().astype(int)
    batch = torch.utils.data.default_collate([reader[int(i)] for i in rows])
    weights = payload["config"]["loss"]

    with torch.no_grad():
        out = model(batch["image"])
    truth2d, truth3d = batch["keypoints_2d"], batch["keypoints_3d"]

    def ratios2d(points):
        padded = lambda p: torch.cat([p, torch.zeros_like(p[..., :1])], dim=-1)  # spread_ratios wants (N, K, 3)
        r = spread_ratios(padded(points), padded(truth2d))
        return f"x {r['x']:.2f} y {r['y']:.2f}"

    px = size / 2.0
    err2d = lambda p: float((p - truth2d).norm(dim=-1).mean()) * px
    r3 = spread_ratios(out.points3d, truth3d)
    split = mpjpe_split_mm(out.points3d.double(), truth3d.double())
    print(f"{args.checkpoint}: {len(rows)} {args.split} frames, input {size} px, lift "
          f"{model.config.lift}, loss weights 2D init {weights['w2d_init']}, 2D {weights['w2d']}, "
          f"3D {weights['w3d']}")
    print(f"  spread ratio, initial 2D : {ratios2d(out.points2d_init)} | error {err2d(out.points2d_init):.1f} px")
    print(f"  spread ratio, refined 2D : {ratios2d(out.points2d)} | error {err2d(out.points2d):.1f} px")
    print(f"  spread ratio, 3D         : x {r3['x']:.2f} y {r3['y']:.2f} z {r3['z']:.2f} | MPJPE all {split['all']:.1f} "
          f"hand {split['hand']:.1f} probe {split['probe']:.1f} mm")

    with torch.no_grad():
        features = model.backbone.features(batch["image"])
        lift = lambda p: model.lift_to_3d(p, features)
        base = lift(out.points2d)
        moved = lift(out.points2d + torch.tensor([0.02, 0.0]))  # 1 % of the image width = 0.02 normalised
        on_truth = lift(truth2d)
    sensitivity = (moved - base).norm(dim=-1).mean() * 1000.0
    true_x_shift = (truth3d[..., 2] * 0.02 / model.intrinsics[0] * 1000.0).mean() if model.intrinsics is not None \
        else truth3d[..., 2].mean() * 0.02 / (2 * payload["K_input"][0][0] / size) * 1000.0
    split_true2d = mpjpe_split_mm(on_truth.double(), truth3d.double())
    print(f"  lifter: moving every 2D point 1 % of the width in x moves the 3D output {sensitivity:.2f} mm "
          f"(a pinhole camera moves it {float(true_x_shift):.2f} mm); fed the true 2D it scores "
          f"{split_true2d['all']:.1f} mm")

    # gradients of each loss term with respect to the backbone's pooled feature
    model.train(False)
    features = model.backbone.features(batch["image"]).detach().requires_grad_(True)
    points2d_init = model.head2d(features).reshape(-1, model.n_keypoints, 2)
    points2d = model.graphnet(points2d_init, features)
    points3d = model.lift_to_3d(points2d, features)
    parts = {"2D init": weights["w2d_init"] * torch.nn.functional.mse_loss(points2d_init, truth2d),
             "2D refined": weights["w2d"] * torch.nn.functional.mse_loss(points2d, truth2d),
             "3D": weights["w3d"] * torch.nn.functional.mse_loss(points3d / weights["unit_3d_m"],
                                                                 truth3d / weights["unit_3d_m"])}
    for name, term in parts.items():
        (grad,) = torch.autograd.grad(term, features, retain_graph=True)
        print(f"  gradient into the pooled feature from the weighted {name:10s} term: median "
              f"{float(grad.norm(dim=-1).median()):.3e} per frame (term {float(term.detach()):.4f})")


if __name__ == "__main__":
    main()
