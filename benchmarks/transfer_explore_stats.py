"""Where the transfer critic's explore asks help on the transfer ladder's stored runs.

    python -m benchmarks.transfer_explore_stats --root runs/transfer --methods transfer ...
        [--seeds 0 1 2] [--out F.json] [--md F.md]

For every target (``ROOT/<system>/gap<g>``) and method whose runs carry the transfer critic's
decision records, the trials are split by the ask that made them (the decision's ``n_told`` is
the index of its first trial; trial 0, the zero-shot trial, belongs to no ask): ``design`` (the
elite pool's initial design), ``explore`` (an ``explore_every`` ask) and ``region`` (every other
ask: the trust region's pools, the manual θ after falls). Per kind, summed over the seeds that
ran every listed method: trials, falls, and *records*, the trials that did not fall and beat
every earlier standing trial (zero-shot included; the first standing trial of a run is a record).
``final best by explore``: seeds whose lowest standing cost is an explore trial's.
``explore asks by pool``: per pool the explore asks drew from (the decision's ``explore_pool``:
``latent``, ``lines``, …), ``asks (with a record)``, summed over the seeds.
``agreement``: the median over the seeds of each run's median agreement (the posterior mean of
the source model's weight ``a``) over its asks after the initial design (``None`` when no such
ask recorded one).
"""
from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.common import Provenance, bench_parser, error_line
from benchmarks.transfer_curves import finish_ladder, ladder_args, targets

KINDS = ("design", "explore", "region")


def ask_kinds(run: dict[str, Any]) -> list[str | None]:
    """(n,) the kind of ask (``KINDS``) that made each trial of ``run``; ``None`` for trials no
    decision record covers (the zero-shot trial)."""
    kinds: list[str | None] = [None] * len(run["costs"])
    for d in run.get("decisions", []):
        kind = "design" if d.get("design") else "explore" if d.get("explore") else "region"
        for j in range(len(d["pools"])):
            if d["n_told"] + j < len(kinds):
                kinds[d["n_told"] + j] = kind
    return kinds


def run_stats(run: dict[str, Any]) -> dict[str, Any]:
    """Per kind of ask: ``trials``, ``falls``, ``records`` (counts in one run);
    ``final_kind``: the kind of the run's lowest standing trial (``None``: zero-shot or none);
    ``agreement``: the median agreement of its asks after the initial design (or ``None``)."""
    kinds = ask_kinds(run)
    out: dict[str, Any] = {k: {"trials": 0, "falls": 0, "records": 0} for k in KINDS}
    best, final_kind = np.inf, None
    is_record = []
    for kind, c, fell in zip(kinds, run["costs"], run["failed"]):
        record = not fell and c is not None and c < best
        is_record.append(record)
        if record:
            best, final_kind = c, kind
        if kind is None:
            continue
        out[kind]["trials"] += 1
        out[kind]["falls"] += int(bool(fell))
        out[kind]["records"] += int(record)
    out["final_kind"] = final_kind
    pools: dict[str, list[int]] = {}
    for d in run.get("decisions", []):
        if d.get("explore") and not d.get("design"):
            got = pools.setdefault(str(d.get("explore_pool") or "latent"), [0, 0])
            got[0] += 1
            got[1] += int(any(is_record[d["n_told"]:d["n_told"] + len(d["pools"])]))
    out["pools"] = pools
    agree = [d["agreement"] for d in run.get("decisions", [])
             if not d.get("design") and d.get("agreement") is not None]
    out["agreement"] = float(np.median(agree)) if agree else None
    return out


def explore_stats(root: Path, methods: list[str], seeds: list[int] | None
                  ) -> list[dict[str, Any]]:
    """One row per (target, method) with decision records: per kind of ask, trials, falls and
    records summed over the seeds that ran every method, and the seeds whose final best is an
    explore trial."""
    rows: list[dict[str, Any]] = []
    for tdir, use in targets(root, methods, seeds):
        for m in methods:
            runs = [json.loads((tdir / f"seed{s}" / f"{m}.json").read_text()) for s in use]
            if not any(r.get("decisions") for r in runs):
                continue
            st = [run_stats(r) for r in runs]
            row: dict[str, Any] = {"target": f"{tdir.parent.name} {tdir.name}",
                                   "seeds": len(use), "method": m}
            for k in KINDS:
                for q in ("trials", "falls", "records"):
                    row[f"{k} {q}"] = sum(s[k][q] for s in st)
            row["final best by explore"] = sum(s["final_kind"] == "explore" for s in st)
            by_pool: dict[str, list[int]] = {}
            for s in st:
                for pool, (n, r) in s["pools"].items():
                    got = by_pool.setdefault(pool, [0, 0])
                    got[0], got[1] = got[0] + n, got[1] + r
            row["explore asks by pool"] = ", ".join(
                f"{pool} {n} ({r})" for pool, (n, r) in sorted(by_pool.items())) or None
            agree = [s["agreement"] for s in st if s["agreement"] is not None]
            row["agreement"] = round(float(np.median(agree)), 3) if agree else None
            rows.append(row)
    return rows


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    prov = Provenance(argv, "benchmarks.transfer_explore_stats")
    ap = bench_parser("benchmarks.transfer_explore_stats", description=__doc__.splitlines()[0])
    ladder_args(ap)
    a = ap.parse_args(argv)
    try:
        rows = explore_stats(Path(a.root), a.methods, a.seeds)
    except ValueError as e:
        error_line("benchmarks.transfer_explore_stats", e)
        return 2
    finish_ladder(a, prov, {}, rows)
    return 0


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.transfer_explore_stats"))
