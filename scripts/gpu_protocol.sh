#!/usr/bin/env bash
# The paper protocol's HOPE-Net and our HUPNet trained on one GPU, each for a wall-clock budget, with the training
# pipeline's images/s beside the GPU's ceiling for the same model:
#   bash scripts/gpu_protocol.sh [MINUTES] [OUT]    (MINUTES of training per model, default 2; OUT, hupbench_out/gpu)
# 1. the paper protocol's dataset unless it is there: hupbench generate +track=unseen_grasps, a worker a core but two;
# 2. for conf/experiment/paper_hopenet_rgbd_fit_gpu and paper_hupnet_seg_gpu in turn:
#    benchmarks/train.py on the experiment's own config, its training pipeline (the frame cache, the run's loader
#    workers, bf16, channels_last) against one batch kept on the GPU (the ceiling: no loader in the timed loop)
#    -> OUT/<experiment>_rates.json; then python train.py +experiment=<experiment> with train.max_steps sized to
#    MINUTES at the pipeline's measured end-to-end images/s (a validation and a checkpoint at every fifth of it);
# 3. the run folder as evaluation needs it (run.json, summary.json, metrics.jsonl, train.log and checkpoints/last.pt
#    without the optimiser's state) -> OUT/<run>.tgz.part-aa, -ab ... (15 MiB parts: a lent machine's transfer limit).
# Then, where the dataset is (a CPU machine with the parts copied to FOLDER):
#   bash scripts/gpu_protocol.sh evaluate FOLDER
# unpacks each run into its run folder (unless it is there), exports it to ONNX (with the parity check), evaluates it
# on the test split -> leaderboard/results/<run>.json (its training log -> leaderboard/logs/), and rebuilds the
# leaderboard, as scripts/paper_protocol.sh does for a CPU run (docs/results.md, "Trained on a GPU").
# EXPERIMENTS names the experiments (default both), DEVICE=cpu trains on the CPU, DATASET names another dataset, and
# SET adds train config overrides to the runs and their benchmarks (the tests' smoke run: a tiny dataset, small
# batches).
set -euo pipefail
cd "$(dirname "$0")/.."
minutes="${1:-2}"
out="${2:-hupbench_out/gpu}"
device="${DEVICE:-cuda}"
dataset="${DATASET:-hupbench_out/dataset}"
read -r -a extra <<< "${SET:-}"
experiments="${EXPERIMENTS:-paper_hopenet_rgbd_fit_gpu paper_hupnet_seg_gpu}"
describe() {  # experiment $1 with SET's overrides: its run folder, loader workers, batch and the depth it reads
    python3 -c "
from hupbench.config import compose
c = compose('train', ['+experiment=$1', *'''${extra[*]:-}'''.split()])
print(c.out_root + '/' + c.run_name, c.data.num_workers, c.data.batch_size, c.data.reader.depth_sensor)"
}

if [ "$minutes" = evaluate ]; then
    parts="${2:?usage: scripts/gpu_protocol.sh evaluate FOLDER (the folder holding the parts a GPU run wrote)}"
    for experiment in $experiments; do
        read -r run_dir _ _ sensor < <(describe "$experiment")
        run_name=$(basename "$run_dir")
        if [ ! -f "$run_dir/summary.json" ]; then
            compgen -G "$parts/$run_name.tgz.part-*" > /dev/null || { echo "no $parts/$run_name.tgz.part-*" >&2
                                                                       exit 1; }
            mkdir -p "$(dirname "$run_dir")"
            cat "$parts/$run_name".tgz.part-* | tar xz -C "$(dirname "$run_dir")"
        fi
        cp "$run_dir/metrics.jsonl" "leaderboard/logs/$run_name.jsonl"
        hupbench export "$run_dir/checkpoints/last.pt" --out "$run_dir/$run_name.onnx" --dataset "$dataset"
        hupbench eval "$run_dir/checkpoints/last.pt" "$dataset" --split test --run-name "$run_name" \
            --out "leaderboard/results/$run_name.json" --depth-sensor "$sensor" \
            --training-command "bash scripts/gpu_protocol.sh" --training-log "logs/$run_name.jsonl"
    done
    hupbench leaderboard
    exit 0
fi
mkdir -p "$out"

if [ ! -f "$dataset/manifest.json" ]; then
    cores=$(nproc)
    hupbench generate +track=unseen_grasps progress=false "out_dir=$dataset" "workers=$(( cores > 3 ? cores - 2 : 1 ))"
fi
for experiment in $experiments; do
    set_args=()
    for kv in "device=$device" "data.root=$dataset" ${extra[@]+"${extra[@]}"}; do set_args+=(--set "$kv"); done
    read -r run_dir workers batch _ < <(describe "$experiment")
    run_name=$(basename "$run_dir")
    python3 benchmarks/train.py "$dataset" --experiment "$experiment" --device "$device" --batch "$batch" \
        --steps 40 --warmup 10 --threads 4 --pipelines "cache:$workers:cl:bf16,cache:0:cl:bf16:resident" \
        --json "$out/${experiment}_rates.json" "${set_args[@]}"
    read -r steps every < <(python3 -c "
import json
rate = json.load(open('$out/${experiment}_rates.json'))['cache:$workers:cl:bf16']['end_to_end_img_s']
steps = max(10, int($minutes * 60 * rate / $batch))
print(steps, max(1, steps // 5))")
    echo "$experiment: $steps steps of $batch images ($minutes min at the pipeline's measured rate)"
    python3 train.py "+experiment=$experiment" "device=$device" "data.root=$dataset" "train.max_steps=$steps" \
        "train.val_every=$every" "train.ckpt_every=$every" train.progress=false ${extra[@]+"${extra[@]}"}
    [ -f "$run_dir/summary.json" ] || { echo "training of $run_name did not finish" >&2; exit 1; }
    pack=$(mktemp -d)
    mkdir -p "$pack/$run_name/checkpoints"
    cp "$run_dir/run.json" "$run_dir/summary.json" "$run_dir/metrics.jsonl" "$run_dir/train.log" "$pack/$run_name/"
    python3 -c "
import sys, torch
checkpoint = torch.load(sys.argv[1], map_location='cpu', weights_only=False)
for key in ('optimizer', 'scheduler', 'rng'):  # a resume's state: evaluation reads the weights and the config
    checkpoint.pop(key, None)
torch.save(checkpoint, sys.argv[2])" "$run_dir/checkpoints/last.pt" "$pack/$run_name/checkpoints/last.pt"
    tar -C "$pack" -czf - "$run_name" | split -b 15M - "$out/$run_name.tgz.part-"
    rm -rf "$pack"
    ls -la "$out"
done
