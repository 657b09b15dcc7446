#!/usr/bin/env bash
# One experiment of conf/experiment/ on its track's full dataset, end to end and rerunnable:
#   bash scripts/paper_protocol.sh paper_hopenet_cpu      (or paper_hupnet_cpu, paper_resnet50_cpu, views_hopenet_cpu)
# 1. the experiment's dataset (data.root) unless it is there: the track of conf/track/ whose out_dir it is
#    (hupbench_out/dataset: the paper's unseen grasps, 31,680 frames, grasp split 7/2/2;
#    hupbench_out/dataset_unseen_views: the same frames, views split 3/1/1): hupbench generate +track=TRACK
# 2. training: python train.py +experiment=NAME (resumes where a killed run stopped)
# 3. evaluation on the test split -> leaderboard/results/<run_name>.json, its log -> leaderboard/logs/
# 4. ONNX export (with the parity check) next to the checkpoint, and the leaderboard rebuilt
# With a second argument, a track of conf/track/ (e.g. clinic), the model trained as above is evaluated, without
# retraining, on that track's test split instead: its dataset generated unless there, training run (or resumed),
# results -> leaderboard/results/<run_name>_on_<track>.json:
#   bash scripts/paper_protocol.sh paper_hupnet_handfit_cpu clinic
set -euo pipefail
cd "$(dirname "$0")/.."
experiment="${1:?usage: scripts/paper_protocol.sh EXPERIMENT [TRACK] (EXPERIMENT a file of conf/experiment/, TRACK one of conf/track/, without .yaml)}"
on_track="${2:-}"
[ -f "conf/experiment/$experiment.yaml" ] || { echo "no conf/experiment/$experiment.yaml" >&2; exit 1; }
[ -z "$on_track" ] || [ -f "conf/track/$on_track.yaml" ] || { echo "no conf/track/$on_track.yaml" >&2; exit 1; }
dataset=$(python3 -c "from hupbench.config import compose; print(compose('train', ['+experiment=$experiment']).data.root)")
track=$(python3 -c "
from pathlib import Path
from hupbench.config import compose
tracks = [p.stem for p in sorted(Path('conf/track').glob('*.yaml')) if compose('generate', ['+track=' + p.stem]).out_dir == '$dataset']
print(tracks[0] if tracks else '')")
[ -n "$track" ] || { echo "data.root $dataset of $experiment is the out_dir of no track in conf/track/" >&2; exit 1; }
run_name=$(python3 -c "from hupbench.config import compose; print(compose('train', ['+experiment=$experiment']).run_name)")
label=$(python3 -c "from hupbench.config import compose; print(compose('train', ['+experiment=$experiment']).label or '')")
# a depth model is evaluated on the depth its training read (data.reader.depth_sensor; "dataset" is eval's default)
sensor=$(python3 -c "from hupbench.config import compose; print(compose('train', ['+experiment=$experiment']).data.reader.depth_sensor)")
run_dir=hupbench_out/runs/$run_name

[ -f "$dataset/manifest.json" ] || hupbench generate "+track=$track" progress=false
python3 train.py "+experiment=$experiment"  # a finished run answers "already complete" at once
[ -f "$run_dir/summary.json" ] || { echo "training of $run_name did not finish" >&2; exit 1; }
if [ -n "$on_track" ]; then
    other=$(python3 -c "from hupbench.config import compose; print(compose('generate', ['+track=$on_track']).out_dir)")
    [ -f "$other/manifest.json" ] || hupbench generate "+track=$on_track" progress=false
    [ -n "$label" ] || label=$(python3 -c "
from pathlib import Path
from hupbench.evaluation.evaluate import model_label
from hupbench.evaluation.prediction import EvalModel
net = EvalModel(Path('$run_dir/checkpoints/last.pt'))
print(model_label(net.model_config, net.input_size))")
    hupbench eval "$run_dir/checkpoints/last.pt" "$other" --split test --run-name "${run_name}_on_$on_track" \
        --out "leaderboard/results/${run_name}_on_$on_track.json" \
        --training-command "bash scripts/paper_protocol.sh $experiment $on_track" \
        --label "$label, trained on the $track track, not retrained"
    hupbench leaderboard
    exit 0
fi
cp "$run_dir/metrics.jsonl" "leaderboard/logs/$run_name.jsonl"
hupbench export "$run_dir/checkpoints/last.pt" --out "$run_dir/$run_name.onnx" --dataset "$dataset"
hupbench eval "$run_dir/checkpoints/last.pt" "$dataset" --split test --run-name "$run_name" \
    --out "leaderboard/results/$run_name.json" --depth-sensor "$sensor" \
    --training-command "bash scripts/paper_protocol.sh $experiment" --training-log "logs/$run_name.jsonl" \
    ${label:+--label "$label"}
hupbench leaderboard
