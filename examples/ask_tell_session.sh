#!/usr/bin/env bash
# An ask/tell session scripted the way a person at a robot runs it: latentune suggests a θ,
# the person runs the trial on the robot and types in what happened.
#
#   bash examples/ask_tell_session.sh [ROOT] [TRIALS]
#   (from anywhere; ROOT defaults to runs/examples/asktell, TRIALS to 6 per session)
#
# Here the "robot" is the perturbed Hopper of examples/gym_controller.py (make_real_system) and
# the "person" is a Python one-liner that reads the suggestion's JSON file and runs one episode.
# Part 1 tunes the full θ (phase 1) on the robot; part 2 learns a latent space on the model
# (phases 1 + 2, cheap) and tunes in it on the robot (ask --phase 3 --vae MODEL_RUN).
# Every command is its own short process: stop the script any time and run it again, the
# studies resume (a pending suggestion is handed out again until it is told).
# Needs gymnasium[mujoco]. LATENTUNE and PYTHON choose the executables (default: the
# repository's .venv if it has one, else latentune and python3 on the PATH).
set -euo pipefail
ROOT=${1:-}
[ -n "$ROOT" ] && ROOT=$(realpath -m "$ROOT")       # relative to where it was started
cd "$(dirname "$0")/.."                            # the repository root: examples.* imports
ROOT=${ROOT:-runs/examples/asktell}
TRIALS=${2:-6}
if ! [[ $TRIALS =~ ^[0-9]+$ ]] || (( 10#$TRIALS < 1 )); then   # before any trial or store
  echo "ask_tell_session.sh: error: TRIALS must be a whole number >= 1, got '$TRIALS'" >&2
  exit 2
fi
if [ -x .venv/bin/latentune ]; then LT=${LATENTUNE:-.venv/bin/latentune}; PY=${PYTHON:-.venv/bin/python}
else LT=${LATENTUNE:-latentune}; PY=${PYTHON:-python3}; fi
ROBOT=examples.gym_controller:make_real_system
MODEL=examples.gym_controller:make_system

# The person at the robot: run the trial of a suggestion file, print "COST FAILED(0/1)".
run_trial() {
  "$PY" -c 'import json, sys; from examples.gym_controller import make_real_system as robot
r = robot(); o = r.evaluate(r.space.parse(json.load(open(sys.argv[1]))))
print(f"{o.cost:.6f} {int(o.failed)}")' "$1"
}

# One session: TRIALS times ask -> run the trial -> tell; then status.
session() {   # DIR ASK_FLAGS...
  local dir=$1; shift
  for _ in $(seq "$TRIALS"); do
    # "<id>\tphase <p>\t<file>\t<first values>"; the file holds every weight by name
    IFS=$'\t' read -r id _ file _ < <("$LT" ask "$dir" --system "$ROBOT" "$@")
    echo "suggestion $id: $file"
    read -r cost failed < <(run_trial "$file")
    if [ "$failed" = 1 ]; then
      "$LT" tell "$dir" "$id" --cost "$cost" --failed --note "fell"
    else
      "$LT" tell "$dir" "$id" --cost "$cost"
    fi
  done
  "$LT" status "$dir"
}

echo "== part 1: phase 1 (the full θ) on the robot, in $ROOT/robot-phase1"
session "$ROOT/robot-phase1"

echo "== part 2: phases 1 + 2 on the model ($ROOT/model), then phase 3 on the robot"
if [ ! -f "$ROOT/model/vae.json" ]; then
  resume=(); [ -f "$ROOT/model/run.db" ] && resume=(--resume)
  "$LT" phase1 --system "$MODEL" --out "$ROOT/model" --phase1-evals 120 --workers 1 \
    --backend serial --quiet "${resume[@]}"
  "$LT" train-vae --system "$MODEL" --out "$ROOT/model" --latent-dim 5 --quiet
fi
session "$ROOT/robot-phase3" --phase 3 --vae "$ROOT/model"
