"""Time the README's two commands on a fresh clone of this repository.

    python -m benchmarks.readme_commands [--out FILE.json]

Clones the current HEAD into a temporary directory (removed at the end: its venv is ~4 GB),
runs the README's first command (set up the venv and run the main job) and its second (the
tests), and records each wall time, exit status, the main job's summary (manual / phase-1 /
phase-3 best) and the machine load at the start and end of each.
"""
from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from benchmarks.common import ROOT, Provenance, add_out_arg, bench_parser, finish


def readme_commands() -> list[str]:
    """The two commands of the README's first code block (comment lines dropped)."""
    text = (ROOT / "README.md").read_text()
    block = re.search(r"```bash\n(.*?)```", text, re.S).group(1)
    return [ln.strip() for ln in block.splitlines() if ln.strip() and not ln.strip().startswith("#")]


def main(argv: list[str] | None = None) -> int:
    prov = Provenance(argv, "benchmarks.readme_commands")
    ap = bench_parser("benchmarks.readme_commands", description=__doc__.splitlines()[0])
    add_out_arg(ap)
    a = ap.parse_args(argv)
    cmds = readme_commands()
    with tempfile.TemporaryDirectory(prefix="lt_readme_") as tmp:   # its venv alone is ~4 GB
        return _run(Path(tmp), cmds, a.out, prov)


def _run(work: Path, cmds: list[str], out: Any, prov: Provenance) -> int:
    """Clone the repository into ``work``, run ``cmds`` there and write what they did."""
    clone = work / "latentune"
    subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True)
    shared = ROOT.parent / "shared"
    if shared.is_dir() and not (work / "shared").exists():
        os.symlink(shared, work / "shared")
    commit = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True,
                            cwd=clone).stdout.strip()
    runs = []
    env = {k: v for k, v in os.environ.items() if k not in ("VIRTUAL_ENV", "PYTHONPATH")}
    env["RAY_AUTH_MODE"] = "disabled"
    for cmd in cmds:
        load0 = list(os.getloadavg())
        t0 = time.perf_counter()
        p = subprocess.run(["bash", "-c", cmd], cwd=clone, capture_output=True, text=True, env=env)
        wall = time.perf_counter() - t0
        tail = p.stdout.strip().splitlines()[-12:]
        runs.append({"command": cmd, "wall_s": wall, "exit": p.returncode, "stdout_tail": tail,
                     "stderr_tail": p.stderr.strip().splitlines()[-3:],
                     "loadavg_start": load0, "loadavg_end": list(os.getloadavg())})
        print(f"{cmd}\n  exit {p.returncode} in {wall:.0f} s", file=sys.stderr, flush=True)
    summary = None
    s = clone / "runs" / "a1_trot" / "summary.json"
    if s.is_file():
        d = json.loads(s.read_text())
        summary = {k: d.get(k) for k in ("manual_cost", "phase1_best", "phase3_best",
                                          "phase1_evals", "phase3_evals", "wall_s")}
    rows = [{"command": r["command"], "exit": r["exit"], "wall_s": r["wall_s"],
             "load_start": r["loadavg_start"][0], "load_end": r["loadavg_end"][0]}
            for r in runs]
    finish(out, prov, {"clone_commit": commit, "runs": runs, "main_job": summary}, rows,
           title="the README's commands on a fresh clone"
                 + (f"; main job {summary}" if summary else ""))
    return 0


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.readme_commands"))
