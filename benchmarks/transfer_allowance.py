"""Can a run know criterion (3)'s fall allowance? The default's early falls against the best
peer's falls, per target.

    python -m benchmarks.transfer_allowance \
        --summary results/transfer/screened_cma/summary.json \
        --runs results/transfer/rebuilt/runs \
        --robot-summary results/robot_transfer/ladder10220/summary_allowance.json \
        --robot-traces results/robot_transfer/ladder10220/traces \
        --out results/transfer/screened_cma/allowance.json

Criterion (3) allows a quarter of the best peer's median falls (:func:`benchmarks.transfer.
fall_allowance`), which a run cannot see. This reads a ``benchmarks.transfer summary`` (the
cheap targets; runs under ``--runs`` as ``SYSTEM/gapG/seedS/METHOD[@avx512].json``) and,
optionally, a robot summary with its exported traces (``RUNG.json``: every run's fall flags).
For every target it takes the default's (``--default``) falls within the first quarter of its
budget (10 of 40, 25 of 100), median over seeds, beside the best peer's median falls and the
allowance. It prints Spearman's rank correlation of the two (with p), over the cheap targets,
the robots and both. The default's early falls come before most of what it spends, so a
strong correlation means a run could estimate the allowance while it runs. Bad input is one
line on stderr and exit 2."""
from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.common import error_line
from benchmarks.transfer import DEFAULT_METHOD as DEFAULT
from benchmarks.transfer_walk import load_trace, runs_by_seed



def _early(failed: list[bool]) -> int:
    """Falls within the first quarter of a run's trials."""
    return int(sum(failed[:max(1, len(failed) // 4)]))


def rows_of(summary: dict[str, Any], early: dict[tuple[str, int], int], name: str
            ) -> list[dict[str, Any]]:
    """One row per summary target: the best peer, its median falls, the allowance and the
    default's median early falls (``early``: (target, seed) → falls in the first quarter)."""
    out = []
    for t in summary["targets"]:
        key = name.format(**t)
        seeds = [s for s in t["seeds"] if (key, s) in early]
        if not seeds:
            raise ValueError(f"no stored default run for {key}")
        bp = t["best_peer"]
        out.append({"target": key, "best_peer": bp,
                    "peer_falls": t["methods"][bp]["falls_median"],
                    "allowance": t["fall_allowance"],
                    "default_early_falls": float(np.median([early[key, s] for s in seeds])),
                    "default_falls": t["methods"]["transfer"]["falls_median"]})
    return out


def cheap_early(runs: Path, summary: dict[str, Any], default: str) -> dict[tuple[str, int], int]:
    """(target, seed) → the default's early falls, from the cheap runs
    (:func:`benchmarks.transfer_walk.load_trace`: a run re-made on this machine's sources,
    ``METHOD@avx512``, is read in place of the stored one)."""
    out = {}
    for t in summary["targets"]:
        for s in t["seeds"]:
            run = load_trace([runs], t["system"], t["gap"], s, default)
            if run is not None:
                out[f"{t['system']} {t['gap']:g}", s] = _early(run["failed"])
    return out


def robot_early(traces: Path, default: str) -> dict[tuple[str, int], int]:
    """(rung, seed) → the default's early falls, from the exported robot traces (its
    ``@avx512`` run where there is one, :func:`~benchmarks.transfer_walk.runs_by_seed`)."""
    out = {}
    for f in sorted(traces.glob("*.json")):
        d = json.loads(f.read_text())
        runs = d.get("runs", []) if isinstance(d, dict) else []
        for seed, r in runs_by_seed(runs, default).items():
            out[d["target"], seed] = _early(r["failed"])
    return out


def spearman(rows: list[dict[str, Any]]) -> dict[str, float]:
    """Spearman's ρ (and p) of the default's early falls against the best peer's falls."""
    from scipy.stats import spearmanr

    if len(rows) < 3:
        return {"n": len(rows), "rho": float("nan"), "p": float("nan")}
    r = spearmanr([x["default_early_falls"] for x in rows], [x["peer_falls"] for x in rows])
    return {"n": len(rows), "rho": float(r.statistic), "p": float(r.pvalue)}


def main(argv: list[str] | None = None) -> int:
    from benchmarks.common import bench_parser, out_file, write_text
    ap = bench_parser("benchmarks.transfer_allowance", description=__doc__.splitlines()[0])
    ap.add_argument("--summary", required=True)
    ap.add_argument("--runs", required=True)
    ap.add_argument("--robot-summary", default=None)
    ap.add_argument("--robot-traces", default=None)
    ap.add_argument("--default", default=DEFAULT)
    ap.add_argument("--out", type=out_file, default=None, metavar="FILE.json")
    a = ap.parse_args(sys.argv[1:] if argv is None else argv)
    try:
        if (a.robot_summary is None) != (a.robot_traces is None):
            raise ValueError("--robot-summary and --robot-traces go together")
        s = json.loads(Path(a.summary).read_text())
        rows = rows_of(s, cheap_early(Path(a.runs), s, a.default), "{system} {gap:g}")
        robots: list[dict[str, Any]] = []
        if a.robot_summary:
            rs = json.loads(Path(a.robot_summary).read_text())
            robots = rows_of(rs, robot_early(Path(a.robot_traces), a.default),
                             "{target}")
    except (OSError, ValueError, KeyError) as e:
        error_line("benchmarks.transfer_allowance", e)
        return 2
    res = {"cheap": rows, "robots": robots, "spearman": {
        "cheap": spearman(rows), "robots": spearman(robots), "all": spearman(rows + robots)}}
    for r in rows + robots:
        print(f"{r['target']:24s} peer {r['best_peer']:17s} falls {r['peer_falls']:5g} "
              f"allowance {r['allowance']:3d}  default: early {r['default_early_falls']:4g}, "
              f"all {r['default_falls']:5g}")
    for k, v in res["spearman"].items():
        print(f"Spearman ρ ({k}, {v['n']} targets): {v['rho']:.3f} (p {v['p']:.2g})")
    if a.out:
        write_text(a.out, json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.transfer_allowance"))
