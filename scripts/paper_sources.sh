#!/usr/bin/env bash
# The evidence issue's runs at the paper's budget, in the layout `latentune paper --scale 1.0`
# resumes (stores under results/paper10k/{a1,solo12}). Resumable: run it again after a stop and it
# continues where it was.
#   bash scripts/paper_sources.sh [A1_WORKERS] [SEEDS] [SOLO12_WORKERS]
# runs two jobs side by side:
#   A1: every study of `latentune paper --robot a1 --scale 1 --seeds SEEDS` (its own sources first:
#       trot and jump at 10,000 evaluations, seed 0; the preservation run last);
#   Solo12: every study of `latentune paper --robot solo12 --scale 1 --seeds SEEDS` (its sources,
#       done on 2026-12-03, first; then the seeded phase-3 rows and baselines; preservation last).
set -uo pipefail
cd "$(dirname "$0")/.."
W=${1:-2}
SEEDS=${2:-5}
WS=${3:-1}
LT=.venv/bin/latentune
export OMP_NUM_THREADS=1
$LT paper --robot a1 --scale 1.0 --out results/paper10k/a1 --workers "$W" --seeds "$SEEDS" \
    --quiet >> results/paper10k/a1.log 2>&1 &
$LT paper --robot solo12 --scale 1.0 --out results/paper10k/solo12 --workers "$WS" \
    --seeds "$SEEDS" --quiet >> results/paper10k/solo12.log 2>&1 &
wait
