#!/usr/bin/env bash
# The paper protocol for one experiment of conf/experiment/, end to end and rerunnable:
#   bash scripts/paper_protocol.sh paper_hopenet_cpu      (or paper_resnet50_cpu)
# 1. the full default dataset (31,680 frames, grasp split 7/2/2) unless it is there: hupbench generate
# 2. training: python train.py +experiment=NAME (resumes where a killed run stopped)
# 3. evaluation on the test split -> leaderboard/results/<run_name>.json, its log -> leaderboard/logs/
# 4. ONNX export (with the parity check) next to the checkpoint, and the leaderboard rebuilt
set -euo pipefail
cd "$(dirname "$0")/.."
experiment="${1:?usage: scripts/paper_protocol.sh EXPERIMENT (a file of conf/experiment/ without .yaml)}"
[ -f "conf/experiment/$experiment.yaml" ] || { echo "no conf/experiment/$experiment.yaml" >&2; exit 1; }
dataset=hupbench_out/dataset
run_name=$(python3 -c "from hupbench.config import compose; print(compose('train', ['+experiment=$experiment']).run_name)")
label=$(python3 -c "from hupbench.config import compose; print(compose('train', ['+experiment=$experiment']).label or '')")
run_dir=hupbench_out/runs/$run_name

[ -f "$dataset/manifest.json" ] || hupbench generate out_dir="$dataset"
python3 train.py "+experiment=$experiment"
[ -f "$run_dir/summary.json" ] || { echo "training of $run_name did not finish" >&2; exit 1; }
cp "$run_dir/metrics.jsonl" "leaderboard/logs/$run_name.jsonl"
hupbench export "$run_dir/checkpoints/last.pt" --out "$run_dir/$run_name.onnx" --dataset "$dataset"
hupbench eval "$run_dir/checkpoints/last.pt" "$dataset" --split test --run-name "$run_name" \
    --out "leaderboard/results/$run_name.json" \
    --training-command "bash scripts/paper_protocol.sh $experiment" --training-log "logs/$run_name.jsonl" \
    ${label:+--label "$label"}
hupbench leaderboard
