"""How long a run store takes to create and to open, against the store of another commit.

    python -m benchmarks.store_open [--n 40] [--before REV] [--out FILE.json]

Times ``RunStore(DIR, create=True)`` (a new store: its tables and format mark written, then
linked in as ``DIR/run.db``) and ``RunStore(DIR)`` of an existing one, each followed by
``close()``, ``--n`` times in new directories under one temporary directory on the file system
of ``/tmp``; prints the median and the quartiles in milliseconds. With ``--before REV`` the same
loop runs on ``src/latentune`` of that commit (checked out to a temporary directory with ``git
archive``) in a process of its own, in turn with this tree's, so both see the same disk.
"""
from __future__ import annotations

import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from benchmarks.common import ROOT, Provenance, add_out_arg, bench_parser, finish

LOOP = """
import json, statistics, sys, tempfile, time
from latentune.pipeline.store import RunStore
n = int(sys.argv[1])
d = tempfile.mkdtemp(dir="/tmp", prefix="lt_store_")
out = {"create_ms": [], "open_ms": []}
for i in range(n):
    t = time.perf_counter(); s = RunStore(f"{d}/r{i}", create=True); s.close()
    out["create_ms"].append(1000 * (time.perf_counter() - t))
for i in range(n):
    t = time.perf_counter(); s = RunStore(f"{d}/r{i}"); s.close()
    out["open_ms"].append(1000 * (time.perf_counter() - t))
import shutil; shutil.rmtree(d, ignore_errors=True)
print(json.dumps(out))
"""


def _times(src: Path, n: int) -> dict[str, list[float]]:
    """The loop's times (ms) run by a fresh interpreter on the package in ``src``."""
    env = dict(os.environ, PYTHONPATH=str(src))
    p = subprocess.run([sys.executable, "-c", LOOP, str(n)], env=env, capture_output=True,
                       text=True, check=True)
    return json.loads(p.stdout)


def _row(label: str, ms: list[float]) -> dict[str, object]:
    q = statistics.quantiles(ms, n=4)
    return {"store": label, "median_ms": statistics.median(ms), "q1_ms": q[0], "q3_ms": q[2]}


def main(argv: list[str] | None = None) -> int:
    prov = Provenance(argv, "benchmarks.store_open")
    ap = bench_parser("benchmarks.store_open", description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=40, help="stores created and opened (default 40)")
    ap.add_argument("--before", default=None, metavar="REV",
                    help="also time the store of this commit, in turn with this tree's")
    add_out_arg(ap)
    a = ap.parse_args(argv)
    if a.n < 4:
        ap.error(f"--n must be at least 4 (quartiles), got {a.n}")
    trees = {"this tree": ROOT / "src"}
    tmp = None
    if a.before:
        tmp = Path(tempfile.mkdtemp(prefix="lt_before_"))
        try:
            archive = subprocess.run(["git", "-C", str(ROOT), "archive", a.before, "src"],
                                     capture_output=True, check=True).stdout
        except subprocess.CalledProcessError as exc:
            shutil.rmtree(tmp, ignore_errors=True)
            ap.error(f"--before {a.before}: {exc.stderr.decode(errors='replace').strip()}")
        subprocess.run(["tar", "-x", "-C", str(tmp)], input=archive, check=True)
        trees[a.before] = tmp / "src"
    try:
        times = {k: {"create_ms": [], "open_ms": []} for k in trees}
        for _ in range(2):                                    # in turn, twice each
            for k, src in trees.items():
                t = _times(src, a.n)
                for key in t:
                    times[k][key] += t[key]
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
    rows = [_row(f"{k}: create", v["create_ms"]) for k, v in times.items()] + \
        [_row(f"{k}: open", v["open_ms"]) for k, v in times.items()]
    finish(a.out, prov, {"n": a.n, "runs_each": 2, "times_ms": times}, rows,
           ["store", "median_ms", "q1_ms", "q3_ms"],
           title=f"run store: create and open, {2 * a.n} stores each, in ms")
    return 0


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.store_open"))
