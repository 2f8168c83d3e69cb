"""Time the README's test command: this checkout, and optionally an earlier commit, in turn.

    python -m benchmarks.suite_time [--python PY] [--before REV] [--pairs N] [--out FILE.json]

Runs the second command of the README's first code block (the test command) in this checkout
with ``.venv/bin/python`` replaced by ``--python`` (default: the interpreter running this
benchmark) and ``PYTHONPATH`` set to the checkout's ``src`` and root, so the checkout's code is
tested whatever the venv's editable install points to. With ``--before REV`` it also clones the
repository into a temporary directory at REV and runs *that* commit's README test command the same way,
alternating before / after ``--pairs`` times so both see the same machine load.

Each run records the wall time [s], the CPU time of the command and all its children
(user + sys [s], from ``getrusage(RUSAGE_CHILDREN)``), the load average at start and end, the
exit status, pytest's counts (passed, failed, skipped, errors) from its last line and the
names of the failed tests.
"""
from __future__ import annotations

import statistics
import os
import re
import resource
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from benchmarks.common import ROOT, Provenance, add_out_arg, bench_parser, finish


def test_command(checkout: Path) -> str:
    """The README's test command (the second command of its first ``bash`` block)."""
    text = (checkout / "README.md").read_text()
    block = re.search(r"```bash\n(.*?)```", text, re.S)
    if block is None:
        raise SystemExit(f"no bash block in {checkout / 'README.md'}")
    cmds = [ln.strip() for ln in block.group(1).splitlines()
            if ln.strip() and not ln.strip().startswith("#")]
    return cmds[1]


def counts(last_line: str) -> dict[str, int]:
    """pytest's summary counts (``783 passed, 1 failed in 12.3s`` -> passed, failed, ...)."""
    out = {k: 0 for k in ("passed", "failed", "skipped", "errors")}
    for n, what in re.findall(r"(\d+) (passed|failed|skipped|errors?)\b", last_line):
        out["errors" if what.startswith("error") else what] = int(n)
    return out


def run_suite(checkout: Path, python: str, label: str) -> dict[str, Any]:
    """One run of ``checkout``'s README test command; its wall, CPU, load and counts."""
    cmd = test_command(checkout)
    argv = shlex.split(cmd)
    if argv and argv[0].endswith("python"):
        argv[0] = python
    env = {k: v for k, v in os.environ.items() if k != "VIRTUAL_ENV"}
    env["PYTHONPATH"] = f"{checkout / 'src'}{os.pathsep}{checkout}"
    env["RAY_AUTH_MODE"] = "disabled"
    load0 = list(os.getloadavg())
    ru0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    p = subprocess.run(argv, cwd=checkout, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    ru1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    lines = [ln for ln in p.stdout.strip().splitlines() if ln.strip()]
    last = lines[-1] if lines else ""
    row = {"label": label, "command": " ".join(argv), "readme_command": cmd, "exit": p.returncode,
           "wall_s": round(wall, 2), "user_s": round(ru1.ru_utime - ru0.ru_utime, 2),
           "sys_s": round(ru1.ru_stime - ru0.ru_stime, 2),
           "load_start": [round(v, 2) for v in load0],
           "load_end": [round(v, 2) for v in os.getloadavg()], **counts(last),
           "summary": last.strip("= "),
           "failed_tests": [ln.split()[1] for ln in lines if ln.startswith(("FAILED ", "ERROR "))]}
    row["cpu_s"] = round(row["user_s"] + row["sys_s"], 2)
    row["tests"] = sum(row[k] for k in ("passed", "failed", "skipped", "errors"))
    print(f"{label}: exit {p.returncode}, {wall:.0f} s wall, {row['cpu_s']:.0f} s CPU, "
          f"load {load0[0]:.1f}: {row['summary']}", file=sys.stderr, flush=True)
    return row


def main(argv: list[str] | None = None) -> int:
    prov = Provenance(argv, "benchmarks.suite_time")
    ap = bench_parser("benchmarks.suite_time", description=__doc__.splitlines()[0])
    ap.add_argument("--python", default=sys.executable,
                    help="interpreter that replaces the README's .venv/bin/python")
    ap.add_argument("--before", metavar="REV", default=None,
                    help="also time this commit's README test command, alternating with HEAD")
    ap.add_argument("--pairs", type=int, default=1, help="runs of each command (default 1)")
    add_out_arg(ap)
    a = ap.parse_args(argv)
    if a.pairs < 1:
        ap.error(f"--pairs must be >= 1, got {a.pairs}")
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="lt_suite_") as work:
        before = None
        if a.before is not None:                 # a clone: the repository itself is untouched
            before = Path(work) / "before"
            subprocess.run(["git", "clone", "-q", "--no-checkout", str(ROOT), str(before)],
                           check=True)
            subprocess.run(["git", "-C", str(before), "checkout", "-q", a.before], check=True)
        for _ in range(a.pairs):
            if before is not None:
                rows.append(run_suite(before, a.python, f"before ({a.before})"))
            rows.append(run_suite(ROOT, a.python, "after (this checkout)"))
    results: dict[str, Any] = {"before": a.before, "runs": rows}
    if a.before is not None:
        b = [r for r in rows if r["label"].startswith("before")]
        h = [r for r in rows if r["label"].startswith("after")]
        results["wall_ratio_median"] = round(statistics.median(
            y["wall_s"] / x["wall_s"] for x, y in zip(b, h)), 3)
        results["cpu_ratio_median"] = round(statistics.median(
            y["cpu_s"] / x["cpu_s"] for x, y in zip(b, h)), 3)
    finish(a.out, prov, results, rows,
           columns=["label", "exit", "wall_s", "cpu_s", "user_s", "sys_s", "load_start", "tests",
                    "passed", "failed", "skipped", "errors"],
           title="the README's test command" + (
               f"; after / before: wall {results['wall_ratio_median']}, CPU "
               f"{results['cpu_ratio_median']} (median of pairs)" if before is not None else ""))
    return 0


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.suite_time"))
