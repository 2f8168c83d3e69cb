"""``latentune bench``: the performance-ratio benchmarks of the suite at a quick size.

Each benchmark runs as ``python -m benchmarks.NAME ... --out FILE.json`` in a subprocess with one
BLAS thread, from the source checkout that holds ``benchmarks/`` (the suite is not part of the
installed package); its JSON output's ``"ratio"`` and provenance are read back and shown in one
Markdown table.
"""
from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from latentune.errors import UsageError
from latentune.threads import thread_env

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class Bench:
    """One benchmark of ``latentune bench``: module, arguments, what its ratio means."""

    name: str
    args: tuple[str, ...]
    ratio: str
    uses_steps: bool = False
    uses_n: bool = False
    goal: tuple[str, float] | None = None     # ("<=" or ">=", bound) the ratio should meet

    def verdict(self, ratio: float) -> str:
        """The status of a benchmark that ran: whether its ratio meets its goal (if any)."""
        if self.goal is None:
            return "ran"
        op, bound = self.goal
        met = ratio <= bound if op == "<=" else ratio >= bound
        return "ran, goal met" if met else f"ran, goal missed ({ratio:.2f}, goal {op} {bound:g})"


BENCHES: tuple[Bench, ...] = (
    Bench("actor", ("--repeat", "1"), "rollout / bare stepping + PD (goal <= 2)", uses_steps=True,
          goal=("<=", 2.0)),
    Bench("turbo_overhead", ("--told", "1000", "--asks", "3", "--regions", "1"),
          "TuRBO-m s/point with torch's threads / with its default one thread (> 1: one "
          "thread is faster)"),
    Bench("throughput", (), "serial / 2 process workers wall time (goal >= 1.8 on 2 free cores)",
          uses_steps=True, uses_n=True, goal=(">=", 1.8)),
)


NO_LIMIT_S = 1e6
"""A longer ``--timeout`` (or inf) is no limit: subprocess cannot wait for much longer (it
raised OverflowError from 1e10 s, or 3e6 s on epoll)."""


def repo_root(start: Path | None = None) -> Path | None:
    """The source checkout holding ``benchmarks/common.py``: an ancestor of this module (an
    editable install) or of ``start`` (default: the working directory); None if neither."""
    for here in (Path(__file__).resolve(), (start or Path.cwd()).resolve() / "_"):
        for base in here.parents:
            if (base / "benchmarks" / "common.py").is_file():
                return base
    return None


def run_bench(steps: int = 2000, n: int = 8, timeout: float = 900.0,
              root: Path | None = None) -> int:
    """Run the benchmarks of :data:`BENCHES` and print one Markdown table of their ratios.

    Args:
        steps: rollout steps of the actor and throughput benchmarks (>= 1).
        n: rollouts of the throughput benchmark (>= 1).
        timeout: seconds allowed per benchmark (> 0; above :data:`NO_LIMIT_S`, ``inf``
            included: no limit).
        root: the source checkout (default: :func:`repo_root`).

    Returns:
        0 if every benchmark succeeded, else 1.

    Raises:
        UsageError: a bad argument, or no checkout with ``benchmarks/`` (an installed package).
    """
    # the parameters are the command's flags of the same names
    from latentune.task import MAX_STEPS

    for flag, v in (("--steps", steps), ("--n", n)):
        if v < 1:
            raise UsageError(f"{flag} must be >= 1, got {v}")
    if steps > MAX_STEPS:
        raise UsageError(f"--steps must be at most {MAX_STEPS:,}, got {steps}")
    if not timeout > 0:
        raise UsageError(f"--timeout must be > 0, got {timeout}")
    root = root or repo_root()
    if root is None:
        raise UsageError("the benchmarks are not installed with the package: run latentune bench "
                         "in a source checkout of latentune (a directory holding benchmarks/)")
    limit = timeout if timeout <= NO_LIMIT_S else None
    env = dict(os.environ, **thread_env())
    rows: list[dict[str, Any]] = []
    status = 0
    with tempfile.TemporaryDirectory(prefix="lt_bench_") as tmp:
        for b in BENCHES:
            out = Path(tmp) / f"{b.name}.json"
            args = [*b.args, *(["--steps", str(steps)] if b.uses_steps else []),
                    *(["--n", str(n)] if b.uses_n else [])]
            logger.info("running python -m benchmarks.%s %s", b.name, " ".join(args))
            argv = [sys.executable, "-m", f"benchmarks.{b.name}", *args, "--out", str(out)]
            t = time.perf_counter()
            row: dict[str, Any] = {"benchmark": b.name, "ratio": None, "meaning": b.ratio}
            try:
                r = subprocess.run(argv, capture_output=True, text=True, env=env, cwd=root,
                                   timeout=limit)
            except subprocess.TimeoutExpired:
                row["status"] = f"timed out after {timeout:.0f} s"
                status = 1
            else:
                row.update(_read(out, r))
                if row["status"] != "ok":
                    status = 1
                else:
                    row["status"] = b.verdict(row["ratio"])
            row["wall_s"] = round(time.perf_counter() - t, 1)
            rows.append(row)
    print(_table(rows))
    return status


def _read(out: Path, proc: subprocess.CompletedProcess) -> dict[str, Any]:
    """Ratio, load and status of one benchmark from its JSON output."""
    if proc.returncode != 0 or not out.is_file():
        err = [ln for ln in proc.stderr.splitlines() if ln.strip()]
        return {"status": f"exit {proc.returncode}: {err[-1] if err else 'no output'}"}
    try:
        obj = json.loads(out.read_text())
        ratio = float(obj["ratio"])
    except (OSError, ValueError, KeyError, TypeError) as exc:
        return {"status": f"unreadable output ({type(exc).__name__}: {exc})"}
    load = (obj.get("provenance") or {}).get("loadavg_end") or [None]
    return {"status": "ok", "ratio": ratio, "load": load[0]}


def _table(rows: list[dict[str, Any]]) -> str:
    cols = ["benchmark", "ratio", "meaning", "load", "wall_s", "status"]
    lines = ["| " + " | ".join(cols) + " |", "|" + "|".join("---" for _ in cols) + "|"]
    for r in rows:
        cells = []
        for c in cols:
            v = r.get(c)
            cells.append("–" if v is None else f"{v:.2f}" if isinstance(v, float) else str(v))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)
