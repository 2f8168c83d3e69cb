"""Transfer-critic variants at the paper's phase-3 budget on synthetic source/target pairs whose
optimum lies next to a fall boundary (the A1 jump's situation: ``results/paper10k/a1``).

    python -m benchmarks.transfer_long [--variants default restart=true ...] [--seeds 0 1 ...]
        [--problems cliff:0 cliff:0.02 bowl:0.05 levy:0.05] [--root runs/transfer_long]
        [--out FILE.json] [--md FILE.md]

Problems (d = :data:`D`; each seed draws its own source and target):

* ``cliff``: cost ``C + 10·Σ w_i (θ_i − θ*_i)²`` (``C`` = :data:`CLIFF_OFFSET`: as in the A1
  jump's cost, a large part that no θ changes, so a gain near the optimum is a small fraction of
  the cost; ``w`` log-uniform in [0.3, 3]). The bowl's centre ``θ*`` lies beyond a fall boundary
  ``g(θ) = 0``, ``g(θ) = n·(θ − c) + κ‖(θ − c)_⊥‖² + ρ Σ_i sin(2π θ_i / P + φ_i) / √d`` (``n`` a
  random unit vector; ``c`` 0.15 along ``n`` and 0.2 across it from the box's centre, which
  stands; ``θ* = c + 0.1 n``; κ = :data:`CLIFF_CURVATURE`: about half the box falls; a ripple of
  amplitude ρ = :data:`CLIFF_RIPPLE` and period P = :data:`CLIFF_PERIOD`: next to the boundary,
  which of two close θ falls is not predictable at the scale a fall model resolves). So the
  constrained optimum sits on the boundary, where an optimizer pushes θ (the edge of
  stability). θ with ``g > 0`` falls, cost ``10 C (1 + g)``. The target moves ``c`` and ``θ*``
  by ``gap`` along a random unit vector (``gap`` 0: the target is the source).
* ``bowl`` and ``levy``: :func:`benchmarks.transfer_variants.problem` at d = :data:`D`.

For each (problem, gap, seed): a TuRBO-m source run of :data:`SOURCE` trials (batch
:data:`SOURCE_BATCH`), stored in ``ROOT/sources``; then the zero-shot trial (the source's best θ)
and :data:`B` target trials in batches of :data:`BATCH` of each variant. Every run's trace (cost,
fall flag and trust-region side per trial) is stored in ``ROOT/<problem>/gap<g>/seed<s>/<variant>
.json`` and reused when present. A variant is ``default`` or ``option=value[:option=value]`` of
:data:`latentune.critic.transfer.TRANSFER_DEFAULTS`.

Per (problem, variant) the table gives medians over seeds: the best cost that did not fall
after 40, 100 and ``B`` trials (the zero-shot trial counts as trial 0), the gain over the
zero-shot cost, the gain from trial :data:`LATE` to ``B``, falls per 100 trials, falls after
trial :data:`LATE`, the first trial asked at
the smallest side, the fall rate of the trials asked at the smallest side (pooled), and the
seeds on which the variant's best after ``B`` trials is lower / equal / higher than the
default's.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

from latentune.threads import one_thread_env

one_thread_env()

import numpy as np  # noqa: E402

from benchmarks.common import Provenance, add_out_arg, bench_parser, finish  # noqa: E402
from benchmarks.common import out_file, write_text  # noqa: E402

D, SOURCE, SOURCE_BATCH, B, BATCH, LATE = 20, 1000, 20, 220, 4, 72
CHECKPOINTS = (40, 100, B)
PROBLEMS = ("cliff:0", "cliff:0.02", "bowl:0.05", "levy:0.05")
CLIFF_CURVATURE = 0.1
CLIFF_OFFSET = 100.0
CLIFF_RIPPLE, CLIFF_PERIOD = 0.003, 0.02


def cliff(gap: float, rng: np.random.Generator):
    """(source, target) of the ``cliff`` family: each maps θ (n, D) to (cost (n,), fell (n,))."""
    n = rng.standard_normal(D)
    n /= np.linalg.norm(n)
    t = rng.standard_normal(D)
    t -= (t @ n) * n
    c = 0.5 + 0.15 * n + 0.2 * t / np.linalg.norm(t)
    w = np.exp(rng.uniform(np.log(0.3), np.log(3.0), D))
    u = rng.standard_normal(D)
    u /= np.linalg.norm(u)
    phase = rng.uniform(0, 2 * np.pi, D)

    def f(X: np.ndarray, centre: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        dx = X - centre
        s = dx @ n
        g = s + CLIFF_CURVATURE * ((dx - s[:, None] * n[None, :]) ** 2).sum(1) + \
            CLIFF_RIPPLE * np.sin(2 * np.pi * X / CLIFF_PERIOD + phase).sum(1) / np.sqrt(D)
        q = (w * (X - centre - 0.1 * n) ** 2).sum(1)
        fell = g > 0
        return np.where(fell, 10.0 * CLIFF_OFFSET * (1.0 + g), CLIFF_OFFSET + 10.0 * q), fell
    return (lambda X: f(X, c)), (lambda X: f(X, c + gap * u))


def problem(name: str, gap: float, seed: int):
    """(source, target) of (problem, gap, seed)."""
    rng = np.random.default_rng([seed, 99])
    if name == "cliff":
        return cliff(gap, rng)
    from benchmarks.transfer_variants import problem as short_problem

    return short_problem(name, gap, rng, d=D)


def source(name: str, gap: float, seed: int, root: Path
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The source run of (problem, gap, seed), ``(X, y, fell)``: TuRBO-m from the box's centre,
    stored in ``root/sources`` and read from there when present."""
    from latentune.critic.turbo import TurboM, regions_for_budget

    path = root / "sources" / f"{name}_gap{gap:g}_seed{seed}.npz"
    if path.exists():
        z = np.load(path)
        return z["X"], z["y"], z["fell"]
    src, _ = problem(name, gap, seed)
    s = TurboM(D, batch_size=SOURCE_BATCH, seed=seed, x0=np.full(D, 0.5),
               n_regions=regions_for_budget(SOURCE))
    while s.n_told < SOURCE:
        X = s.ask()
        y, f = src(X)
        s.tell(X, y, s.last_tags, fell=f)
    X, y = np.asarray(s.X), np.asarray(s.y)
    fell = src(X)[1]
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, X=X, y=y, fell=fell)
    return X, y, fell


def run(variant: str, name: str, gap: float, seed: int, root: Path) -> dict[str, Any]:
    """The zero-shot trial and ``B`` target trials of ``variant``: its trace (stored, or read
    when stored): ``zero_shot`` cost, per trial ``cost``, ``fell`` and ``length`` (the side the
    trial was asked at)."""
    from benchmarks.transfer import LADDER_BASE, parse_variant
    from latentune.critic.transfer import Transfer

    path = root / name / f"gap{gap:g}" / f"seed{seed}" / f"{variant}.json"
    if path.exists():
        return json.loads(path.read_text())
    Xs, ys, fs = source(name, gap, seed, root)
    _, tgt = problem(name, gap, seed)
    best = Xs[np.argmin(np.where(fs, np.inf, ys))]
    opts = {**LADDER_BASE, **({} if variant == "default" else parse_variant(variant))}
    cr = Transfer((Xs, ys, fs), None, np.full(D, 0.5), batch_size=BATCH, seed=seed, **opts)
    y0, f0 = tgt(best[None])
    cr.tell(best[None], y0, fell=f0)
    costs: list[float] = []
    falls: list[bool] = []
    lengths: list[float] = []
    while len(costs) < B:
        X = cr.ask(BATCH)
        y, f = tgt(X)
        cr.tell(X, y, cr.last_tags, fell=f)
        costs += [float(v) for v in y]
        falls += [bool(v) for v in f]
        lengths += [float(cr.decisions[-1].get("length", float("nan")))] * len(y)
    out = {"variant": variant, "problem": name, "gap": gap, "seed": seed,
           "zero_shot": float(y0[0]), "zero_shot_fell": bool(f0[0]), "cost": costs[:B],
           "fell": falls[:B], "length": lengths[:B],
           "restarts": int(cr.decisions[-1].get("restarts", 0))}
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(out))
    return out


def best_after(tr: dict[str, Any], t: int) -> float:
    """The best cost that did not fall among the zero-shot trial and the first ``t`` trials."""
    ok = [c for c, f in zip(tr["cost"][:t], tr["fell"][:t]) if not f]
    z = [] if tr["zero_shot_fell"] else [tr["zero_shot"]]
    return float(min(ok + z, default=float("nan")))


def summarize(traces: list[dict[str, Any]], length_min: float) -> dict[str, Any]:
    """Medians over the seeds' ``traces`` of one (problem, variant) (module docstring)."""
    row: dict[str, Any] = {f"best@{t}": float(np.median([best_after(tr, t) for tr in traces]))
                           for t in CHECKPOINTS}
    row["gain@220"] = float(np.median([tr["zero_shot"] - best_after(tr, B) for tr in traces]))
    row[f"gain after {LATE}"] = float(np.median([best_after(tr, LATE) - best_after(tr, B)
                                                for tr in traces]))
    row["falls/100"] = float(np.median([100.0 * np.mean(tr["fell"]) for tr in traces]))
    row[f"falls after {LATE}"] = float(np.median([sum(tr["fell"][LATE:]) for tr in traces]))
    at_min = [np.asarray(tr["length"]) <= length_min * (1 + 1e-9) for tr in traces]
    firsts = [int(np.argmax(m)) + 1 if m.any() else B + 1 for m in at_min]
    row["first trial at L_min"] = float(np.median(firsts))
    n_min = sum(int(m.sum()) for m in at_min)
    f_min = sum(int(np.asarray(tr["fell"])[m].sum()) for tr, m in zip(traces, at_min))
    row["trials at L_min"] = n_min
    row["fall rate at L_min"] = f_min / n_min if n_min else None
    row["restarts"] = float(np.median([tr["restarts"] for tr in traces]))
    return row


def by_length(traces: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Trials, falls and fall rate per trust-region side (log2 L), pooled over ``traces``, with
    the first and last trial (1-based) any seed asked at that side."""
    L = np.concatenate([np.asarray(tr["length"]) for tr in traces])
    F = np.concatenate([np.asarray(tr["fell"]) for tr in traces])
    T = np.concatenate([np.arange(1, len(tr["length"]) + 1) for tr in traces])
    return [{"log2 L": round(float(np.log2(v)), 3), "trials": int((L == v).sum()),
             "falls": int(F[L == v].sum()), "rate": float(F[L == v].mean()),
             "first trial": int(T[L == v].min()), "last trial": int(T[L == v].max())}
            for v in np.unique(L[np.isfinite(L)])[::-1]]


def main(argv: list[str] | None = None) -> int:
    from latentune.critic.transfer import TRANSFER_DEFAULTS

    from benchmarks.transfer import parse_variant

    prov = Provenance(argv, "benchmarks.transfer_long")
    ap = bench_parser("benchmarks.transfer_long", description=__doc__.splitlines()[0])
    ap.add_argument("--variants", nargs="+", default=["default"])
    ap.add_argument("--seeds", nargs="+", type=int, default=list(range(8)))
    ap.add_argument("--problems", nargs="+", default=list(PROBLEMS))
    ap.add_argument("--root", type=Path, default=Path("runs/transfer_long"))
    ap.add_argument("--md", type=out_file, default=None, help="also write the table to this file")
    add_out_arg(ap)
    a = ap.parse_args(argv)
    rows: list[dict[str, Any]] = []
    sides: list[dict[str, Any]] = []
    for prob in a.problems:
        name, _, g = prob.partition(":")
        gap = float(g or 0)
        base = [run("default", name, gap, s, a.root) for s in a.seeds]
        for v in a.variants:
            traces = [run(v, name, gap, s, a.root) for s in a.seeds]
            opts = {} if v == "default" else parse_variant(v)
            lmin = float(opts.get("length_min", TRANSFER_DEFAULTS["length_min"]))
            diff = np.sign([best_after(t, B) - best_after(t0, B) for t, t0 in zip(traces, base)])
            sides.append({"problem": name, "gap": gap, "variant": v, "sides": by_length(traces)})
            rows.append({"problem": name, "gap": gap, "variant": v,
                         **summarize(traces, lmin),
                         "w/t/l vs default": f"{(diff < 0).sum()}/{(diff == 0).sum()}/"
                                             f"{(diff > 0).sum()}"})
            print(rows[-1], flush=True)
    res = finish(a.out, prov, {"seeds": a.seeds, "budget": B, "batch": BATCH, "dim": D,
                               "source_trials": SOURCE, "by_length": sides}, rows,
                 title="transfer variants at the long budget")
    if a.md is not None:
        from benchmarks.common import markdown_table

        shown = [{k: f"{v:.4f}" if k.startswith(("best", "gain")) else v for k, v in r.items()}
                 for r in rows]
        parts = [f"# Transfer variants at the long budget\n\nCommand: "
                 f"`{res['provenance']['command']}`\n\n{markdown_table(shown)}\n",
                 "## Falls by trust-region side (all seeds pooled)\n"]
        parts += [f"### {s['problem']} gap {s['gap']:g}, {s['variant']}\n\n"
                  f"{markdown_table(s['sides'])}\n" for s in sides]
        write_text(a.md, "\n".join(parts))
    return 0


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.transfer_long"))
