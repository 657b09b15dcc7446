#!/usr/bin/env bash
# Training from the frame cache against the reference JPEG reader (README, "The input pipeline"): three
# 400-step trainings of hopenet_r10_128 (batch 32, bf16 autocast, channels_last, 2 threads) on the full
# default dataset: cache (seed 0), JPEG reader with 1 worker (seed 0), cache (seed 1, the seed-to-seed
# noise). Prints each run's validation MPJPE (all, mm, 480 frames) every 100 steps.
#   bash scripts/compare_pipelines.sh [DATASET] [OUT]      (defaults: hupbench_out/dataset, hupbench_out/pipelines)
set -euo pipefail
cd "$(dirname "$0")/.."
dataset="${1:-hupbench_out/dataset}"
out="${2:-hupbench_out/pipelines}"
[ -f "$dataset/manifest.json" ] || hupbench generate out_dir="$dataset"
common=(model=hopenet_r10_128 "data.root=$dataset" "out_root=$out" threads=2 precision=bf16 channels_last=true
        train.max_steps=400 train.val_every=100 train.ckpt_every=400 data.val_frames=480 train.progress=false)
python3 train.py "${common[@]}" run_name=cache_seed0
python3 train.py "${common[@]}" run_name=jpeg_seed0 data.pipeline=jpeg data.num_workers=1
python3 train.py "${common[@]}" run_name=cache_seed1 seed=1
for run in cache_seed0 jpeg_seed0 cache_seed1; do
  python3 - "$out/$run/metrics.jsonl" "$run" <<'PY'
import json, sys
vals = [json.loads(line) for line in open(sys.argv[1]) if '"val"' in line]
print(f"{sys.argv[2]:12s}", " / ".join(f"{r['val_mpjpe_mm']['all']:.1f}" for r in vals), "mm at steps",
      ", ".join(str(r["step"]) for r in vals))
PY
done
