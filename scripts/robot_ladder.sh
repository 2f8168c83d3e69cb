#!/usr/bin/env bash
# The transfer issue's ladder on the robots (benchmarks/robot_transfer.py), from the four
# paper-budget sources (results/paper10k, 10,000 phase-1 + 220 phase-3 trials each), into
# runs/robot_ladder. Resumable: every (rung, seed, method) is one JSON, skipped when it exists.
#   bash scripts/robot_ladder.sh [WORKERS]
# Pass 1 screens every rung with the default phase 3, the zero-shot θ and TuRBO-m from the
# source's best (the best peer on most robot rungs so far) over seeds 0-2; pass 2 adds every
# peer and the paper's phase 3 and hand-over over seeds 0-4 (the rows shared with
# `latentune paper` were imported first: `robot_transfer import-paper`).
set -uo pipefail
cd "$(dirname "$0")/.."
W=${1:-1}
PY=.venv/bin/python
export OMP_NUM_THREADS=1
RT="$PY -m benchmarks.robot_transfer"
$RT run --robots a1 solo12 --paper results/paper10k --root runs/robot_ladder --workers "$W" \
    --methods transfer zero_shot turbo_source --seeds 0 1 2
$RT run --robots a1 solo12 --paper results/paper10k --root runs/robot_ladder --workers "$W" \
    --methods transfer zero_shot turbo_source turbo_manual cma_source cma_source_trials tpe plain \
    handover --seeds 0 1 2 3 4
