"""Does the agreement the default phase 3 measures tell when a target-only GP beats it?

The transfer critic models the target's cost ranks as ``a · source model + b + residual`` and
records, at every ask, the posterior mean of ``a`` (its decision's ``agreement``). This reads,
for each (target, seed) with both runs stored, the default's agreement at ``--cuts`` told trials
(the decision whose ``n_told`` is the cut) and whether GPSampler (``gp``, a GP on the target's
trials alone) ended with a strictly lower best cost within the budget. It gives, per set of
runs: the AUC of a low agreement for a GPSampler win (0.5: no information), the pairs and wins,
and the threshold a* (the highest agreement at or below which GPSampler wins more than half of
the pairs) chosen on the first set and applied to the others: how many pairs it picks, the
share of them GPSampler wins, and the share of all GPSampler wins it holds. Per target: the
median agreement at each cut beside GPSampler's wins. ``results/transfer/agreement/README.md``
states the bar this answers, written before it ran.

    python -m benchmarks.transfer_agreement --runs results/transfer/rebuilt/runs \
        results/transfer/fresh/runs --out results/transfer/agreement/agreement.json

(the tables also go to ``agreement.md`` beside ``--out``).

Bad input (a ``--runs`` directory that is not there, no pair with both runs) is one line on
stderr and exit 2."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks import transfer as tr
from benchmarks.common import bench_parser, error_line, out_file
from benchmarks.transfer_models import emit
from benchmarks.transfer_walk import auc, load_trace

PEER = "gp"
CUTS = (10, 20)


def agreement_at(decisions: list[dict[str, Any]], cut: int) -> float | None:
    """The agreement of the decision asked with ``cut`` trials told (its ``n_told``), or None
    when the run holds no such decision (it ended, or recorded none)."""
    for d in decisions:
        if d.get("n_told") == cut and d.get("agreement") is not None:
            return float(d["agreement"])
    return None


def targets(root: Path) -> list[tuple[str, float]]:
    """Every (system, gap) with a run directory under ``root``, in name order."""
    out = []
    for sysdir in sorted(p for p in root.iterdir() if p.is_dir()):
        for gapdir in sorted(p for p in sysdir.iterdir() if p.is_dir() and p.name.startswith("gap")):
            out.append((sysdir.name, float(gapdir.name[3:])))
    return out


def pairs(root: Path, method: str, cuts: tuple[int, ...]) -> list[dict[str, Any]]:
    """One row per (target, seed) under ``root`` with both ``method``'s and GPSampler's trace:
    the agreement at each cut, both best costs within the budget and the label."""
    rows = []
    for system, gap in targets(root):
        gapdir = root / system / f"gap{gap:g}"
        for seeddir in sorted(gapdir.glob("seed*"), key=lambda p: int(p.name[4:])):
            seed = int(seeddir.name[4:])
            a = load_trace([root], system, gap, seed, method)
            b = load_trace([root], system, gap, seed, PEER)
            if a is None or b is None:
                continue
            best_a = float(np.min(np.asarray(a["costs"], float)[: int(a["budget"])]))
            best_b = float(np.min(np.asarray(b["costs"], float)[: int(b["budget"])]))
            rows.append({"system": system, "gap": gap, "seed": seed, "best": best_a,
                         "peer_best": best_b, "peer_wins": bool(best_b < best_a),
                         "agreement": {str(c): agreement_at(a.get("decisions") or [], c)
                                       for c in cuts}})
    return rows


def threshold(ag: np.ndarray, won: np.ndarray) -> float | None:
    """The highest agreement τ such that the peer wins more than half of the pairs whose
    agreement is ≤ τ; None when there is none."""
    best = None
    for tau in np.unique(ag):
        sel = ag <= tau
        if won[sel].mean() > 0.5:
            best = float(tau)
    return best


def cut_stats(rows: list[dict[str, Any]], cut: int, tau: float | None) -> dict[str, Any]:
    """AUC of −agreement for a peer win at ``cut``, the pairs and wins, and what the threshold
    ``tau`` picks among ``rows``."""
    have = [r for r in rows if r["agreement"][str(cut)] is not None]
    ag = np.array([r["agreement"][str(cut)] for r in have], float)
    won = np.array([r["peer_wins"] for r in have], bool)
    out: dict[str, Any] = {"pairs": len(have), "peer_wins": int(won.sum()),
                           "auc": auc(-ag, won) if len(have) else None,
                           "median_agreement_wins": float(np.median(ag[won])) if won.any() else None,
                           "median_agreement_losses": (float(np.median(ag[~won]))
                                                       if (~won).any() else None)}
    if tau is not None and len(have):
        sel = ag <= tau
        out.update(tau=tau, picked=int(sel.sum()), picked_wins=int(won[sel].sum()),
                   picked_win_share=float(won[sel].mean()) if sel.any() else None,
                   wins_held=float(won[sel].sum() / won.sum()) if won.any() else None)
    return out


def per_target(rows: list[dict[str, Any]], cuts: tuple[int, ...]) -> list[dict[str, Any]]:
    """Per (system, gap): seeds, GPSampler's wins and the median agreement at each cut."""
    out = []
    for key in sorted({(r["system"], r["gap"]) for r in rows}):
        rs = [r for r in rows if (r["system"], r["gap"]) == key]
        med = {}
        for c in cuts:
            v = [r["agreement"][str(c)] for r in rs if r["agreement"][str(c)] is not None]
            med[str(c)] = float(np.median(v)) if v else None
        out.append({"system": key[0], "gap": key[1], "seeds": len(rs),
                    "peer_wins": sum(r["peer_wins"] for r in rs), "median_agreement": med})
    return out


def markdown(result: dict[str, Any]) -> str:
    """The tables of ``result`` (:func:`main`'s JSON) as Markdown."""
    cuts = result["cuts"]
    lines = ["| runs | cut | pairs | GPSampler wins | AUC | median agreement: wins / losses "
             "| a* | picked | GPSampler wins among them | share of its wins held |",
             "|---|---:|---:|---:|---:|---|---:|---:|---:|---:|"]
    f = (lambda x, p=3: "–" if x is None else f"{x:.{p}f}")
    for s in result["sets"]:
        for c in cuts:
            st = s["cuts"][str(c)]
            lines.append(f"| {s['runs']} | {c} | {st['pairs']} | {st['peer_wins']} | {f(st['auc'])} "
                         f"| {f(st['median_agreement_wins'], 2)} / {f(st['median_agreement_losses'], 2)} "
                         f"| {f(st.get('tau'), 2)} | {st.get('picked', '–')} "
                         f"| {f(st.get('picked_win_share'), 2)} | {f(st.get('wins_held'), 2)} |")
    lines += ["", "| runs | target | seeds | GPSampler wins | median agreement at "
              + " / ".join(map(str, cuts)) + " |", "|---|---|---:|---:|---|"]
    for s in result["sets"]:
        for t in s["targets"]:
            lines.append(f"| {s['runs']} | {t['system']} {t['gap']:g} | {t['seeds']} | "
                         f"{t['peer_wins']} | "
                         + " / ".join(f(t["median_agreement"][str(c)], 2) for c in cuts) + " |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = bench_parser("benchmarks.transfer_agreement", description=__doc__,
                      formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=Path, nargs="+", required=True,
                    help="trace roots (SYSTEM/gapG/seedS/METHOD.json); a* is chosen on the first")
    ap.add_argument("--method", default=tr.DEFAULT_METHOD,
                    help="the phase 3 whose agreement is read")
    ap.add_argument("--cuts", type=int, nargs="+", default=list(CUTS), help="told trials")
    ap.add_argument("--out", type=out_file, default=None, metavar="FILE.json")
    args = ap.parse_args(argv)
    cuts = tuple(args.cuts)
    try:
        for root in args.runs:
            if not root.is_dir():
                raise ValueError(f"--runs {root}: no such directory")
        sets = [(root, pairs(root, args.method, cuts)) for root in args.runs]
        if not any(rows for _, rows in sets):
            raise ValueError(f"no (target, seed) under --runs holds both {args.method} and {PEER}")
    except ValueError as e:
        error_line("benchmarks.transfer_agreement", e)
        return 2
    taus = {}
    for c in cuts:
        first = [r for r in sets[0][1] if r["agreement"][str(c)] is not None]
        taus[c] = threshold(np.array([r["agreement"][str(c)] for r in first], float),
                            np.array([r["peer_wins"] for r in first], bool)) if first else None
    result = {"method": args.method, "peer": PEER, "cuts": list(cuts),
              "sets": [{"runs": str(root), "cuts": {str(c): cut_stats(rows, c, taus[c]) for c in cuts},
                        "targets": per_target(rows, cuts)} for root, rows in sets]}
    emit([r for _, rows in sets for r in rows] + [result], markdown(result).splitlines(),
         args.out, with_md=True)
    return 0


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.transfer_agreement"))
