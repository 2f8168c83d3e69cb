"""Median best-so-far curves of the transfer ladder's stored runs.

    python -m benchmarks.transfer_curves --root runs/transfer --methods transfer gp ...
        [--seeds 0 1 2] [--at 1 2 4 10 20 40] [--out F.json] [--md F.md]

For every target (``ROOT/<system>/gap<g>``) and method: the best cost among the trials that did
not fall after each trial (∞ until one stands), per seed, then the median over the seeds that
ran every listed method, at the trials ``--at``. Printed as a Markdown table; ``--out`` writes the
rows with their provenance (command, commit, machine, load) as JSON, ``--md`` the table headed by
the command that made it.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.common import (Provenance, add_out_arg, bench_parser, error_line, finish,
                               markdown_table)
from benchmarks.common import out_file, write_text  # noqa: E402


def best_so_far(run: dict) -> np.ndarray:
    """(n,) best cost among the trials of ``run`` that did not fall, after each trial."""
    c = np.array([np.inf if x is None else x for x in run["costs"]], dtype=float)
    return np.minimum.accumulate(np.where(np.array(run["failed"], dtype=bool), np.inf, c))


def targets(root: Path, methods: list[str], seeds: list[int] | None
            ) -> list[tuple[Path, list[int]]]:
    """Each target directory ``ROOT/<system>/gap<g>`` with the seeds (among ``seeds``, all when
    ``None``) that ran every method of ``methods``; targets with none are skipped. ValueError
    when no target has one (an empty table would read as a result)."""
    out = []
    for tdir in sorted(root.glob("*/gap*")):
        have = [int(p.name[4:]) for p in tdir.glob("seed*")
                if all((p / f"{m}.json").is_file() for m in methods)]
        use = sorted(s for s in have if seeds is None or s in seeds)
        if use:
            out.append((tdir, use))
    if not out:
        raise ValueError(f"no target under {root} has a seed"
                         + (f" among {' '.join(map(str, seeds))}" if seeds is not None else "")
                         + f" that ran every method of {' '.join(methods)}")
    return out


def ladder_args(ap: argparse.ArgumentParser) -> None:
    """The options every table of the ladder's stored runs takes: ``--root``, ``--methods``,
    ``--seeds``, ``--out`` (JSON with provenance) and ``--md`` (the table headed by its
    command)."""
    ap.add_argument("--root", default="runs/transfer")
    ap.add_argument("--methods", nargs="+", required=True)
    ap.add_argument("--seeds", nargs="+", type=int, default=None)
    add_out_arg(ap)
    ap.add_argument("--md", type=out_file, default=None, metavar="FILE.md",
                    help="also write the table, headed by the command that made it")


def finish_ladder(a: argparse.Namespace, prov: Provenance, params: dict[str, Any],
                  rows: list[dict[str, Any]]) -> None:
    """Write a ladder table's rows: ``--out`` (JSON with ``params`` and provenance, or printed) and,
    with ``--md``, the table headed by the command that made it (:func:`ladder_args`)."""
    finish(a.out, prov, {"root": str(a.root), "methods": a.methods, **params}, rows)
    if a.md is not None:
        write_text(a.md, f"`{prov.command}`\n\n{markdown_table(rows)}\n")


def curves(root: Path, methods: list[str], seeds: list[int] | None, at: list[int]
           ) -> list[dict[str, Any]]:
    """One row per (target, method): the seeds used and the median best-so-far at each trial of
    ``at`` (key ``"trial t"``; ∞ until a trial stands) over the seeds that ran every method."""
    rows: list[dict[str, Any]] = []
    for tdir, use in targets(root, methods, seeds):
        for m in methods:
            C = np.array([best_so_far(json.loads((tdir / f"seed{s}" / f"{m}.json").read_text()))
                          for s in use])
            med = np.median(C, axis=0)
            if max(at) > len(med):
                raise ValueError(f"{tdir}: {m} ran {len(med)} trials, fewer than --at {max(at)}")
            rows.append({"target": f"{tdir.parent.name} {tdir.name}", "seeds": len(use),
                         "method": m, **{f"trial {t}": float(med[t - 1]) for t in at}})
    return rows


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    prov = Provenance(argv, "benchmarks.transfer_curves")
    ap = bench_parser("benchmarks.transfer_curves", description=__doc__.splitlines()[0])
    ladder_args(ap)
    ap.add_argument("--at", nargs="+", type=int, default=[1, 2, 4, 10, 20, 40])
    a = ap.parse_args(argv)
    if min(a.at) < 1:
        error_line("benchmarks.transfer_curves", "--at: trials count from 1")
        return 2
    try:
        rows = curves(Path(a.root), a.methods, a.seeds, a.at)
    except ValueError as e:
        error_line("benchmarks.transfer_curves", e)
        return 2
    finish_ladder(a, prov, {"at": a.at}, rows)
    return 0


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.transfer_curves"))
