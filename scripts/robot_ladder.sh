#!/usr/bin/env bash
# The transfer issue's ladder on the robots (benchmarks/robot_transfer.py), from the four
# paper-budget sources (results/paper10k, 10,000 phase-1 + 220 phase-3 trials each), into
# runs/robot_ladder. Resumable: every (rung, seed, method) is one JSON, skipped when it exists.
#   bash scripts/robot_ladder.sh [WORKERS] [--reverse]
# Pass 1 screened every rung with the default phase 3, the zero-shot θ and TuRBO-m from the
# source's best over seeds 0-2. Pass 2 runs the default and every peer over seeds 0-4, then the
# paper's phase 3 and hand-over (reported beside the peers, not peers). A1 trot in MuJoCo is
# dropped from pass 2 after seeds 0-1: every method stayed within 0.2 % of the zero-shot θ
# (results/robot_transfer/ladder10220/README.md). Jobs go seed by seed. `--reverse` takes the
# rungs of each seed last first: a second process on the same root then meets the first once per
# seed, and every seed is complete before the next starts (the rows shared with `latentune paper`
# were imported first: `robot_transfer import-paper`).
set -uo pipefail
cd "$(dirname "$0")/.."
W=${1:-1}
REV=${2:-}
PY=.venv/bin/python
export OMP_NUM_THREADS=1
RT="$PY -m benchmarks.robot_transfer"
$RT run --robots a1 solo12 --paper results/paper10k --root runs/robot_ladder --workers "$W" \
    --methods transfer zero_shot turbo_source --seeds 0 1 2 $REV
RUNGS=$($RT list | awk '{print $1}' | grep -v '^a1-trot-mujoco$')
if [ "$REV" = "--reverse" ]; then RUNGS=$(echo "$RUNGS" | tac); fi
# shellcheck disable=SC2086
$RT run --robots a1 solo12 --targets $RUNGS --paper results/paper10k --root runs/robot_ladder \
    --workers "$W" --methods transfer zero_shot turbo_source turbo_manual cma_source \
    cma_source_trials tpe --seeds 0 1 2 3 4
# shellcheck disable=SC2086
$RT run --robots a1 solo12 --targets $RUNGS --paper results/paper10k --root runs/robot_ladder \
    --workers "$W" --methods plain handover --seeds 0 1 2 3 4
