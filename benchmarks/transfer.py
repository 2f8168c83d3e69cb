"""Cross-task / cross-robot transfer of a latent space: ``phase3 --vae RUN_DIR`` elsewhere.

    python benchmarks/transfer.py RUN_DIR [--targets a1:jump b1:trot b1:jump] [--evals 220]
        [--workers 2] [--seed 0] [--out-root DIR]

RUN_DIR holds the VAE (e.g. ``latentune tune --robot a1 --task trot --out RUN_DIR``). For each
target robot:gait, runs ``latentune phase3 --vae RUN_DIR`` in ``OUT_ROOT/<robot>_<gait>`` and
prints the manual cost, the phase-3 best cost and whether it is stable (< C1 = 100).
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from latentune.pipeline.store import RunStore
from latentune.task import C1


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run_dir")
    ap.add_argument("--targets", nargs="+", default=["a1:jump", "b1:trot", "b1:jump"])
    ap.add_argument("--evals", type=int, default=220)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out-root", default=None)
    a = ap.parse_args()
    root = Path(a.out_root or tempfile.mkdtemp(prefix="lt_transfer_"))
    rows = []
    for t in a.targets:
        robot, gait = t.split(":")
        out = root / f"{robot}_{gait}"
        t0 = time.perf_counter()
        p = subprocess.run([sys.executable, "-m", "latentune.cli", "phase3", "--robot", robot,
                            "--task", gait, "--vae", a.run_dir, "--out", str(out),
                            "--phase3-evals", str(a.evals), "--workers", str(a.workers),
                            "--seed", str(a.seed), "--quiet"] + (["--resume"] if (out / "run.db").exists() else []),
                           capture_output=True, text=True)
        if p.returncode != 0:
            print(f"{t}: failed: {p.stderr.strip()}")
            continue
        s = json.loads((out / "summary.json").read_text())
        with RunStore(out) as st:
            n_stable = int((st.costs(3) < C1).sum())
        r = {"target": t, "manual": s["manual_cost"], "phase3_best": s["phase3_best"],
             "evals": s["phase3_evals"], "evals_to_manual": s["phase3_evals_to_beat_manual"],
             "stable": s["phase3_best"] < C1, "n_stable": n_stable, "wall_s": time.perf_counter() - t0}
        rows.append(r)
        print(json.dumps(r), flush=True)
    print(f"\nVAE of {a.run_dir}; stores in {root}")
    print("| target | manual | phase 3 best | evals | stable evals | evals to reach manual |")
    print("|---|---:|---:|---:|---:|---:|")
    for r in rows:
        print(f"| {r['target']} | {r['manual']:.3f} | {r['phase3_best']:.3f} | {r['evals']} | "
              f"{r['n_stable']}/{r['evals']} | {r['evals_to_manual']} |")


if __name__ == "__main__":
    main()
