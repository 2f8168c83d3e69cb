"""Which of the source's standing θ stand on a target after the source's record fell there: what
a walk down the record (``record_walk``) can know before it asks, measured on the stored runs.

    python -m benchmarks.transfer_walk [--runs results/transfer/rebuilt/runs ...]
        [--sources runs/transfer_skx] [--systems ...] [--seeds 0 1 ...] [--steps 3]
        [--out F.json] [--md F.md]

For every stored run of the default phase 3 (``--method``, the traces under ``--runs``:
``<system>/gap<g>/seed<s>/<method>[@avx512].json``) in which the source's record fell on the
target (the zero-shot θ, trial 0, and the design's elites, trials 2 and 3; trial 1 is the
target's manual θ, tried because the zero-shot θ fell), the candidates of the walk are the
source's standing trials (``<sources>/<system>/seed<s>/source``) that no told trial has and that
lie at least ``elite_spacing`` (max-norm, unit box) from the told falls, ranked by their cost on
the model. Every candidate is run once on the target (deterministic; one trial each, cached in
``--cache``). Per run:

* ``stand_rate``: the share of the candidates that stand on the target;
* the AUC of each signal the walk has before it asks (1: every standing candidate scores above
  every falling one; 0.5: no better than chance), with the sign that predicts a stand:
  ``rank`` (better model cost), ``fall_model`` (lower target fall probability: the transfer
  fall model, :class:`~latentune.critic.transfer_model.TargetModel` on the told fall flags with
  ``h = (p_s(θ), 1)`` and the source's fall lengthscales), ``source_fall`` (lower ``p_s(θ)``),
  ``far_falls`` (farther from the told falls, Euclidean in fall lengthscales),
  ``near_manual`` (nearer the manual θ), ``source_margin`` (farther from the source's own
  falls);
* for each walk rule (``RULES``), a simulation of up to ``--steps`` asks, each told before the
  next, stopping at the first stand: the falls it takes, whether it found a stand, and that
  stand's cost over the stored run's best within B (< 1: the walk's first stand already beats
  what the default found in 40 trials).

It reads stored traces and runs single trials; it decides nothing by itself. A rule that does
well here is a candidate for a phase-3 option, to be measured by ``benchmarks.transfer``.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any, Callable

from latentune.threads import one_thread_env

one_thread_env()

import numpy as np  # noqa: E402

from benchmarks.common import (Provenance, add_out_arg, bench_parser, error_line,  # noqa: E402
                               finish, markdown_table)
from benchmarks.common import out_dir, out_file, write_text  # noqa: E402
from benchmarks.transfer import DEFAULT_METHOD, SYSTEMS  # noqa: E402

SPACING = 0.15          # the default elite_spacing (record_walk's distance from told falls)


def load_trace(runs: list[Path], system: str, gap: float, seed: int, method: str
               ) -> dict[str, Any] | None:
    """The stored trace of ``method`` on (system, gap, seed) under the first of ``runs`` that
    has it (the ``@avx512`` name first), or None."""
    for root in runs:
        d = root / system / f"gap{gap:g}" / f"seed{seed}"
        for name in (f"{method}@avx512.json", f"{method}.json"):
            if (d / name).is_file():
                return json.loads((d / name).read_text())
    return None


def runs_by_seed(runs: list[dict[str, Any]], method: str) -> dict[int, dict[str, Any]]:
    """Seed → the run of ``method`` among ``runs`` (an exported robot trace's ``runs``), its
    ``@avx512`` twin read in its place where both are there (as :func:`load_trace`)."""
    out: dict[int, dict[str, Any]] = {}
    for r in runs:
        if r.get("method") == method:
            out.setdefault(int(r["seed"]), r)
    for r in runs:
        if r.get("method") == f"{method}@avx512":
            out[int(r["seed"])] = r
    return out


def record_fell(trace: dict[str, Any]) -> bool:
    """True when the zero-shot θ (trial 0) and the design's elites (trials 2, 3) fell."""
    f = trace["failed"]
    return len(f) >= 4 and bool(f[0] and f[2] and f[3])


def auc(score: np.ndarray, stand: np.ndarray) -> float | None:
    """P(score of a standing candidate > score of a falling one), ties ½; None when one class
    is empty."""
    a, b = score[stand], score[~stand]
    if not len(a) or not len(b):
        return None
    gt = (a[:, None] > b[None, :]).mean()
    eq = (a[:, None] == b[None, :]).mean()
    return float(gt + 0.5 * eq)


def scaled_min_dist(A: np.ndarray, B: np.ndarray, ls: np.ndarray) -> np.ndarray:
    """(len(A),) Euclidean distance of each row of A to its nearest row of B in units of ``ls``
    (inf where B is empty)."""
    if not len(B):
        return np.full(len(A), np.inf)
    D = ((A[:, None, :] - B[None, :, :]) / ls) ** 2
    return np.sqrt(D.sum(-1)).min(1)


class WalkCase:
    """One run where the record fell: the told trials, the candidates and what the walk knows.

    Args:
        Xt: (4, d) the told θ; ``ft`` (4,) their fall flags.
        S: (m, d) the candidates, best model cost first; ``rank`` (m,) their rank among the
            source's standing trials (0: best).
        stand: (m,) True where the candidate stands on the target; ``cost`` (m,) its cost there.
        sm: the source models (:class:`~latentune.critic.transfer_model.SourceModel`).
        manual: (d,) the target's manual θ; ``n_standing`` the source's standing trials.
    """

    def __init__(self, Xt, ft, S, rank, stand, cost, sm, manual, n_standing, src_falls):
        self.Xt, self.ft, self.S, self.rank = Xt, ft, S, rank
        self.stand, self.cost, self.sm, self.manual = stand, cost, sm, manual
        self.n_standing, self.src_falls = n_standing, src_falls

    def fall_model(self, Xt: np.ndarray, ft: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Posterior mean and sd (m,) of the target fall model on the told (Xt, ft)."""
        from latentune.critic.transfer_model import target_fall_model

        m = target_fall_model(Xt, ft, self.sm)
        mu, _ = m.mean_cov(self.S, with_cov=False)
        return np.asarray(mu), np.sqrt(m.variance(self.S))

    def signals(self) -> dict[str, np.ndarray]:
        """Each signal (m,), higher = predicted to stand."""
        ls = self.sm.fall_lengthscales
        mu, _ = self.fall_model(self.Xt, self.ft)
        return {"rank": -self.rank.astype(float), "fall_model": -mu,
                "source_fall": -self.sm.fall_prob(self.S),
                "far_falls": scaled_min_dist(self.S, self.Xt[self.ft], ls),
                "near_manual": -scaled_min_dist(self.S, self.manual[None, :], ls),
                "source_margin": np.minimum(scaled_min_dist(self.S, self.src_falls, ls), 1e9)}


Rule = Callable[[WalkCase, np.ndarray, np.ndarray, np.ndarray, int, int], int | None]
"""(case, admissible (m,) bool, told θ, told falls, step i, steps k) → candidate index."""


def rule_quantile(c: WalkCase, ok, Xt, ft, i, k):
    """``record_walk`` as it is: the best-ranked admissible candidate past rank quantile
    (i + 1)/(k + 1) of the source's standing trials."""
    idx = np.flatnonzero(ok & (c.rank >= int(c.n_standing * (i + 1) / (k + 1))))
    return int(idx[0]) if len(idx) else None


def _least_likely(c: WalkCase, ok, Xt, ft, band: float) -> int | None:
    mu, _ = c.fall_model(Xt, ft)
    idx = np.flatnonzero(ok & (c.rank < max(1, int(c.n_standing * band))))
    if not len(idx):
        return None
    return int(idx[np.lexsort((c.rank[idx], np.round(mu[idx], 3)))[0]])


def rule_fall_model(c, ok, Xt, ft, i, k):
    """The admissible candidate of least target fall probability (3 decimals; ties: best
    rank), over every rank."""
    return _least_likely(c, ok, Xt, ft, 1.0)


def rule_fall_model_half(c, ok, Xt, ft, i, k):
    """As ``fall_model`` within the better half of the ranks."""
    return _least_likely(c, ok, Xt, ft, 0.5)


def rule_far(c, ok, Xt, ft, i, k):
    """Within the better half of the ranks, the admissible candidate farthest from the told
    falls (fall lengthscales)."""
    idx = np.flatnonzero(ok & (c.rank < max(1, c.n_standing // 2)))
    if not len(idx):
        return None
    d = scaled_min_dist(c.S[idx], Xt[ft], c.sm.fall_lengthscales)
    return int(idx[np.argmax(d)])


def rule_quantile_far(c, ok, Xt, ft, i, k):
    """In the rank band of step i (quantiles (i + 1)/(k + 1) to (i + 2)/(k + 1)), the admissible
    candidate farthest from the told falls."""
    lo, hi = int(c.n_standing * (i + 1) / (k + 1)), int(c.n_standing * (i + 2) / (k + 1))
    idx = np.flatnonzero(ok & (c.rank >= lo) & (c.rank < hi))
    if not len(idx):
        return None
    d = scaled_min_dist(c.S[idx], Xt[ft], c.sm.fall_lengthscales)
    return int(idx[np.argmax(d)])


def rule_band_fall_model(c, ok, Xt, ft, i, k):
    """In the rank band of step i (as ``quantile_far``), the admissible candidate of least
    target fall probability."""
    lo, hi = int(c.n_standing * (i + 1) / (k + 1)), int(c.n_standing * (i + 2) / (k + 1))
    idx = np.flatnonzero(ok & (c.rank >= lo) & (c.rank < hi))
    if not len(idx):
        return None
    mu, _ = c.fall_model(Xt, ft)
    return int(idx[np.lexsort((c.rank[idx], np.round(mu[idx], 3)))[0]])


def _screened_best(c, ok, Xt, ft, p: float) -> int | None:
    idx = np.flatnonzero(ok)
    if not len(idx):
        return None
    mu, _ = c.fall_model(Xt, ft)
    keep = idx[mu[idx] <= np.quantile(mu[idx], p)]
    return int(keep[np.argmin(c.rank[keep])])


def rule_screen_half(c, ok, Xt, ft, i, k):
    """The best-ranked admissible candidate whose target fall probability is at most the
    median of the admissible candidates'."""
    return _screened_best(c, ok, Xt, ft, 0.5)


def rule_screen_quarter(c, ok, Xt, ft, i, k):
    """As ``screen_half`` with the lower quartile."""
    return _screened_best(c, ok, Xt, ft, 0.25)


def rule_screen_tenth(c, ok, Xt, ft, i, k):
    """As ``screen_half`` with the lowest tenth."""
    return _screened_best(c, ok, Xt, ft, 0.1)


RULES: dict[str, Rule] = {"quantile": rule_quantile, "fall_model": rule_fall_model,
                          "fall_model_half": rule_fall_model_half, "far": rule_far,
                          "quantile_far": rule_quantile_far,
                          "band_fall_model": rule_band_fall_model,
                          "screen_half": rule_screen_half, "screen_quarter": rule_screen_quarter,
                          "screen_tenth": rule_screen_tenth}


def simulate(c: WalkCase, rule: Rule, steps: int) -> tuple[int, int | None]:
    """(falls, index of the first standing candidate or None) of ``rule`` over ``steps`` asks."""
    Xt, ft = c.Xt.copy(), c.ft.copy()
    ok = np.ones(len(c.S), dtype=bool)
    falls = 0
    for i in range(steps):
        if ft.any():
            ok &= np.abs(c.S[:, None, :] - Xt[ft][None]).max(-1).min(1) >= SPACING
        j = rule(c, ok, Xt, ft, i, steps)
        if j is None:
            break
        ok[j] = False
        if c.stand[j]:
            return falls, j
        falls += 1
        Xt, ft = np.vstack([Xt, c.S[j]]), np.append(ft, True)
    return falls, None


def build_case(system: str, gap: float, seed: int, trace: dict[str, Any], sources: Path,
               cache: Path) -> WalkCase | None:
    """The walk's view of one run (None without a source run or candidates)."""
    from latentune.critic.transfer import canonical_order
    from latentune.pipeline.baselines import source_trials
    from latentune.critic.transfer_model import SourceModel
    from latentune.system import evaluate

    src = sources / system / f"seed{seed}" / "source"
    if not (src / "run.db").is_file():
        return None
    X, y, f = source_trials(src)
    o = canonical_order(X, y, f)
    X, y, f = X[o], y[o], f[o]
    ok = np.flatnonzero(~f)
    S_all = X[ok]                                   # canonical order: best model cost first
    Xt = np.asarray(trace["thetas"][:4], dtype=float)
    ft = np.asarray(trace["failed"][:4], dtype=bool)
    taken = np.array([np.abs(Xt - s).max(1).min() <= 1e-9 for s in S_all])
    near = np.abs(S_all[:, None, :] - Xt[ft][None]).max(-1).min(1) < SPACING
    keep = np.flatnonzero(~taken & ~near)
    if not len(keep):
        return None
    S = S_all[keep]
    f_cache = cache / system / f"gap{gap:g}" / f"seed{seed}.npz"
    z = np.load(f_cache) if f_cache.is_file() else None
    if z is not None and np.array_equal(z["S"], S):
        stand, cost = z["stand"], z["cost"]
    else:                               # no cache, or one made for other candidates: run them
        target = SYSTEMS[system]["target"](gap)
        outs = [evaluate(target, s) for s in S]
        stand = np.array([not o.failed for o in outs], dtype=bool)
        cost = np.array([o.cost for o in outs], dtype=float)
        f_cache.parent.mkdir(parents=True, exist_ok=True)
        np.savez(f_cache, S=S, stand=stand, cost=cost)
    sm = SourceModel(X, y, f, seed=seed)
    return WalkCase(Xt, ft, S, keep, stand, cost, sm, Xt[1], len(S_all), X[f])


def study(runs: list[Path], sources: Path, cache: Path, systems: list[str],
          gaps: dict[str, list[float]] | None, seeds: list[int], method: str, steps: int
          ) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """(one row per run where the record fell, one summary row per system and overall)."""
    rows: list[dict[str, Any]] = []
    for system in systems:
        for gap in (gaps or {}).get(system, SYSTEMS[system]["gaps"]):
            for seed in seeds:
                tr = load_trace(runs, system, float(gap), seed, method)
                if tr is None or not record_fell(tr):
                    continue
                c = build_case(system, float(gap), seed, tr, sources, cache)
                if c is None:
                    continue
                c_run = [v for v, fl in zip(tr["costs"], tr["failed"]) if not fl]
                best_run = min(c_run) if c_run else float("inf")
                row: dict[str, Any] = {"system": system, "gap": float(gap), "seed": seed,
                                       "candidates": len(c.S),
                                       "stand_rate": float(c.stand.mean()),
                                       "run_best": best_run}
                for name, s in c.signals().items():
                    row[f"auc_{name}"] = auc(s, c.stand)
                for name, rule in RULES.items():
                    falls, j = simulate(c, rule, steps)
                    row[f"{name}_falls"] = falls
                    row[f"{name}_stood"] = j is not None
                    row[f"{name}_vs_run"] = (float(c.cost[j] / best_run)
                                             if j is not None and np.isfinite(best_run)
                                             else None)
                rows.append(row)
    return rows, (summarize(rows) if rows else [])


def summarize(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per system and over all runs: medians of the AUCs, walk falls summed, stands counted,
    the median first-stand cost over the run's best."""
    out = []
    groups = sorted({r["system"] for r in rows}) + ["all"]
    for g in groups:
        rs = [r for r in rows if g in ("all", r["system"])]
        s: dict[str, Any] = {"system": g, "runs": len(rs),
                             "stand_rate": float(np.median([r["stand_rate"] for r in rs]))}
        for k in [k for k in rs[0] if k.startswith("auc_")]:
            v = [r[k] for r in rs if r[k] is not None]
            s[k] = float(np.median(v)) if v else None
        for name in RULES:
            s[f"{name}_falls"] = int(sum(r[f"{name}_falls"] for r in rs))
            s[f"{name}_stood"] = int(sum(r[f"{name}_stood"] for r in rs))
            v = [r[f"{name}_vs_run"] for r in rs if r[f"{name}_vs_run"] is not None]
            s[f"{name}_vs_run"] = float(np.median(v)) if v else None
        out.append(s)
    return out


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    prov = Provenance(argv, "benchmarks.transfer_walk")
    ap = bench_parser("benchmarks.transfer_walk", description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=Path, nargs="+",
                    default=[Path("results/transfer/rebuilt/runs")])
    ap.add_argument("--sources", type=Path, default=Path("runs/transfer_skx"))
    ap.add_argument("--cache", type=out_dir, default="runs/transfer_walk")
    ap.add_argument("--systems", nargs="+", default=list(SYSTEMS), choices=list(SYSTEMS))
    ap.add_argument("--gaps", nargs="+", type=float, default=None,
                    help="gaps (the same for every system) instead of each system's ladder")
    ap.add_argument("--seeds", nargs="+", type=int, default=list(range(10)))
    ap.add_argument("--method", default=DEFAULT_METHOD)
    ap.add_argument("--steps", type=int, default=3)
    add_out_arg(ap)
    ap.add_argument("--md", type=out_file, default=None, metavar="FILE.md")
    a = ap.parse_args(argv)
    if a.steps < 1:
        error_line("benchmarks.transfer_walk", "--steps takes a count ≥ 1")
        return 2
    missing = [str(r) for r in a.runs if not r.is_dir()]
    if missing:
        error_line("benchmarks.transfer_walk", f"no runs directory {', '.join(missing)}")
        return 2
    gaps = None if a.gaps is None else {s: list(a.gaps) for s in a.systems}
    rows, summary = study(a.runs, a.sources, a.cache, a.systems, gaps, a.seeds, a.method,
                          a.steps)
    if not rows:
        error_line("benchmarks.transfer_walk", "no stored run in which the source's record "
                   f"fell (or no source run under {a.sources})")
        return 2
    finish(a.out, prov, {"runs": [str(r) for r in a.runs], "sources": str(a.sources),
                         "method": a.method, "steps": a.steps, "summary": summary}, rows)
    if a.md is not None:
        write_text(a.md, f"`{prov.command}`\n\n{markdown_table(summary)}\n")
    return 0


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.transfer_walk"))
