#!/usr/bin/env bash
# The evidence issue's phase-1 sources at the paper's budget (10,000 evaluations each, seed 0),
# in the layout `latentune paper --scale 1.0` resumes: A1 trot, A1 jump, A1's preservation run,
# then Solo12 trot and jump. Resumable: run it again after a stop and it continues where it was.
# Usage: bash scripts/paper_sources.sh [WORKERS]   (stores under results/paper10k/{a1,solo12})
set -uo pipefail
cd "$(dirname "$0")/.."
W=${1:-2}
LT=.venv/bin/latentune
$LT paper --robot a1 --scale 1.0 --out results/paper10k/a1 --workers "$W" --sources-only --quiet
$LT paper --robot solo12 --scale 1.0 --out results/paper10k/solo12 --workers "$W" --sources-only --quiet
