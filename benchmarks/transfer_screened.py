"""The bar of CMA-ES screened by the default's fall model (``results/transfer/screened_cma/bar.md``).

    python -m benchmarks.transfer_screened --summary results/transfer/screened_cma/summary.json \
        --out results/transfer/screened_cma/bar_result.json

Reads a ``benchmarks.transfer summary`` that holds the peers, the default and the methods
``cma_source_screened`` / ``cma_source_trials_screened`` (:data:`benchmarks.transfer.SCREENED`).
For every target whose best peer is a CMA-ES (``cma_source`` or ``cma_source_trials``) it sets the
screened twin of that peer beside it: median best, the ratio of the two medians, median falls
and the falls summed over the seeds, and the twin stopped at criterion (3)'s fall allowance.
Then the bar's three parts: (1) the twin's falls summed over those targets at most half the
peer's; (2) its median within 5 % of the peer's on at least all but two of them; (3) on the
targets named with ``--losses`` (where the default loses), no worse than the best peer with
at most a quarter of its falls (the whole run, and stopped at the allowance). With ``--runs``
(the run tree) it also counts, per target and screened method, the trials after the first
whose sample the screen admitted and those it did not (after :data:`SCREEN_DRAWS
<benchmarks.transfer.SCREEN_DRAWS>` draws, the least likely to fall ran), and how many of each
fell. Bad input is one line on stderr and exit 2."""
from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

from benchmarks.common import error_line

CMA_PEERS = ("cma_source", "cma_source_trials")


def bar(summary: dict[str, Any], losses: list[str]) -> dict[str, Any]:
    """The bar's rows and verdicts from a summary (module docstring). ValueError when no target
    has a CMA-ES as best peer with its screened twin read."""
    rows = []
    for t in summary["targets"]:
        m, bp = t["methods"], t["best_peer"]
        twin = f"{bp}_screened"
        if bp not in CMA_PEERS or twin not in m:
            continue
        p, s = m[bp], m[twin]
        rows.append({"target": f"{t['system']} {t['gap']:g}", "peer": bp,
                     "peer_median": p["median_best"], "twin_median": s["median_best"],
                     "ratio": s["median_best"] / p["median_best"],
                     "peer_falls": p["falls_median"], "twin_falls": s["falls_median"],
                     "peer_falls_sum": sum(p["falls"]), "twin_falls_sum": sum(s["falls"]),
                     "twin_within_allowance": s["median_best_within_allowance"],
                     "allowance": t["fall_allowance"],
                     "twin_no_worse_within_allowance": twin in t["within_allowance"],
                     "default_median": m["transfer"]["median_best"] if "transfer" in m else None,
                     "default_falls": m["transfer"]["falls_median"] if "transfer" in m else None})
    if not rows:
        raise ValueError("no target with a CMA-ES best peer and its screened twin in the summary")
    falls = sum(r["twin_falls_sum"] for r in rows) / max(1, sum(r["peer_falls_sum"] for r in rows))
    close = sum(r["ratio"] <= 1.05 for r in rows)
    named = [r for r in rows if r["target"] in losses]
    return {"rows": rows, "falls_ratio": falls, "bar1_falls_half": falls <= 0.5,
            "within_5pct": close, "bar2_close": close >= len(rows) - 2,
            "bar3": {r["target"]: {"whole_run_quarter_falls": r["twin_falls"] <= r["allowance"],
                                   "ratio": r["ratio"],
                                   "no_worse_within_allowance":
                                       r["twin_no_worse_within_allowance"],
                                   "median_within_allowance": r["twin_within_allowance"]}
                     for r in named}}


def forced(root: Path) -> dict[str, dict[str, int]]:
    """Per ``"system gap method"``: trials after the first that ran an admitted sample and that
    ran a forced one (no draw admitted), and the falls of each, over every stored screened run
    under ``root`` (``SYSTEM/gapG/seedS/METHOD.json``)."""
    from benchmarks.transfer import SCREEN_DRAWS

    out: dict[str, dict[str, int]] = {}
    for f in sorted(root.glob("*/gap*/seed*/*screened*.json")):
        r = json.loads(f.read_text())
        if "draws" not in r:
            continue
        key = f"{r['system']} {float(r['gap']):g} {r['method']}"
        c = out.setdefault(key, {"admitted": 0, "admitted_fell": 0, "forced": 0, "forced_fell": 0})
        for d, fell in list(zip(r["draws"], r["failed"]))[1:]:
            kind = "forced" if d >= SCREEN_DRAWS else "admitted"
            c[kind] += 1
            c[f"{kind}_fell"] += int(fell)
    return out


def main(argv: list[str] | None = None) -> int:
    from benchmarks.common import bench_parser, out_file, write_text
    ap = bench_parser("benchmarks.transfer_screened", description=__doc__.splitlines()[0])
    ap.add_argument("--summary", required=True)
    ap.add_argument("--losses", nargs="*", default=["vehicle 2", "cartpole 2"])
    ap.add_argument("--runs", default=None, help="the run tree: count forced and admitted trials")
    ap.add_argument("--out", type=out_file, default=None, metavar="FILE.json")
    a = ap.parse_args(sys.argv[1:] if argv is None else argv)
    try:
        res = bar(json.loads(Path(a.summary).read_text()), a.losses)
        if a.runs is not None:
            if not Path(a.runs).is_dir():
                raise ValueError(f"no run tree at {a.runs}")
            res["forced"] = forced(Path(a.runs))
    except (OSError, ValueError, KeyError) as e:
        error_line("benchmarks.transfer_screened", e)
        return 2
    for r in res["rows"]:
        print(f"{r['target']:13s} {r['peer']:17s} {r['peer_median']:.4g} / {r['peer_falls']:g}  "
              f"screened {r['twin_median']:.4g} / {r['twin_falls']:g} (×{r['ratio']:.3f}), "
              f"stopped at {r['allowance']} falls {r['twin_within_allowance']:.4g}")
    print(f"falls summed: ×{res['falls_ratio']:.3f} (bar 1, ≤ 0.5: {res['bar1_falls_half']}); "
          f"median within 5 %: {res['within_5pct']} of {len(res['rows'])} (bar 2: "
          f"{res['bar2_close']}); bar 3: {json.dumps(res['bar3'])}")
    for k, c in res.get("forced", {}).items():
        print(f"{k}: admitted {c['admitted']} (fell {c['admitted_fell']}), forced "
              f"{c['forced']} (fell {c['forced_fell']})")
    if a.out:
        write_text(a.out, json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.transfer_screened"))
