#!/usr/bin/env bash
# Create .venv with latentune and its pinned dependencies (CPU only). Usage: bash scripts/setup.sh [VENV]
set -euo pipefail
cd "$(dirname "$0")/.."
VENV=${1:-.venv}
PY=${PYTHON:-python3}
[ -x "$VENV/bin/python" ] || "$PY" -m venv "$VENV"
"$VENV/bin/python" -m pip install -q --upgrade pip
# torch first and pinned, so nothing else can pull a CUDA build
"$VENV/bin/python" -m pip install -q "torch==2.13.0"
"$VENV/bin/python" -m pip install -q -e ".[test,ray,examples,optuna]" daqp "torch==2.13.0"
# crocoddyl without its deps (they would downgrade example-robot-data); pin 4.0.0 comes from the extra
"$VENV/bin/python" -m pip install -q --no-deps "crocoddyl==3.2.1" "libcrocoddyl==3.2.1"
"$VENV/bin/python" - <<'PY'
import torch, botorch, pybullet_data, pinocchio, daqp, osqp, cma
import optuna, optuna_dashboard, cmaes, selenium  # the optuna extra (tests/test_optuna.py, test_dashboard.py)
assert torch.__version__.startswith("2.13.0"), torch.__version__
try:
    import crocoddyl  # noqa: F401
    print("crocoddyl", crocoddyl.__version__)
except ImportError as exc:
    print("warning: crocoddyl unavailable:", exc)
print("latentune environment ready: torch", torch.__version__, "botorch", botorch.__version__)
PY
