"""What every benchmark of the suite shares: the problem registry, provenance and one output
convention.

Run a benchmark from the repository root as a module (``benchmarks`` is a package; nothing edits
``sys.path``)::

    python -m benchmarks.NAME [options] [--out FILE.json]

Every benchmark prints a Markdown table of its results on stdout and, with ``--out FILE.json``,
writes one JSON object: its results plus ``"provenance"`` (:class:`Provenance`: the command, the
git commit, the date, the machine's CPU, cores and vector extension, the Python and library
versions, the load average at start and end, the wall time). ``latentune bench`` reads these
files.

Problems
--------
Every problem is minimized on the unit box [0, 1]^d (:class:`Problem`, ``f(u) -> float``).

* The peer suite (:func:`problems`, used by ``benchmarks.peers``): synthetic functions mapped
  affinely from the unit box to their usual domain, then shifted (the optimum moves to a point
  ``o`` drawn in the inner 60 % of the domain) and, where marked, rotated
  (``z = z* + R (x − o)``, R a random orthogonal matrix), with shift and rotation drawn from a
  generator seeded by the problem's name, so they are the same for every optimizer and seed.
  The global minimum of every synthetic problem is 0. Two controller-like problems (global
  minimum unknown, > 0):

  * ``lqr16``: tune the 16 diagonal LQR weights (log10 Q_ii of 12 states, log10 R_jj of 4
    inputs, each in [-3, 3]) of an unstable discrete linear system; the gain is designed on the
    nominal model and run on a perturbed plant with saturated inputs (|u| <= 1) from 4 fixed
    initial states for 60 steps. Cost: mean quadratic task cost; a run whose state leaves
    ``|x|_inf <= 20`` fails with cost ``100 · (2 − t_fail / T)`` (a failure region of costs in
    [100, 200)).
  * ``gains24``: tune the 24 entries of a state-feedback gain K (4 inputs × 6 states) directly,
    ``K = K_lqr + 3 · max(|K_lqr|, 0.3) · (2u − 1)`` around the nominal LQR gain (the box
    centre, like a hand-tuned starting point), on a perturbed plant with saturation and a
    destabilizing cubic term ``+0.01·x³``; same cost and failure rule (about a fifth of the box
    diverges).

* The quick suite (:func:`quick_problems`, used by ``benchmarks.critic``): the same base
  functions, unshifted and unrotated, on their usual domains (``ackley20``, ``levy25``,
  ``rosenbrock25``, ``styblinski77``, ``ackley77``).
* :func:`shifted_levy` (``benchmarks.resume_determinism``): Levy of x − 0.7 on [-5, 5]^d.
"""
from __future__ import annotations

import argparse
import datetime
import hashlib
import json
import os
import platform
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

import numpy as np

from latentune.checks import file_in_the_way
from latentune.machine import loadavg, machine  # noqa: F401 - re-exported to benchmarks

ROOT = Path(__file__).resolve().parents[1]
"""The repository root (the checkout holding ``benchmarks/``)."""


# ==================================================================== problems
def _rng(name: str) -> np.random.Generator:
    return np.random.default_rng(int(hashlib.sha256(name.encode()).hexdigest()[:12], 16))


def _rotation(rng: np.random.Generator, d: int) -> np.ndarray:
    q, r = np.linalg.qr(rng.standard_normal((d, d)))
    return q * np.sign(np.diag(r))


# ------------------------------------------------------------------ base functions (of z)
def ackley(z):
    d = z.shape[0]
    return -20.0 * np.exp(-0.2 * np.sqrt(np.sum(z ** 2) / d)) - np.exp(
        np.sum(np.cos(2 * np.pi * z)) / d) + 20.0 + np.e


def levy(z):
    w = 1.0 + (z - 1.0) / 4.0
    return (np.sin(np.pi * w[0]) ** 2
            + np.sum((w[:-1] - 1) ** 2 * (1 + 10 * np.sin(np.pi * w[:-1] + 1) ** 2))
            + (w[-1] - 1) ** 2 * (1 + np.sin(2 * np.pi * w[-1]) ** 2))


def rastrigin(z):
    return 10.0 * z.shape[0] + np.sum(z ** 2 - 10.0 * np.cos(2 * np.pi * z))


def rosenbrock(z):
    return np.sum(100.0 * (z[1:] - z[:-1] ** 2) ** 2 + (1 - z[:-1]) ** 2)


ST_MIN = -2.903534027771178


def styblinski_tang(z):
    return 0.5 * np.sum(z ** 4 - 16 * z ** 2 + 5 * z) - 0.5 * z.shape[0] * (
        ST_MIN ** 4 - 16 * ST_MIN ** 2 + 5 * ST_MIN)


def griewank(z):
    i = np.arange(1, z.shape[0] + 1)
    return 1.0 + np.sum(z ** 2) / 4000.0 - np.prod(np.cos(z / np.sqrt(i)))


def ellipsoid(z):
    d = z.shape[0]
    return np.sum(10.0 ** (4.0 * np.arange(d) / max(d - 1, 1)) * z ** 2)


def valleys(z):
    """Sum of narrow curved valleys: 100·(z_2k − sin(π z_2k−1))² + |z_2k−1| over pairs."""
    a, b = z[0::2], z[1::2]
    return np.sum(100.0 * (b - np.sin(np.pi * a)) ** 2 + np.abs(a))


@dataclass
class Problem:
    """One benchmark problem: ``f(u)`` for ``u`` in [0, 1]^dim."""

    name: str
    dim: int
    f: Callable[[np.ndarray], float]
    kind: str                      # "synthetic" or "controller"
    f_min: float | None = 0.0      # known global minimum (None: unknown)
    info: dict = field(default_factory=dict)

    def __call__(self, u: np.ndarray) -> float:
        return float(self.f(np.asarray(u, dtype=float)))


def synthetic(name: str, base, d: int, lo: float, hi: float, z_star: float,
              rotate: bool) -> Problem:
    rng = _rng(name)
    span = hi - lo
    o = lo + span * (0.2 + 0.6 * rng.random(d))
    R = _rotation(rng, d) if rotate else None

    def f(u):
        x = lo + span * u
        dz = x - o
        if R is not None:
            dz = R @ dz
        return base(z_star + dz)

    return Problem(name, d, f, "synthetic", 0.0,
                   dict(base=base.__name__, domain=[lo, hi], rotated=rotate))


# ------------------------------------------------------------------ controllers
def _dlqr(A, B, Q, R):
    from scipy.linalg import solve_discrete_are

    P = solve_discrete_are(A, B, Q, R)
    return np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A)


class _Plant:
    """Unstable discrete linear plant, nominal (A, B) and a perturbed 'true' plant."""

    def __init__(self, name: str, n: int, m: int, cubic: float = 0.0) -> None:
        rng = _rng(name)
        A = rng.standard_normal((n, n)) / np.sqrt(n)
        A *= 1.08 / np.max(np.abs(np.linalg.eigvals(A)))        # spectral radius 1.08
        B = rng.standard_normal((n, m)) / np.sqrt(n)
        self.A, self.B = A, B
        self.A_true = A + 0.03 * rng.standard_normal((n, n)) / np.sqrt(n)
        self.B_true = B * (1.0 + 0.2 * rng.standard_normal((1, m)))
        self.Qc = np.diag(10.0 ** rng.uniform(-1, 1, n))           # the task's true weights
        self.Rc = np.diag(10.0 ** rng.uniform(-1, 1, m))
        self.x0 = rng.standard_normal((4, n)) * 1.5
        self.cubic = cubic
        self.T = 60
        self.n, self.m = n, m

    def cost(self, K: np.ndarray) -> float:
        X = self.x0.copy()                                       # (4, n): 4 runs in parallel
        total = np.zeros(X.shape[0])
        alive = np.ones(X.shape[0], dtype=bool)
        t_fail = np.full(X.shape[0], float(self.T))
        for t in range(self.T):
            U = np.clip(-X @ K.T, -1.0, 1.0)
            total += np.einsum("ij,jk,ik->i", X, self.Qc, X) + np.einsum(
                "ij,jk,ik->i", U, self.Rc, U)
            X = X @ self.A_true.T + U @ self.B_true.T - self.cubic * X ** 3
            bad = alive & ~(np.abs(X).max(1) <= 20.0)
            t_fail[bad] = t + 1
            alive &= ~bad
            X[~alive] = 0.0
        c = np.where(alive, total / self.T, 100.0 * (2.0 - t_fail / self.T))
        return float(np.mean(np.minimum(c, 200.0)))


def lqr16() -> Problem:
    plant = _Plant("lqr16", 12, 4)

    def f(u):
        w = -3.0 + 6.0 * u
        try:
            K = _dlqr(plant.A, plant.B, np.diag(10.0 ** w[:12]), np.diag(10.0 ** w[12:]))
        except (np.linalg.LinAlgError, ValueError):
            return 200.0
        if not np.all(np.isfinite(K)):
            return 200.0
        return plant.cost(K)

    return Problem("lqr16", 16, f, "controller", None, dict(states=12, inputs=4))


def gains24() -> Problem:
    plant = _Plant("gains24", 6, 4, cubic=-0.01)
    K0 = _dlqr(plant.A, plant.B, np.eye(6), np.eye(4))
    scale = 3.0 * np.maximum(np.abs(K0), 0.3)

    def f(u):
        K = K0 + scale * (2.0 * u.reshape(4, 6) - 1.0)
        return plant.cost(K)

    return Problem("gains24", 24, f, "controller", None, dict(states=6, inputs=4))


def problems() -> dict[str, Problem]:
    """All problems of the suite, by name."""
    ps = [
        synthetic("ackley30r", ackley, 30, -10.0, 10.0, 0.0, True),
        synthetic("levy40", levy, 40, -10.0, 10.0, 1.0, False),
        synthetic("rastrigin20r", rastrigin, 20, -5.12, 5.12, 0.0, True),
        synthetic("rosenbrock30", rosenbrock, 30, -5.0, 10.0, 1.0, False),
        synthetic("styblinski50", styblinski_tang, 50, -5.0, 5.0, ST_MIN, False),
        synthetic("griewank60r", griewank, 60, -100.0, 100.0, 0.0, True),
        synthetic("ellipsoid40r", ellipsoid, 40, -5.0, 5.0, 0.0, True),
        synthetic("valleys30r", valleys, 30, -3.0, 3.0, 0.0, True),
        lqr16(),
        gains24(),
    ]
    return {p.name: p for p in ps}


def quick_problems() -> dict[str, Problem]:
    """The quick suite of ``benchmarks.critic``: base functions on their usual domains,
    unshifted and unrotated (minimum 0)."""
    def boxed(name: str, base: Callable[[np.ndarray], float], d: int, lo: float,
              hi: float) -> Problem:
        def f(u: np.ndarray) -> float:
            return float(base(lo + (hi - lo) * u))
        return Problem(name, d, f, "synthetic", 0.0,
                       dict(base=base.__name__, domain=[lo, hi], rotated=False))

    ps = [boxed("ackley20", ackley, 20, -5.0, 10.0), boxed("levy25", levy, 25, -10.0, 10.0),
          boxed("rosenbrock25", rosenbrock, 25, -5.0, 10.0),
          boxed("styblinski77", styblinski_tang, 77, -5.0, 5.0),
          boxed("ackley77", ackley, 77, -5.0, 10.0)]
    return {p.name: p for p in ps}


def shifted_levy(x: np.ndarray) -> float:
    """Levy of ``x - 0.7`` for ``x`` (d,) in [-5, 5]^d (minimum 0 at x = 1.7)."""
    return float(levy(np.asarray(x, dtype=float) - 0.7))


def problem(name: str) -> Problem:
    """A problem of either suite by name (``KeyError`` names the known ones)."""
    allp = {**problems(), **quick_problems()}
    if name not in allp:
        raise KeyError(f"unknown problem {name!r} (known: {', '.join(sorted(allp))})")
    return allp[name]


def median_evals(evals: Sequence[int | None]) -> float:
    """Median of evaluations-to-target over seeds; a seed that never reached it counts as inf."""
    return float(np.median([np.inf if e is None else e for e in evals]))


# ==================================================================== provenance
def git_commit() -> str | None:
    """The checkout's commit (with ``+dirty`` when tracked files changed), or None."""
    try:
        rev = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True,
                             text=True, timeout=20).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(ROOT), "status", "--porcelain",
                                "--untracked-files=no"], capture_output=True, text=True,
                               timeout=20).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return None
    return (rev + ("+dirty" if dirty else "")) if rev else None


def versions(extra: Iterable[str] = ()) -> dict[str, str | None]:
    """The platform's, Python's and the main libraries' versions (None: not installed)."""
    from importlib.metadata import PackageNotFoundError, version

    out: dict[str, str | None] = {"platform": platform.platform(),
                                  "python": platform.python_version()}
    for dist in ("latentune", "numpy", "scipy", "torch", "gpytorch", "botorch", "cma",
                 "optuna", *extra):
        try:
            out[dist] = version(dist)
        except PackageNotFoundError:
            out[dist] = None
    return out


class Provenance:
    """What reproduces a benchmark output, started when the benchmark starts.

    :meth:`finish` returns ``{"command", "commit", "date" (UTC, ISO 8601), "machine",
    "versions", "loadavg_start", "loadavg_end", "wall_s"}``.
    """

    def __init__(self, argv: Sequence[str] | None = None, module: str | None = None) -> None:
        argv = list(sys.argv[1:] if argv is None else argv)
        self.command = " ".join(["python", "-m", module, *argv] if module else
                                ["python", *sys.argv[:1], *argv])
        self.date = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
        self.loadavg_start = loadavg()
        self.t0 = time.perf_counter()

    def finish(self) -> dict[str, Any]:
        return {"command": self.command, "commit": git_commit(), "date": self.date,
                "machine": machine(), "versions": versions(),
                "loadavg_start": self.loadavg_start, "loadavg_end": loadavg(),
                "wall_s": round(time.perf_counter() - self.t0, 3)}


# ==================================================================== entry point
def stdout_closed() -> int:
    """stdout's reader went away (``| head``): stdout is pointed at /dev/null so that nothing
    more is written (nor a traceback at the interpreter's last flush); 141, the exit status of
    ``latentune`` then (a shell's for SIGPIPE)."""
    try:
        fd = os.open(os.devnull, os.O_WRONLY)
        os.dup2(fd, sys.stdout.fileno())
        os.close(fd)
    except (OSError, ValueError, AttributeError):
        pass
    return 141


def cli_main(main: Callable[[], int], prog: str) -> int:
    """Run a benchmark's ``main()`` (every benchmark's ``__main__``): a user error of
    latentune's (a run directory without a store, a bad parameter:
    :class:`latentune.errors.LatentuneError`) or an input file that does not exist (named, or
    the FileNotFoundError's own message when it names none) is one line on stderr and exit 2,
    as argparse's errors are, not a traceback; a closed stdout (``| head``) ends quietly with
    exit 141 (:func:`stdout_closed`). ``prog``: the benchmark's module (``benchmarks.transfer``),
    which the error line names as ``python -m MODULE`` (:func:`error_line`)."""
    from latentune.errors import LatentuneError

    try:
        code = main()
        sys.stdout.flush()                  # a closed pipe is seen here, not at exit
        return code
    except BrokenPipeError:
        return stdout_closed()
    except LatentuneError as e:
        msg = " ".join(str(e).split())
    except FileNotFoundError as e:      # raised with a message of its own: that message
        msg = str(e) if e.filename is None else f"no such file or directory: {e.filename}"
    except OSError as e:
        msg = os_error_line(e)
    error_line(prog, msg)
    return 2


def error_line(module: str, msg: Any) -> None:
    """Print the one error line of the benchmark ``module`` (``benchmarks.transfer``) on stderr,
    named as argparse's own error lines name it (:func:`bench_parser`):
    ``python -m benchmarks.transfer: error: MSG``."""
    print(f"python -m {module}: error: {msg}", file=sys.stderr)


def os_error_line(e: OSError) -> str:
    """One line for a file that could not be read or written (an ``--out`` under a file or in
    a read-only directory, a ``--work`` that is a file): the file of the path that is not a
    directory, a directory given for a file, else the path and the system's reason."""
    name = e.filename
    if name is None:
        return str(e)
    path = Path(name)
    if isinstance(e, (FileExistsError, NotADirectoryError)):
        blocking = file_in_the_way(path)
        if blocking is not None:
            return f"{blocking} is not a directory"
    if isinstance(e, IsADirectoryError):
        return f"{path} is a directory, not a file"
    return f"{path}: {e.strerror or e}"


def refuse_out_of_range(ap: argparse.ArgumentParser, a: argparse.Namespace,
                        **ranges: tuple[Any, Any]) -> None:
    """``ap.error`` (one line, exit 2) for the first option of ``ranges`` (its ``dest``: a
    ``(least, most)`` bound, ``most`` None for none; both inclusive) whose value, or one of its
    values (a list such as ``--seeds``), is out of it; None (an option not given) passes. For
    the counts and seeds a benchmark would otherwise see refused only after it built its
    tasks and rolled out their first trials."""
    for dest, (lo, hi) in ranges.items():
        v = getattr(a, dest)
        for x in v if isinstance(v, list) else [v]:
            if x is not None and not (lo <= x and (hi is None or x <= hi)):
                ap.error(f"--{dest.replace('_', '-')} must be "
                         + (f">= {lo}" if hi is None else f"in [{lo}, {hi}]") + f", got {x}")


# ==================================================================== output
def out_file(text: str) -> Path:
    """An ``--out`` file (argparse ``type``), checked before any work so that a long run does
    not end in a file it cannot write: not a directory, no file among its parents, and its
    nearest existing parent a writable directory (argparse's one-line error otherwise)."""
    path = Path(text)
    if not text.strip():
        raise argparse.ArgumentTypeError("an output file needs a name")
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{path} is a directory, not a file")
    parent = next(p for p in path.absolute().parents if p.exists())
    if not parent.is_dir():
        raise argparse.ArgumentTypeError(f"{parent} is not a directory")
    _refuse_unwritable(parent)
    return path


def out_dir(text: str) -> Path:
    """An output directory (argparse ``type``: ``robot_transfer export --out DIR``), checked
    before any work as :func:`out_file` checks a file: not a file, no file among its parents,
    and the nearest of it and its parents that exists a writable directory (argparse's one-line
    error otherwise). The directory itself is made by the writer."""
    path = Path(text)
    if not text.strip():
        raise argparse.ArgumentTypeError("an output directory needs a name")
    blocking = file_in_the_way(path)
    if blocking is not None:
        raise argparse.ArgumentTypeError(f"{blocking} is not a directory")
    _refuse_unwritable(next(p for p in (path.absolute(), *path.absolute().parents)
                            if p.exists()))
    return path


def _refuse_unwritable(directory: Path) -> None:
    """argparse's error when files cannot be made in the existing ``directory``."""
    if not os.access(directory, os.W_OK | os.X_OK):
        raise argparse.ArgumentTypeError(f"{directory}: Permission denied")


def bench_parser(module: str, description: str | None = None,
                 **kw: Any) -> argparse.ArgumentParser:
    """The argument parser of the benchmark ``module`` (``benchmarks.transfer``; a subcommand's
    parser adds its name: ``benchmarks.transfer_falls ladder``): its usage and error lines name
    the command as it is run, ``python -m benchmarks.transfer``, not argparse's default, the
    file's name (``transfer.py``, which is not a command one can run). ``kw``: more of
    :class:`argparse.ArgumentParser`'s arguments."""
    return argparse.ArgumentParser(prog=f"python -m {module}", description=description, **kw)


def add_out_arg(parser: argparse.ArgumentParser) -> None:
    """``--out FILE.json``: the one output option of every benchmark (:func:`out_file`)."""
    parser.add_argument("--out", type=out_file, default=None, metavar="FILE.json",
                        help="also write the results and their provenance to this JSON file")


def _cell(v: Any) -> str:
    if v is None:
        return "–"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, (float, np.floating)):
        v = float(v)
        if not np.isfinite(v):
            return str(v)
        return f"{v:.4g}"
    return str(v)


def markdown_table(rows: Sequence[dict[str, Any]], columns: Sequence[str] | None = None) -> str:
    """A Markdown table of ``rows`` (dicts; ``columns`` default: the first row's keys)."""
    if not rows:
        return "(no rows)"
    cols = list(columns or rows[0].keys())
    lines = ["| " + " | ".join(cols) + " |", "|" + "|".join("---" for _ in cols) + "|"]
    lines += ["| " + " | ".join(_cell(r.get(c)) for c in cols) + " |" for r in rows]
    return "\n".join(lines)


def _json_default(v: Any) -> Any:
    if isinstance(v, (np.integer,)):
        return int(v)
    if isinstance(v, (np.floating,)):
        return float(v)
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, Path):
        return str(v)
    raise TypeError(f"not JSON serializable: {type(v).__name__}")


def write_text(path: Path | str, text: str) -> Path:
    """Write an output text file (a ``--md`` table) to ``path``, parents created; return it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def write_json(path: Path | str, results: dict[str, Any], prov: Provenance | dict[str, Any]
               ) -> Path:
    """Write ``{**results, "provenance": ...}`` to ``path`` (parents created); return it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    p = prov.finish() if isinstance(prov, Provenance) else prov
    path.write_text(json.dumps({**results, "provenance": p}, indent=1,
                               default=_json_default) + "\n")
    return path


def finish(out: Path | str | None, prov: Provenance, results: dict[str, Any],
           rows: Sequence[dict[str, Any]], columns: Sequence[str] | None = None,
           title: str | None = None) -> dict[str, Any]:
    """The end of every benchmark: print ``title`` and the Markdown table of ``rows`` on stdout,
    and write ``results`` (with ``"rows"`` when absent) and the provenance to ``out`` if given.
    Returns the written object."""
    if title:
        print(f"### {title}\n")
    print(markdown_table(rows, columns), flush=True)
    obj = {**results}
    obj.setdefault("rows", list(rows))
    p = prov.finish()
    if out is not None:
        write_json(out, obj, p)
        print(f"\nwritten: {out}")
    return {**obj, "provenance": p}
