"""What the source's own θ can reach on each target of the transfer ladder: the bound that
criterion (2) of the transfer issue (the best peer's median within B/10 trials) runs into.

    python -m benchmarks.transfer_reach [--sources runs/transfer] [--ladder F.json ...]
        [--systems arm chain hopper springs] [--seeds 0 1 ...] [--top 4 50]
        [--out F.json] [--md F.md]

For every target (system, gap) of the ladder summaries ``--ladder`` (``benchmarks.transfer
summary`` outputs: the best peer and its median best within B) and every seed whose source run
is under ``--sources`` (``<system>/seed<s>/source``), the source's trials that did not fall are
ranked by their cost on the model and the best ``max(--top)`` of them are run on the target
(one trial each, the ladder's target at that gap). Per target and k of ``--top``, over the seeds:

* ``best_of_top_k``: the median of the best cost on the target among the source's k best θ
  (the trials that did not fall on the target; ∞ when all fell);
* ``reach_top_k``: on how many seeds that best is ≤ the best peer's median;
* ``falls_top_k``: the median number of them that fall on the target.

A search that spends its first trials on θ the source tried (as the default's initial design
does: the zero-shot θ and the source's best diverse θ) reaches the best peer's median within
B/10 = 4 trials only where ``best_of_top_k`` for a k of a few is below it; where the best of
the source's 50 best is not, reaching it within B/10 needs θ the source never tried.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

from latentune.threads import one_thread_env

one_thread_env()

import numpy as np  # noqa: E402

from benchmarks.common import (Provenance, add_out_arg, bench_parser, error_line,  # noqa: E402
                               finish, markdown_table)
from benchmarks.common import out_file, write_text  # noqa: E402
from benchmarks.transfer import SYSTEMS  # noqa: E402
from latentune.system import evaluate  # noqa: E402


def best_peers(ladders: list[Path]) -> dict[tuple[str, float], tuple[str, float]]:
    """(system, gap) → (best peer, its median best within B) from ladder summaries."""
    out: dict[tuple[str, float], tuple[str, float]] = {}
    for f in ladders:
        for t in json.loads(f.read_text())["targets"]:
            peer = t["best_peer"]
            out[(t["system"], float(t["gap"]))] = (peer, float(t["methods"][peer]["median_best"]))
    return out


def top_source_theta(src: Path, k: int) -> np.ndarray:
    """(≤ k, d) the source's trials that did not fall, lowest model cost first."""
    from latentune.pipeline.baselines import source_trials

    X, y, fell = source_trials(src)
    keep = np.flatnonzero(~fell & np.isfinite(y))
    return X[keep[np.argsort(y[keep], kind="stable")[:k]]]


def reach(sources: Path, peers: dict[tuple[str, float], tuple[str, float]],
          systems: list[str], seeds: list[int], tops: list[int]) -> list[dict[str, Any]]:
    """One row per target (see the module docstring)."""
    rows: list[dict[str, Any]] = []
    kmax = max(tops)
    for system in systems:
        for gap in SYSTEMS[system]["gaps"]:
            if (system, float(gap)) not in peers:
                continue
            peer, level = peers[(system, float(gap))]
            target = SYSTEMS[system]["target"](gap)
            per_seed = []
            for s in seeds:
                src = sources / system / f"seed{s}" / "source"
                if not (src / "run.db").is_file():
                    continue
                outs = [evaluate(target, x) for x in top_source_theta(src, kmax)]
                per_seed.append((np.array([o.cost for o in outs]),
                                 np.array([o.failed for o in outs], dtype=bool)))
            if not per_seed:
                continue
            row: dict[str, Any] = {"target": f"{system} gap{gap:g}", "seeds": len(per_seed),
                                   "best peer": peer, "its median": level}
            for k in tops:
                bests = [float(np.min(np.where(f[:k], np.inf, c[:k]))) for c, f in per_seed]
                row[f"best_of_top_{k}"] = float(np.median(bests))
                row[f"reach_top_{k}"] = int(sum(b <= level for b in bests))
                row[f"falls_top_{k}"] = float(np.median([f[:k].sum() for _, f in per_seed]))
            rows.append(row)
    return rows


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    prov = Provenance(argv, "benchmarks.transfer_reach")
    ap = bench_parser("benchmarks.transfer_reach", description=__doc__.splitlines()[0])
    ap.add_argument("--sources", type=Path, default=Path("runs/transfer"))
    ap.add_argument("--ladder", type=Path, nargs="+",
                    default=[Path("results/transfer/rebuilt/ladder.json")])
    ap.add_argument("--systems", nargs="+", default=list(SYSTEMS), choices=list(SYSTEMS))
    ap.add_argument("--seeds", nargs="+", type=int, default=list(range(10)))
    ap.add_argument("--top", nargs="+", type=int, default=[4, 50])
    add_out_arg(ap)
    ap.add_argument("--md", type=out_file, default=None, metavar="FILE.md")
    a = ap.parse_args(argv)
    if min(a.top) < 1:
        error_line("benchmarks.transfer_reach", "--top takes counts ≥ 1")
        return 2
    missing = [str(f) for f in a.ladder if not f.is_file()]
    if missing:
        error_line("benchmarks.transfer_reach", f"no ladder summary {', '.join(missing)}")
        return 2
    rows = reach(a.sources, best_peers(a.ladder), a.systems, a.seeds, sorted(set(a.top)))
    if not rows:
        error_line("benchmarks.transfer_reach", f"no source run under {a.sources} for a target "
                   "of the ladder summaries")
        return 2
    finish(a.out, prov, {"sources": str(a.sources), "ladder": [str(f) for f in a.ladder],
                         "top": sorted(set(a.top))}, rows)
    if a.md is not None:
        write_text(a.md, f"`{prov.command}`\n\n{markdown_table(rows)}\n")
    return 0


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.transfer_reach"))
