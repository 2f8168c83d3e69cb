"""Rows digest: the sorted md5 of a run's stored trials, to show a refactor changes no row.

A run's rows are (phase, θ as float64 bytes, cost, fell) for every stored evaluation; timings,
creation times and the completion order (idx) are left out, so two runs of the same seed on the
same machine give the same digest whatever order the workers finished in.

Usage::

    python -m benchmarks.rows_digest digest DIR [DIR ...] [--out F.json] # the digest of stored runs
    python -m benchmarks.rows_digest main OUT                       # the main job (A1 trot, small), then its digest
    python -m benchmarks.rows_digest handover OUT                   # a seeded hand-over run on a user system

``main`` runs ``latentune tune --robot a1 --task trot --out OUT --phase1-evals 40
--phase3-evals 16 --workers 2 --seed 0 --quiet``. ``handover`` runs, with seed 0, phase 1
(60 trials) and phase 2 on a quadratic :class:`~latentune.FunctionSystem` with a fall region
(``OUT/source``), then phase 3 (30 trials, ``handover=True``) on a shifted copy of it through the
source's latent space (``OUT/target``), and the same phase 3 fall-aware (``max_fall_prob=0.3``,
``OUT/target_fall``). OUT must not exist (the digest is of a fresh run). Prints the digest as a table; ``--out``
writes it with its provenance (benchmarks.common).
"""
from __future__ import annotations

import hashlib
import json
import os
import sqlite3
import subprocess
import sys
from pathlib import Path

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS"):
    os.environ.setdefault(_v, "1")      # one BLAS thread, as the CLI (before numpy is loaded)

import numpy as np  # noqa: E402

from latentune.errors import StoreError  # noqa: E402
from latentune.pipeline.store import read_uri  # noqa: E402

from benchmarks.common import Provenance, add_out_arg, bench_parser, cli_main, finish  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def rows(run: Path) -> list[tuple[int, bytes, float, bool]]:
    """(phase, θ bytes, cost, fell) of every stored evaluation of ``run``, sorted."""
    if not (Path(run) / "run.db").is_file():
        raise StoreError(f"no run store in {run} (expected run.db)")
    con = sqlite3.connect(read_uri(Path(run) / 'run.db'), uri=True)
    try:
        got = con.execute("SELECT phase, theta, cost, fell FROM evaluations").fetchall()
    finally:
        con.close()
    return sorted((int(p), np.asarray(json.loads(t), dtype=np.float64).tobytes(), float(c),
                   bool(f)) for p, t, c, f in got)


def digest(*runs: Path) -> dict[str, object]:
    """``{"md5", "n", "per_phase"}`` of the rows of ``runs`` (in the order given)."""
    h = hashlib.md5()
    n, per = 0, {}
    for k, run in enumerate(runs):
        h.update(f"run {k}|".encode())           # the position, not the name, of each run
        for p, theta, cost, fell in rows(run):
            h.update(f"{p}|{cost!r}|{int(fell)}|".encode())
            h.update(theta)
            n += 1
            per[p] = per.get(p, 0) + 1
    return {"md5": h.hexdigest(), "n": n, "per_phase": {str(k): v for k, v in sorted(per.items())}}


def run_main(out: Path) -> dict[str, object]:
    """The main job, small: A1 trot through the CLI with two workers."""
    cmd = [str(ROOT / ".venv" / "bin" / "latentune"), "tune", "--robot", "a1", "--task", "trot",
           "--out", str(out), "--phase1-evals", "40", "--phase3-evals", "16", "--workers", "2",
           "--seed", "0", "--quiet"]
    p = subprocess.run(cmd, capture_output=True, text=True)
    if p.returncode != 0:
        raise SystemExit(f"rows_digest: {' '.join(cmd)} failed: {p.stderr.strip()}")
    return digest(out)


def _plant(shift: float):
    """A 6-weight quadratic plant; θ with w0 > 0.6 (physical) fall."""
    import latentune as lt

    space = lt.ParameterSpace([f"w{i}" for i in range(6)], [-1.0] * 6, [1.0] * 6,
                              manual=[0.5] * 6)

    def fn(x: np.ndarray):
        if x[0] > 0.6:
            return lt.Outcome(None, failed=True, info={"reason": "w0 too big"})
        return float(np.sum((x - 0.2 - shift) ** 2))

    return lt.FunctionSystem(space, fn)


def run_handover(out: Path) -> dict[str, object]:
    """Phase 1 + 2 on the plant, phase 3 with a hand-over on a shifted plant (plain and
    fall-aware); seed 0, serial trials."""
    import latentune as lt

    with lt.Study(out / "source", seed=0) as src:
        src.phase1(_plant(0.0), 60)
        src.train_latent(latent_dim=3, epochs=60)
    for name, mfp in (("target", None), ("target_fall", 0.3)):
        with lt.Study(out / name, seed=0) as tgt:
            tgt.phase3(_plant(0.25), 30, latent=out / "source", handover=True, max_fall_prob=mfp)
    return digest(out / "source", out / "target", out / "target_fall")


def main(argv: list[str] | None = None) -> int:
    ap = bench_parser("benchmarks.rows_digest", description=__doc__.splitlines()[0])
    ap.add_argument("what", choices=("digest", "main", "handover"))
    ap.add_argument("dirs", nargs="+", type=Path)
    add_out_arg(ap)
    a = ap.parse_args(argv)
    prov = Provenance(argv, module="benchmarks.rows_digest")
    if a.what == "digest":
        res = digest(*a.dirs)
    else:
        if len(a.dirs) != 1 or a.dirs[0].exists():
            raise SystemExit(f"rows_digest {a.what}: give one OUT directory that does not exist")
        res = run_main(a.dirs[0]) if a.what == "main" else run_handover(a.dirs[0])
    finish(a.out, prov, {"what": a.what, "dirs": [str(d) for d in a.dirs], **res},
           [{"what": a.what, "rows": res["n"], "md5": res["md5"]}])
    return 0


if __name__ == "__main__":
    sys.exit(cli_main(main, "benchmarks.rows_digest"))
