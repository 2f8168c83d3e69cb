"""Could the target's own *local* agreement with the source system say when to trust it?
Session 48's open question, measured on the stored runs before any gated run is made.

Session 48's ``sim_pick`` (``benchmarks.transfer``'s ``sim_check=8:sim_pick=true``) runs the
critic's 8 proposals on the source system before each target trial and takes the one the target
model rates best. Against the default it ends lower on 139 of 260 (target, seed) pairs and
higher on 121: it gains where the source ranks the target's trials well (the car and the
quadrotor at their largest gaps) and loses the arm, whose payload moves the optimum. A gate
that picks only while the target's own trials near its incumbent agree with the source would
keep the gains and drop the losses, if that agreement tells the pairs apart.

This measures it. For each (target, seed) the θ of ``--a``'s run (the gated method would see
its own trials) are run on the model system (the exact source cost and fall flag,
:func:`benchmarks.transfer_simrank.source_outcomes`). At each cut t, among the first t trials,
the ``--near`` trials nearest the incumbent (the best standing trial, else the first; unit-box
Euclidean distance; the incumbent included) give Spearman's ρ of the source's and the target's
rank scores (falls last; ``local``); ``all``: the same over all t trials. The label is
whether ``--a`` ends lower than ``--b`` on that pair (``min`` of the costs within the budget,
as ``benchmarks.transfer compare``). A gate on ρ can only help if ρ separates the wins from the
losses: the table gives, per cut, the AUC of ρ for a win (0.5: no information), the wins and
losses among the pairs with ρ > 0, and per system the median ρ beside the wins / losses.

    python -m benchmarks.transfer_gate --runs results/transfer/rebuilt/runs \
        --out results/transfer/sim_check/gate.json

Bad input (an unknown system, a pair without both runs) is one line on stderr and exit 2."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks import transfer as tr
from benchmarks.common import error_line
from benchmarks.transfer_models import _spearman, emit
from benchmarks.transfer_simrank import source_outcomes
from benchmarks.transfer_walk import auc, load_trace

PICK = f"{tr.DEFAULT_METHOD}:sim_check=8:sim_pick=true"
CUTS = (10, 20)


def local_rho(X: np.ndarray, v: np.ndarray, vs: np.ndarray, f: np.ndarray, t: int,
              near: int) -> tuple[float | None, float | None]:
    """(local ρ, all ρ) at cut ``t`` (module docstring) of the target's rank scores ``v`` (n,)
    and the source's ``vs`` (n,) at θ ``X`` (n, d) with the target's fall flags ``f`` (n,)."""
    ok = np.flatnonzero(~f[:t])
    inc = int(ok[np.argmin(v[:t][ok])]) if ok.size else 0
    nn = np.argsort(np.linalg.norm(X[:t] - X[inc], axis=1), kind="stable")[:near]
    return _spearman(vs[:t][nn], v[:t][nn]), _spearman(vs[:t], v[:t])


def score(runs: Path, systems: list[str], seeds: list[int], a: str, b: str,
          near: int) -> list[dict[str, Any]]:
    """One row per (target, seed): ρ at every cut and whether ``a`` ended lower than ``b``."""
    from latentune.critic.transfer_model import rank_scores

    rows = []
    for s in systems:
        for g in tr.SYSTEMS[s]["gaps"]:
            for seed in seeds:
                ra, rb = (load_trace([runs], s, g, seed, m) for m in (a, b))
                if ra is None or rb is None:
                    raise ValueError(f"{s} gap {g:g} seed {seed}: no stored run of "
                                     f"{a if ra is None else b}")
                X = np.asarray(ra["thetas"], dtype=float)
                f = np.asarray(ra["failed"], dtype=bool)
                v = rank_scores(np.asarray(ra["costs"], dtype=float), f)
                ys, fs = source_outcomes(s, X)
                vs = rank_scores(ys, fs)
                row: dict[str, Any] = {"system": s, "gap": g, "seed": seed,
                                       "win": min(ra["costs"]) < min(rb["costs"]),
                                       "loss": min(ra["costs"]) > min(rb["costs"])}
                for t in CUTS:
                    row[f"local_{t}"], row[f"all_{t}"] = local_rho(X, v, vs, f, t, near)
                rows.append(row)
                print(f"{s} gap {g:g} seed {seed}: " + ", ".join(
                    f"{k} {row[k]:.2f}" for k in row if k[:3] in ("loc", "all")
                    and row[k] is not None), file=sys.stderr, flush=True)
    return rows


def _median(x: np.ndarray) -> str:
    return f"{np.median(x):.2f}" if len(x) else "–"


def table(rows: list[dict[str, Any]], a: str, b: str, near: int) -> list[str]:
    """The markdown: per cut and kind, the AUC of ρ for a win and the counts where ρ > 0; per
    system, the median local ρ beside the wins and losses."""
    md = [f"`{a}` against `{b}`: {len(rows)} pairs, "
          f"{sum(r['win'] for r in rows)} wins and {sum(r['loss'] for r in rows)} losses; "
          f"local = the {near} trials nearest the incumbent", "",
          "| ρ at cut | AUC of ρ for a win | median ρ, wins / losses | ρ > 0: wins / losses "
          "| ρ ≤ 0: wins / losses |", "|---|---:|---|---|---|"]
    decided = [r for r in rows if r["win"] or r["loss"]]
    for t in CUTS:
        for kind in ("local", "all"):
            k = f"{kind}_{t}"
            rr = [r for r in decided if r[k] is not None]
            rho = np.array([r[k] for r in rr])
            won = np.array([r["win"] for r in rr])
            a_ = auc(rho, won)
            pos = rho > 0
            md.append(f"| {kind}, t = {t} | {'–' if a_ is None else f'{a_:.3f}'} | "
                      f"{_median(rho[won])} / {_median(rho[~won])} | "
                      f"{int((won & pos).sum())} / {int((~won & pos).sum())} | "
                      f"{int((won & ~pos).sum())} / {int((~won & ~pos).sum())} |")
    md += ["", "| system | wins / losses | median local ρ, t = " + " / ".join(map(str, CUTS))
           + " |", "|---|---|---|"]
    for s in dict.fromkeys(r["system"] for r in rows):
        rs = [r for r in rows if r["system"] == s]
        med = [_median(np.array([r[f"local_{t}"] for r in rs if r[f"local_{t}"] is not None]))
               for t in CUTS]
        md.append(f"| {s} | {sum(r['win'] for r in rs)} / {sum(r['loss'] for r in rs)} | "
                  + " / ".join(med) + " |")
    return md


def main(argv: list[str] | None = None) -> int:
    from benchmarks.common import bench_parser, out_file
    ap = bench_parser("benchmarks.transfer_gate", description=__doc__,
                      formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", required=True, help="SYSTEM/gapG/seedS/METHOD.json traces")
    ap.add_argument("--systems", nargs="*", default=list(tr.SYSTEMS))
    ap.add_argument("--seeds", nargs="*", type=int, default=list(range(10)))
    ap.add_argument("--a", default=PICK, help="the method a gate would act in")
    ap.add_argument("--b", default=tr.DEFAULT_METHOD, help="the method it is judged against")
    ap.add_argument("--near", type=int, default=10)
    ap.add_argument("--out", type=out_file, default=None, metavar="FILE.json")
    args = ap.parse_args(argv)
    try:
        bad = [s for s in args.systems if s not in tr.SYSTEMS]
        if bad:
            raise ValueError(f"unknown system {bad[0]!r} (known: {', '.join(tr.SYSTEMS)})")
        if args.near < 3:
            raise ValueError(f"--near must be at least 3, got {args.near}")
        if not Path(args.runs).is_dir():
            raise ValueError(f"--runs {args.runs}: no such directory")
        rows = score(Path(args.runs), args.systems, args.seeds, args.a, args.b, args.near)
    except ValueError as e:
        error_line("benchmarks.transfer_gate", e)
        return 2
    emit(rows, table(rows, args.a, args.b, args.near), args.out, with_md=True)
    return 0


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.transfer_gate"))
