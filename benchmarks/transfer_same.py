"""Are two methods' ladder traces the same trials? (After a default changes: the re-run default
against the stored variant it became, and the old default against its explicit option.)

    python -m benchmarks.transfer_same --a ROOT_A:METHOD_A --b ROOT_B:METHOD_B [--rtol R]
        [--out F.json]

For every ``ROOT_A/<target>/<sub>/seed<s>/METHOD_A.json`` (the cheap ladder's
``<system>/gap<g>``, or the robot ladder's ``<rung>/src<N>`` under its ``targets/``) the trace of
``METHOD_B`` at the same place under ``ROOT_B``: fall flags must be equal, and costs and (when
both record them) the θ asked equal element for element, or within the relative tolerance
``--rtol`` (on another machine a robot's rollout differs in its last digits). Exit
status 1 when any pair differs or is missing; 2, with one line on stderr, when either side has
no trace at all (a mistyped root or method).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from benchmarks.common import Provenance, add_out_arg, bench_parser, error_line, finish


def _spec(text: str) -> tuple[Path, str]:
    root, sep, method = text.partition(":")
    if not sep or not root or not method:
        raise argparse.ArgumentTypeError(f"expected ROOT:METHOD, got {text!r}")
    return Path(root), method


def _equal(x: list, y: list, rtol: float) -> bool:
    if rtol == 0.0:
        return x == y
    xa, ya = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    return xa.shape == ya.shape and bool(np.allclose(xa, ya, rtol=rtol, atol=0.0))


def same_trials(a: dict, b: dict, rtol: float = 0.0) -> bool:
    """True when the traces ``a`` and ``b`` asked and saw the same trials: the same fall flags,
    and costs and θ (when both record θ) equal, or within relative tolerance ``rtol``."""
    if a["failed"] != b["failed"] or not _equal(a["costs"], b["costs"], rtol):
        return False
    return "thetas" not in a or "thetas" not in b or _equal(a["thetas"], b["thetas"], rtol)


def _error(msg: str) -> int:
    """One line on stderr, as :func:`benchmarks.common.cli_main` prints it; exit status 2."""
    error_line("benchmarks.transfer_same", msg)
    return 2


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    prov = Provenance(argv, "benchmarks.transfer_same")
    ap = bench_parser("benchmarks.transfer_same", description=__doc__.splitlines()[0])
    ap.add_argument("--a", type=_spec, required=True, metavar="ROOT:METHOD")
    ap.add_argument("--b", type=_spec, required=True, metavar="ROOT:METHOD")
    ap.add_argument("--rtol", type=float, default=0.0,
                    help="relative tolerance of costs and θ (default 0: equal)")
    add_out_arg(ap)
    a = ap.parse_args(argv)
    if not a.rtol >= 0.0:
        return _error(f"--rtol must be >= 0, got {a.rtol}")
    (ra, ma), (rb, mb) = a.a, a.b
    rows = []
    for f in sorted(ra.glob(f"*/*/seed*/{ma}.json")):
        rel = f.parent.relative_to(ra)
        g = rb / rel / f"{mb}.json"
        rows.append({"run": str(rel), "same": g.is_file() and same_trials(
            json.loads(f.read_text()), json.loads(g.read_text()), a.rtol),
                     "missing": not g.is_file()})
    if not rows:
        return _error(f"no {ma}.json under {ra} (expected {ra}/*/*/seed*/{ma}.json)")
    if all(r["missing"] for r in rows):
        return _error(f"no {mb}.json under {rb} for any of the {len(rows)} runs of {ma} under "
                      f"{ra} (e.g. {rb / rows[0]['run'] / (mb + '.json')})")
    n_same = sum(r["same"] for r in rows)
    finish(a.out, prov, {"a": f"{ra}:{ma}", "b": f"{rb}:{mb}", "rtol": a.rtol,
                         "pairs": len(rows), "same": n_same}, [r for r in rows if not r["same"]] or
           [{"run": "all", "same": True, "missing": False}])
    print(f"{n_same} of {len(rows)} runs the same")
    return 0 if n_same == len(rows) else 1


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.transfer_same"))
