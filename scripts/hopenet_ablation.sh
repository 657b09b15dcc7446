#!/usr/bin/env bash
# HOPE-Net's collapse, measured (docs/results.md): six 600-step trainings of HOPE-Net (ResNet-10, 128 px,
# batch 32, bf16 autocast, channels_last, 2 threads) on the full default dataset, each followed by
# scripts/diagnose_hopenet.py on 256 validation frames. Rerunnable; each run resumes if killed.
#   bash scripts/hopenet_ablation.sh [DATASET] [OUT]      (defaults: hupbench_out/dataset, hupbench_out/ablation)
set -euo pipefail
cd "$(dirname "$0")/.."
dataset="${1:-hupbench_out/dataset}"
out="${2:-hupbench_out/ablation}"
[ -f "$dataset/manifest.json" ] || hupbench generate out_dir="$dataset"
common=(model=hopenet_r10_128 "data.root=$dataset" "out_root=$out" threads=2 precision=bf16 channels_last=true
        train.max_steps=600 train.val_every=200 train.ckpt_every=200 data.val_frames=480 train.progress=false)
published=(model.lift=direct model.unet_image_channels=0 loss.w2d_init=1.25 loss.w2d=1.25)
declare -A runs=(
  [A_published]="${published[*]}"
  [B_direct_w2d100]="model.lift=direct model.unet_image_channels=0"
  [C_camera_w2d100]="model.unet_image_channels=0"
  [D_camera_paper_weights]="model.unet_image_channels=0 loss.w2d_init=1.25 loss.w2d=1.25"
  [E_camera_w2d100_image]=""
  [F_direct_w2d100_image]="model.lift=direct"
)
for name in A_published B_direct_w2d100 C_camera_w2d100 D_camera_paper_weights E_camera_w2d100_image F_direct_w2d100_image; do
  # shellcheck disable=SC2086
  python3 train.py "${common[@]}" run_name="$name" ${runs[$name]}
  python3 scripts/diagnose_hopenet.py "$out/$name/checkpoints/last.pt" "$dataset" --frames 256
done
