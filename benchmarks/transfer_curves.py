"""Median best-so-far curves of the transfer ladder's stored runs.

    python -m benchmarks.transfer_curves --root runs/transfer --methods transfer gp ...
        [--seeds 0 1 2] [--at 1 2 4 10 20 40] [--out F.md]

For every target (``ROOT/<system>/gap<g>``) and method: the best cost among the trials that did
not fall after each trial (∞ until one stands), per seed, then the median over the seeds that
ran every listed method, printed at the trials ``--at`` (Markdown; ``--out`` also writes it).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np


def best_so_far(run: dict) -> np.ndarray:
    """(n,) best cost among the trials of ``run`` that did not fall, after each trial."""
    c = np.array([np.inf if x is None else x for x in run["costs"]], dtype=float)
    return np.minimum.accumulate(np.where(np.array(run["failed"], dtype=bool), np.inf, c))


def curves(root: Path, methods: list[str], seeds: list[int] | None, at: list[int]) -> str:
    """The Markdown table of median best-so-far at trials ``at`` (module docstring)."""
    lines = [f"| target | method | {' | '.join(f'trial {t}' for t in at)} |",
             "|---|---|" + "---:|" * len(at)]
    for tdir in sorted(root.glob("*/gap*")):
        have = [int(p.name[4:]) for p in tdir.glob("seed*")
                if all((p / f"{m}.json").is_file() for m in methods)]
        use = sorted(s for s in have if seeds is None or s in seeds)
        if not use:
            continue
        for m in methods:
            C = np.array([best_so_far(json.loads((tdir / f"seed{s}" / f"{m}.json").read_text()))
                          for s in use])
            med = np.median(C, axis=0)
            lines.append(f"| {tdir.parent.name} {tdir.name} ({len(use)} seeds) | {m} | "
                         + " | ".join(f"{med[t - 1]:.4g}" for t in at) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--root", default="runs/transfer")
    ap.add_argument("--methods", nargs="+", required=True)
    ap.add_argument("--seeds", nargs="+", type=int, default=None)
    ap.add_argument("--at", nargs="+", type=int, default=[1, 2, 4, 10, 20, 40])
    ap.add_argument("--out", default=None)
    a = ap.parse_args(sys.argv[1:] if argv is None else argv)
    md = curves(Path(a.root), a.methods, a.seeds, a.at)
    print(md)
    if a.out:
        Path(a.out).write_text(md + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
