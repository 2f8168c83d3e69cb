"""Where in θ each method of the transfer ladder looked and where its best θ lies, coordinate by
coordinate, from the stored runs.

    python -m benchmarks.transfer_coords --root runs/transfer --methods transfer gp ...
        [--coords grav_1 fric_1] [--faces] [--targets arm/gap1.5] [--seeds 0 1 2] [--out F.json]
        [--md F.md]

For every target (``ROOT/<system>/gap<g>``, or those named by ``--targets``) and method, over
the seeds that ran every listed method and hold their trials' θ (``thetas``, unit box): per
coordinate named by ``--coords`` (names from the system's parameter space, or indices), the
median over the seeds of the best standing θ's value (``best``) and of the highest and lowest
value any trial asked (``max``, ``min``). A method that never asks a coordinate beyond a value
cannot find an optimum that lies beyond it: this is how a search that stays near the source's
θ shows itself, whatever the cost says.

``--faces`` adds one row per (target, method), coordinate ``on a face``: the share of the
coordinates within ``FACE_TOL`` of 0 or 1 in the best standing θ (``best``), and the highest and
lowest such share among the trials (``max``, ``min``), medians over the seeds. An optimizer of an
acquisition over the box (GPSampler's) ends on its faces; a draw inside a trust region does not.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.common import Provenance, bench_parser, error_line
from benchmarks.transfer import SYSTEMS
from benchmarks.transfer_curves import finish_ladder, ladder_args, targets


FACE_TOL = 0.01
"""A coordinate within this of 0 or 1 (unit box) is on a face (``--faces``)."""
FACES = "on a face"
"""The ``coordinate`` of the ``--faces`` rows."""


def coordinate_names(system: str) -> list[str]:
    """The θ names of ladder system ``system`` (its model's parameter space)."""
    return list(SYSTEMS[system]["model"]().space.names)


def coords(root: Path, methods: list[str], seeds: list[int] | None, names: list[str],
           only: list[str] | None = None, faces: bool = False) -> list[dict[str, Any]]:
    """One row per (target, method, coordinate): seeds used, median best value, median max and
    min asked (unit box); with ``faces`` one more per (target, method), coordinate
    :data:`FACES` (the module docstring). ``only``: target paths relative to ``root``
    (``"arm/gap1.5"``). ValueError when a name of ``names`` is not a coordinate (or index) of a
    target's system."""
    rows: list[dict[str, Any]] = []
    for tdir, use in targets(root, methods, seeds):
        rel = f"{tdir.parent.name}/{tdir.name}"
        if only is not None and rel not in only:
            continue
        space = coordinate_names(tdir.parent.name)
        bad = [n for n in names if not (n in space or (n.isdigit() and int(n) < len(space)))]
        if bad:
            raise ValueError(f"{tdir.parent.name} has no coordinate {', '.join(bad)} "
                             f"(its {len(space)} are {', '.join(space)}, or their indices)")
        idx = [int(n) if n.isdigit() else space.index(n) for n in names]
        for m in methods:
            runs = [json.loads((tdir / f"seed{s}" / f"{m}.json").read_text()) for s in use]
            runs = [r for r in runs if r.get("thetas")]
            if not runs:
                continue
            best, hi, lo, share = [], [], [], []
            for r in runs:
                th = np.asarray(r["thetas"], dtype=float)
                c = np.where(np.asarray(r["failed"], dtype=bool), np.inf,
                             np.asarray(r["costs"], dtype=float))
                i_best = int(np.argmin(c))
                best.append(th[i_best])
                hi.append(th.max(0))
                lo.append(th.min(0))
                on = ((th <= FACE_TOL) | (th >= 1 - FACE_TOL)).mean(1)     # (trials,)
                share.append((on[i_best], on.max(), on.min()))
            for i in idx:
                rows.append({"target": rel, "method": m, "seeds": len(runs),
                             "coordinate": space[i],
                             "best": round(float(np.median([b[i] for b in best])), 3),
                             "max": round(float(np.median([h[i] for h in hi])), 3),
                             "min": round(float(np.median([v[i] for v in lo])), 3)})
            if faces:
                med = np.median(np.asarray(share), axis=0)
                rows.append({"target": rel, "method": m, "seeds": len(runs), "coordinate": FACES,
                             "best": round(float(med[0]), 3), "max": round(float(med[1]), 3),
                             "min": round(float(med[2]), 3)})
    return rows


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    prov = Provenance(argv, "benchmarks.transfer_coords")
    ap = bench_parser("benchmarks.transfer_coords", description=__doc__.splitlines()[0])
    ladder_args(ap)
    ap.add_argument("--coords", nargs="+", default=[],
                    help="θ names of the system's parameter space, or indices")
    ap.add_argument("--faces", action="store_true",
                    help="one more row per target and method: the share of θ's coordinates on "
                         "a face of the box")
    ap.add_argument("--targets", nargs="+", default=None, help="e.g. arm/gap1.5")
    a = ap.parse_args(argv)
    if not a.coords and not a.faces:
        error_line("benchmarks.transfer_coords", "give --coords NAME ... or --faces (or both)")
        return 2
    try:
        rows = coords(Path(a.root), a.methods, a.seeds, a.coords, a.targets, a.faces)
    except ValueError as e:
        error_line("benchmarks.transfer_coords", e)
        return 2
    if not rows:
        error_line("benchmarks.transfer_coords",
                   "no stored run holds θ for these targets, methods and coordinates")
        return 2
    finish_ladder(a, prov, {"coords": a.coords}, rows)
    return 0


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.transfer_coords"))
