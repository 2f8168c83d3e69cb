"""Whether a peer's better θ lies across a band of falls from the default's best: the straight
path between them, run on the target.

    python -m benchmarks.basin_path --system cartpole --gap 2 [--a DEFAULT] [--b cma_source]
        [--root results/transfer/rebuilt/runs] [--seeds 0 1 ...] [--points 41]
        [--out F.json] [--md F.md]

For each seed, the best trial that did not fall of method A and of method B
(``ROOT/<system>/gap<g>/seed<s>/<method>[@avx512].json``, the ladder's traces with θ) are
joined by a straight line in the unit box, and ``--points`` evenly spaced θ on it (both ends
included) are run once on the target (``benchmarks.transfer.SYSTEMS``; deterministic). Per
seed: the RMS distance between the two θ (‖Δ‖ / √d), the path as a string (``.`` stands,
``x`` falls), the share of it that falls, the longest run of falls as a share of the path,
and the two ends' costs (re-run: they must equal the stored costs). A path with a fall band
between two standing ends says that reaching B's θ from A's by small steps costs falls, and
that a search which avoids falls has to jump across the band.
"""
from __future__ import annotations

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
from benchmarks.transfer import DEFAULT_METHOD as DEFAULT  # noqa: E402
from benchmarks.transfer_walk import load_trace  # noqa: E402


def best_theta(root: Path, system: str, gap: float, seed: int, method: str
               ) -> tuple[np.ndarray, float] | None:
    """(θ (d,), cost) of ``method``'s best standing trial, or None (no trace, no θ, or every
    trial fell)."""
    tr = load_trace([root], system, gap, seed, method)
    if tr is None or "thetas" not in tr:
        return None
    c = np.where(np.asarray(tr["failed"], bool), np.inf, np.asarray(tr["costs"], float))
    i = int(np.argmin(c))
    return (np.asarray(tr["thetas"][i], float), float(c[i])) if np.isfinite(c[i]) else None


def longest_run(fell: np.ndarray) -> int:
    """The length of the longest run of True in ``fell``."""
    best = run = 0
    for f in fell:
        run = run + 1 if f else 0
        best = max(best, run)
    return best


def paths(root: Path, system: str, gap: float, a: str, b: str, seeds: list[int], points: int
          ) -> list[dict[str, Any]]:
    """One row per seed where both methods stood (module docstring)."""
    from latentune.system import evaluate

    target = SYSTEMS[system]["target"](gap)
    rows = []
    for s in seeds:
        ta, tb = best_theta(root, system, gap, s, a), best_theta(root, system, gap, s, b)
        if ta is None or tb is None:
            continue
        (xa, ca), (xb, cb) = ta, tb
        outs = [evaluate(target, xa + (xb - xa) * t) for t in np.linspace(0.0, 1.0, points)]
        fell = np.array([o.failed for o in outs], dtype=bool)
        if not np.isclose(outs[0].cost, ca) or not np.isclose(outs[-1].cost, cb):
            raise RuntimeError(f"seed {s}: the re-run ends cost {outs[0].cost:.6g} and "
                               f"{outs[-1].cost:.6g}, stored {ca:.6g} and {cb:.6g}")
        rows.append({"seed": s, "distance": float(np.linalg.norm(xb - xa) / np.sqrt(len(xa))),
                     "path": "".join("x" if f else "." for f in fell),
                     "falls_share": float(fell.mean()),
                     "longest_band": float(longest_run(fell) / points),
                     "cost_a": ca, "cost_b": cb,
                     "best_on_path": float(min(o.cost for o in outs if not o.failed))})
    return rows


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    prov = Provenance(argv, "benchmarks.basin_path")
    ap = bench_parser("benchmarks.basin_path", description=__doc__.splitlines()[0])
    ap.add_argument("--system", required=True, choices=list(SYSTEMS))
    ap.add_argument("--gap", type=float, required=True)
    ap.add_argument("--a", default=DEFAULT)
    ap.add_argument("--b", default="cma_source")
    ap.add_argument("--root", type=Path, default=Path("results/transfer/rebuilt/runs"))
    ap.add_argument("--seeds", nargs="+", type=int, default=list(range(10)))
    ap.add_argument("--points", type=int, default=41)
    add_out_arg(ap)
    ap.add_argument("--md", type=out_file, default=None, metavar="FILE.md")
    a = ap.parse_args(argv)
    if a.points < 2:
        error_line("benchmarks.basin_path", "--points takes a count ≥ 2")
        return 2
    rows = paths(a.root, a.system, a.gap, a.a, a.b, a.seeds, a.points)
    if not rows:
        error_line("benchmarks.basin_path", f"no seed where both {a.a} and {a.b} have a "
                   f"standing trial with θ under {a.root}/{a.system}/gap{a.gap:g}")
        return 2
    banded = sum(1 for r in rows if r["longest_band"] > 0)
    summary = {"system": a.system, "gap": a.gap, "a": a.a, "b": a.b, "seeds": len(rows),
               "paths_with_a_fall_band": banded,
               "median_distance": float(np.median([r["distance"] for r in rows])),
               "median_falls_share": float(np.median([r["falls_share"] for r in rows]))}
    finish(a.out, prov, {"summary": summary}, rows)
    if a.md is not None:
        write_text(a.md, f"`{prov.command}`\n\n{markdown_table([summary])}\n\n"
                        f"{markdown_table(rows)}\n")
    return 0


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.basin_path"))
