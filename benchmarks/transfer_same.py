"""Are two methods' ladder traces the same trials? (After a default changes: the re-run default
against the stored variant it became, and the old default against its explicit option.)

    python -m benchmarks.transfer_same --a ROOT_A:METHOD_A --b ROOT_B:METHOD_B [--out F.json]

For every ``ROOT_A/<system>/gap<g>/seed<s>/METHOD_A.json`` the trace of ``METHOD_B`` at the same
place under ``ROOT_B``: costs, fall flags and (when both record them) the θ asked must be equal
element for element. Exit status 1 when any pair differs or is missing.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from benchmarks.common import Provenance, add_out_arg, finish


def _spec(text: str) -> tuple[Path, str]:
    root, sep, method = text.partition(":")
    if not sep or not root or not method:
        raise argparse.ArgumentTypeError(f"expected ROOT:METHOD, got {text!r}")
    return Path(root), method


def same_trials(a: dict, b: dict) -> bool:
    """True when the traces ``a`` and ``b`` asked and saw the same trials."""
    if a["costs"] != b["costs"] or a["failed"] != b["failed"]:
        return False
    return "thetas" not in a or "thetas" not in b or a["thetas"] == b["thetas"]


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    prov = Provenance(argv, "benchmarks.transfer_same")
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--a", type=_spec, required=True, metavar="ROOT:METHOD")
    ap.add_argument("--b", type=_spec, required=True, metavar="ROOT:METHOD")
    add_out_arg(ap)
    a = ap.parse_args(argv)
    (ra, ma), (rb, mb) = a.a, a.b
    rows = []
    for f in sorted(ra.glob(f"*/gap*/seed*/{ma}.json")):
        rel = f.parent.relative_to(ra)
        g = rb / rel / f"{mb}.json"
        rows.append({"run": str(rel), "same": g.is_file() and same_trials(
            json.loads(f.read_text()), json.loads(g.read_text())), "missing": not g.is_file()})
    if not rows:
        print(f"error: no {ma}.json under {ra}", file=sys.stderr)
        return 2
    n_same = sum(r["same"] for r in rows)
    finish(a.out, prov, {"a": f"{ra}:{ma}", "b": f"{rb}:{mb}", "pairs": len(rows),
                         "same": n_same}, [r for r in rows if not r["same"]] or
           [{"run": "all", "same": True, "missing": False}])
    print(f"{n_same} of {len(rows)} runs the same")
    return 0 if n_same == len(rows) else 1


if __name__ == "__main__":
    sys.exit(main())
