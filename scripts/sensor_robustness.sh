#!/usr/bin/env bash
# How an experiment's finished model holds up under each depth camera of hupbench.core.depth_sensor, on its own
# track's test split (the same frames, each preset's noise seeded per frame: every model reads the same depth):
#   bash scripts/sensor_robustness.sh paper_hupnet_handfit_cpu [PRESET ...]   (default: none and every preset)
# The model must have been trained and evaluated by scripts/paper_protocol.sh EXPERIMENT (the table goes beside its
# row in leaderboard/results/); nothing is retrained. "none", the clean z-buffer, is evaluated again with the same
# checkpoint, so that every column of the table is one model's. Each preset's results ->
# leaderboard/robustness/<run_name>_<preset>.json (a preset already there is skipped: a killed run goes on where it
# stopped), then the leaderboard's robustness table is rebuilt. Latency is not measured again: it does not depend
# on the depth's values.
set -euo pipefail
cd "$(dirname "$0")/.."
experiment="${1:?usage: scripts/sensor_robustness.sh EXPERIMENT [PRESET ...] (EXPERIMENT a file of conf/experiment/)}"
shift
[ -f "conf/experiment/$experiment.yaml" ] || { echo "no conf/experiment/$experiment.yaml" >&2; exit 1; }
presets=("$@")
[ ${#presets[@]} -gt 0 ] || mapfile -t presets < <(python3 -c "
from hupbench.core.depth_sensor import NONE, PRESETS
print('\n'.join([NONE, *PRESETS]))")
dataset=$(python3 -c "from hupbench.config import compose; print(compose('train', ['+experiment=$experiment']).data.root)")
run_name=$(python3 -c "from hupbench.config import compose; print(compose('train', ['+experiment=$experiment']).run_name)")
checkpoint=hupbench_out/runs/$run_name/checkpoints/last.pt
[ -f "leaderboard/results/$run_name.json" ] && [ -f "hupbench_out/runs/$run_name/summary.json" ] || {
    echo "$run_name has no finished training run and leaderboard row: bash scripts/paper_protocol.sh $experiment" >&2
    exit 1; }
mkdir -p leaderboard/robustness
for preset in "${presets[@]}"; do
    out="leaderboard/robustness/${run_name}_$preset.json"
    [ -f "$out" ] && { echo "$out is there already"; continue; }
    hupbench eval "$checkpoint" "$dataset" --split test --depth-sensor "$preset" --no-latency --out "$out" \
        --training-command "bash scripts/paper_protocol.sh $experiment"
done
hupbench leaderboard
