"""Does phase 3 depend on the order in which a parallel phase 1 stored its rows?

    python -m benchmarks.phase3_order --run DIR [--trials 8] [--work DIR] [--out F.json]

A parallel phase 1 numbers the rows of a batch in the order its workers finish
(:mod:`latentune.pipeline.phases`), so two runs of the same command on two machines can hold the
same trials in other orders. This benchmark takes a finished run ``DIR`` with phase 1, a latent
space and a phase 3 (e.g. the README's ``latentune tune`` output), and makes two copies under
``--work``:

* ``stored``: phase 1 as it is;
* ``swapped``: the rows of every phase-1 batch (the trials told together: same tag) stored in
  reverse order, as workers finishing in the other order would have stored them.

From both copies it removes phase 3 (its rows, its critic state and its batch record) and runs
``--trials`` phase-3 evaluations again with the run's own options and seed, one worker (so the
new phase-3 rows are in ask order), and reports whether the two asked the same θ and saw the
same costs. Exit status 1 when they differ. The run ``DIR`` itself is never written.
"""
from __future__ import annotations

import argparse
import shutil
import sqlite3
import sys
from pathlib import Path
from typing import Any

import numpy as np

from latentune.pipeline.store import read_uri

from benchmarks.common import (Provenance, add_out_arg, bench_parser, error_line, finish,
                               out_dir)


def _reverse_batches(db: Path) -> int:
    """Store every phase-1 batch's rows in reverse order (swap their idx); the rows moved."""
    con = sqlite3.connect(db)
    try:
        rows = con.execute("SELECT idx, tag FROM evaluations WHERE phase=1 ORDER BY idx").fetchall()
        batches: dict[int, list[int]] = {}
        for idx, tag in rows:
            batches.setdefault(int(tag), []).append(int(idx))
        new = {}
        for idxs in batches.values():
            for a, b in zip(idxs, reversed(idxs)):
                new[a] = b
        moved = sum(a != b for a, b in new.items())
        with con:
            con.execute("UPDATE evaluations SET idx = -1 - idx WHERE phase=1")
            for a, b in new.items():
                con.execute("UPDATE evaluations SET idx=? WHERE phase=1 AND idx=?", (b, -1 - a))
        return moved
    finally:
        con.close()


def _strip_phase3(db: Path) -> None:
    con = sqlite3.connect(db)
    try:
        with con:
            con.execute("DELETE FROM evaluations WHERE phase=3")
            con.execute("DELETE FROM trials WHERE phase=3")
            con.execute("DELETE FROM meta WHERE key IN ('critic_state_3', 'asked_batch_3')")
    finally:
        con.close()


def _copy(run: Path, dest: Path, swap: bool) -> int:
    if dest.exists():
        shutil.rmtree(dest)
    shutil.copytree(run, dest, ignore=shutil.ignore_patterns("run.lock", "*.db-wal", "*.db-shm"))
    src = sqlite3.connect(read_uri(run / 'run.db'), uri=True)
    dst = sqlite3.connect(dest / "run.db")
    try:
        src.backup(dst)                           # one consistent read of a live store
    finally:
        src.close()
        dst.close()
    moved = _reverse_batches(dest / "run.db") if swap else 0
    _strip_phase3(dest / "run.db")
    return moved


def _phase3(d: Path, trials: int) -> dict[str, Any]:
    import latentune as lt
    from latentune.constants import Phase
    from latentune.pipeline.loop import strategy_of
    from latentune.pipeline.store import RunStore
    from latentune.task import Task

    with lt.Study(d, workers=1) as st:
        cfg = st.manifest.config()
        pc = cfg["phase3"]
        system = Task.from_config(cfg["task"])
        plain = strategy_of(pc) == "plain"        # method and regions are the plain one's
        st.phase3(system, int(pc["budget"]), method=pc["method"] if plain else "turbo",
                  regions=pc.get("regions") if plain else None,
                  max_fall_prob=pc.get("max_fall_prob"), strategy=pc.get("strategy"),
                  transfer_options=pc.get("transfer_options"), max_new=trials)
    with RunStore(d) as s:
        rows = s.rows(Phase.PHASE3)
    return {"theta": [list(map(float, r.theta)) for r in rows],
            "cost": [float(r.cost) for r in rows]}


def main(argv: list[str] | None = None) -> int:
    ap = bench_parser("benchmarks.phase3_order", description=__doc__,
                      formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--run", type=Path, required=True, help="a finished run directory")
    ap.add_argument("--trials", type=int, default=8, help="phase-3 evaluations per copy")
    ap.add_argument("--work", type=out_dir, default=Path("runs/phase3_order"))
    add_out_arg(ap)
    a = ap.parse_args(argv)
    if not (a.run / "run.db").is_file():
        error_line("benchmarks.phase3_order", f"{a.run} holds no run store (run.db)")
        return 2
    con = sqlite3.connect(read_uri(a.run / 'run.db'), uri=True)
    try:
        n1 = con.execute("SELECT COUNT(*) FROM evaluations WHERE phase=1").fetchone()[0]
        cfg = con.execute("SELECT value FROM meta WHERE key='config'").fetchone()
    finally:
        con.close()
    if n1 < 2 or cfg is None or '"phase3"' not in cfg[0] or '"task"' not in cfg[0]:
        error_line("benchmarks.phase3_order", f"{a.run} is not a finished run of a task with "
                   "phase 1 and phase 3 (e.g. the README's `latentune tune` output)")
        return 2
    prov = Provenance()
    out: dict[str, Any] = {}
    for name, swap in (("stored", False), ("swapped", True)):
        moved = _copy(a.run, a.work / name, swap)
        out[name] = {"phase1_rows_moved": moved, **_phase3(a.work / name, a.trials)}
    same_theta = np.array_equal(np.array(out["stored"]["theta"]),
                                np.array(out["swapped"]["theta"]))
    same_cost = out["stored"]["cost"] == out["swapped"]["cost"]
    rows = [{"copy": k, "phase-1 rows moved": v["phase1_rows_moved"], "phase-3 trials":
             len(v["cost"]), "best cost": min(v["cost"]) if v["cost"] else None}
            for k, v in out.items()]
    res = {"run": str(a.run), "trials": a.trials, "same_theta": bool(same_theta),
           "same_cost": bool(same_cost), "copies": out}
    finish(a.out, prov, res, rows, title=f"phase 3 from {a.run}: the same θ "
           f"{'yes' if same_theta else 'NO'}, the same costs {'yes' if same_cost else 'NO'}")
    return 0 if same_theta and same_cost else 1


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.phase3_order"))
