"""Rollout identity: exact digests of rollouts, to show a speed-up changes no number.

    python -m benchmarks.rollout_identity [--steps 300] [--per-task 3] [--tasks a1:trot,...]
        [--out FILE.json]
    python -m benchmarks.rollout_identity --compare A.json B.json

For each task (``robot:gait``, the paper's actor of the robot: convex MPC for A1 and B1,
kino-dynamic MPC for Solo12) and each of ``--per-task`` θ (the manual θ, then alternately the
manual θ with N(0, 0.05²) noise on the unit box and a uniform θ, from ``default_rng(0)``), one
recorded rollout of ``--steps`` steps; its digest holds the cost, mean_vx and mean_height as
``float.hex`` (exact), fell, fall_step, steps, reason, the SHA-256 of each trace array (t, vel,
pos, rpy, height as float64 bytes) and of every torque the actor commanded ((steps, 12) float64).
The unrecorded cost (``Task.evaluate``, what tuning runs store) is checked equal to the recorded
one. ``--compare`` prints which digests differ between two output files (exit 1 if any).

The output also records :func:`environment` (the libraries that compute the numbers, the CPU's
vector extension) and the directory ``latentune`` was imported from: bits are only comparable in
one environment. ``tests/data/rollout_golden.json`` (and ``rollout_golden_avx2.json``, made the
same way on an AVX2 machine) is this benchmark's output
(``--steps 500 --per-task 7``) on main's code before the rollout speed-up (an export of commit
7f6b88a on ``PYTHONPATH``); ``tests/test_rollout_identity.py`` recomputes it.
"""
from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path
from typing import Any

from latentune.threads import one_thread_env  # noqa: E402

one_thread_env()

import numpy as np  # noqa: E402

from benchmarks.common import (Provenance, add_out_arg, bench_parser, error_line,  # noqa: E402
                               finish, machine, versions)

ROBOT_ACTOR = {"a1": "convex", "b1": "convex", "solo12": "kinodynamic"}
DEFAULT_TASKS = "a1:trot,a1:jump,solo12:trot"


def _sha(a: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(a, dtype=np.float64).tobytes()).hexdigest()


def _numpy_dispatch() -> list[str]:
    """The SIMD targets numpy dispatches to on this CPU (its ``__cpu_dispatch__`` the CPU has):
    two CPUs with AVX-512 can still take different kernels (``AVX512_ICL`` or not)."""
    from numpy._core._multiarray_umath import __cpu_dispatch__, __cpu_features__

    return sorted(k for k in __cpu_dispatch__ if __cpu_features__.get(k))


def _blas_kernel() -> str | None:
    """The kernel family numpy's OpenBLAS chose for this CPU (``threadpoolctl``), or None."""
    try:
        from threadpoolctl import threadpool_info
    except ImportError:
        return None
    arch = [i.get("architecture") for i in threadpool_info() if i.get("internal_api") == "openblas"]
    return arch[0] if arch else None


def environment() -> dict[str, Any]:
    """What the digests depend on besides the code: Python, the numerical libraries' versions,
    the CPU's widest vector extension, the SIMD targets numpy dispatches to and the BLAS kernel
    family (the last two tell apart CPUs that share the widest extension but not its kernels)."""
    v = versions(("pybullet", "pin", "crocoddyl", "daqp"))
    return {"python": v["python"], **{k: v[k] for k in ("numpy", "pybullet", "pin", "crocoddyl",
                                                         "daqp")}, "simd": machine()["simd"],
            "numpy_dispatch": _numpy_dispatch(), "blas_kernel": _blas_kernel()}


def thetas(task: Any, n: int, seed: int = 0) -> np.ndarray:
    """(n, d) unit-box θ: the manual θ, then alternately a perturbed manual and a uniform θ."""
    rng = np.random.default_rng(seed)
    d = task.space.dim
    out = [np.asarray(task.space.manual, dtype=float)]
    for i in range(1, n):
        if i % 2:
            out.append(np.clip(task.space.manual + 0.05 * rng.standard_normal(d), 0.0, 1.0))
        else:
            out.append(rng.uniform(0.0, 1.0, d))
    return np.array(out[:n])


def digest(task: Any, theta: np.ndarray) -> dict[str, Any]:
    """Exact digest of one recorded rollout of ``task`` at unit-box ``theta`` (see the module
    docstring), and its wall time [s] (not part of the digest)."""
    world = task.world
    taus: list[np.ndarray] = []
    apply = world.apply

    def recording_apply(tau: np.ndarray) -> None:
        taus.append(np.array(tau, dtype=np.float64))
        apply(tau)

    world.apply = recording_apply
    try:
        res = task.rollout(theta, record=True)
    finally:
        del world.apply
    plain = task.evaluate(theta)
    if plain.cost != res.cost or plain.failed != res.fell:
        raise AssertionError(f"recorded and unrecorded rollouts differ: {res.cost!r} "
                             f"{plain.cost!r}")
    d = {"cost": float(res.cost).hex(), "fell": bool(res.fell), "fall_step": res.fall_step,
         "steps": int(res.steps), "mean_vx": float(res.mean_vx).hex(),
         "mean_height": float(res.mean_height).hex(), "reason": res.reason,
         "torques": _sha(np.array(taus).reshape(-1, 12)) if taus else None}
    d.update({f"trace_{k}": _sha(v) for k, v in sorted(res.trace.items())})
    return {"digest": d, "cost": float(res.cost), "wall_s": res.wall_s}


def run(tasks: list[tuple[str, str]], steps: int, per_task: int) -> list[dict[str, Any]]:
    """One row per (task, θ): robot, gait, actor, θ index, θ (unit box), digest, cost, wall_s."""
    from latentune.task import Task

    rows = []
    for robot, gait in tasks:
        task = Task(robot, gait, actor=ROBOT_ACTOR[robot], steps=steps)
        for i, th in enumerate(thetas(task, per_task)):
            r = digest(task, th)
            rows.append({"robot": robot, "gait": gait, "actor": task.actor, "theta_index": i,
                         "theta": th.tolist(), **r})
        task.world.close()
    return rows


def compare(a: dict[str, Any], b: dict[str, Any]) -> list[str]:
    """Lines naming every (task, θ) whose digests differ between outputs a and b (θ too)."""
    def key(r: dict[str, Any]) -> tuple:
        return r["robot"], r["gait"], r["theta_index"]

    ra, rb = {key(r): r for r in a["rows"]}, {key(r): r for r in b["rows"]}
    bad = [f"{k}: only in one file" for k in sorted(set(ra) ^ set(rb))]
    for k in sorted(set(ra) & set(rb)):
        if ra[k]["theta"] != rb[k]["theta"]:
            bad.append(f"{k}: different θ")
        diff = [f for f in ra[k]["digest"] if ra[k]["digest"][f] != rb[k]["digest"].get(f)]
        if diff:
            bad.append(f"{k}: {', '.join(diff)} differ")
    return bad


def main(argv: list[str] | None = None) -> int:
    prov = Provenance(argv, "benchmarks.rollout_identity")
    ap = bench_parser("benchmarks.rollout_identity", description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=300)
    ap.add_argument("--per-task", type=int, default=3)
    ap.add_argument("--tasks", default=DEFAULT_TASKS,
                    help="comma-separated robot:gait (robots: a1, b1, solo12)")
    ap.add_argument("--compare", nargs=2, metavar="FILE", type=Path)
    add_out_arg(ap)
    a = ap.parse_args(argv)
    if a.compare:
        objs = [json.loads(p.read_text()) for p in a.compare]
        bad = compare(*objs)
        n = len(objs[0]["rows"])
        print("\n".join(bad) if bad else f"all {n} digests identical")
        return 1 if bad else 0
    try:
        tasks = [tuple(t.split(":")) for t in a.tasks.split(",")]
        if any(len(t) != 2 or t[0] not in ROBOT_ACTOR for t in tasks):
            raise ValueError
    except ValueError:
        error_line("benchmarks.rollout_identity",
                   f"--tasks must be robot:gait pairs with robots in "
                   f"{', '.join(ROBOT_ACTOR)}, got {a.tasks!r}")
        return 2
    rows = run(tasks, a.steps, a.per_task)  # type: ignore[arg-type]
    import latentune

    out = {"steps": a.steps, "per_task": a.per_task, "tasks": a.tasks,
           "latentune_src": str(Path(latentune.__file__).resolve().parent),
           "environment": environment(), "rows": rows}
    table = [{"task": f"{r['robot']} {r['gait']}", "theta": r["theta_index"],
              "cost": r["cost"], "fell": r["digest"]["fell"], "steps": r["digest"]["steps"],
              "wall_s": r["wall_s"]} for r in rows]
    finish(a.out, prov, out, table, columns=["task", "theta", "cost", "fell", "steps", "wall_s"],
           title=f"rollout digests, {a.steps} steps, {a.per_task} θ per task")
    return 0


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.rollout_identity"))
