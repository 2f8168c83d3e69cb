"""Fall avoidance: falls during tuning and best cost, with and without :class:`FallAware`.

Part ``search`` (default): synthetic problems on [0, 1]^d with a known fall region × critics
{turbo, cma, random} × {plain, fall-aware (``fa``), fall-aware with prior data (``fa+prior``,
only on the problems that define a source)} × seeds, at equal budgets. Each run counts the
evaluations that fell and the best cost of a trial that did not fall. Costs follow latentune's
convention: a trial that did not fall costs less than C1 = 100, one that fell costs
``C1·(1 + depth)`` with ``depth`` in (0, 1] growing with how far inside the fall region it is
(the analogue of ``C1·(2 − k/N)``, an earlier fall costs more).

Problems:

* ``halfspace3`` (d = 3): cost ``10 + 30·|x − x*|²``, falls if ``x0 + x1 > 1.2``; the optimum
  ``x*`` lies just inside (``x0* + x1* = 1.1``). Source (for the prior): the boundary at 1.3.
* ``holes6`` (d = 6): cost ``10 + 30·|x − x*|²``, falls inside any of 12 balls (radius 0.33)
  whose centres lie 0.38–0.55 from the optimum in random directions.
* ``stableball10`` (d = 10): stable only inside a ball of radius 0.35 in the first three
  coordinates (about 80 % of the box falls); the optimum lies at 0.9 of the radius.
* ``controller8`` (d = 8): a linearised cart-pole (M = 1 kg, m = 0.1 kg, l = 0.5 m) moving the
  cart 0.5 m in 5 s (dt 0.02 s) with a push at 2 s; θ = four state-feedback gains (±0.8 decades
  around an LQR gain), a first-order filter on the command, a force limit (5–30 N), the time
  constant of the reference (0.05–1.55 s) and an extra rate gain. Falls when the pole tilts
  beyond 0.6 rad or the cart leaves ±2.5 m (about 60 % of the box). Cost ``10 + 400·mean
  squared error`` (capped below C1); source: a pole 30 % longer.

The prior of ``fa+prior``: ``--prior-n`` evaluations of a plain TuRBO-m run on the source
problem (seed 1000), their θ and fell flags (the analogue of a source run's phase 1).

Part ``classifiers``: the candidate fall classifiers on the same kinds of regions (half-space,
ball, outside a ball, a gain product), d ∈ {3, 10}, training sets like an optimizer's (30 %
uniform, 70 % clustered along a random path), with and without label noise near the boundary;
test points near the training points and uniform. Reports log loss, Brier score, the share of
falling test points let through (p ≤ 0.5) and of stable ones rejected, and the fit time.

    python -m benchmarks.fall_avoidance --part search --seeds 5 --budget 200 --batch-size 5
    python -m benchmarks.fall_avoidance --part classifiers
    python -m benchmarks.fall_avoidance --part overhead

Part ``overhead``: seconds per suggested point FallAware adds to each critic at 1000 told points
in 10-d (its asks minus a plain ask of the inner critic for the same batch).

Prints a Markdown table; ``--out FILE.json`` writes every run and the provenance
(:mod:`benchmarks.common`).
"""
from __future__ import annotations

import argparse
import math
import os
import sys
import time
from typing import Any, Callable

from latentune.threads import one_thread_env  # noqa: E402

one_thread_env()

import numpy as np  # noqa: E402

from latentune.constants import C1, STABLE_CAP  # noqa: E402

from benchmarks.common import Provenance, add_out_arg, bench_parser, finish  # noqa: E402


# ============================================================================ problems
class Problem:
    """A synthetic tuning problem on [0, 1]^d: ``evaluate(X (n, d)) -> (cost (n,), fell (n,))``."""

    def __init__(self, name: str, dim: int, fn: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
                 source: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]] | None = None):
        self.name, self.dim, self.fn, self.source = name, dim, fn, source

    def evaluate(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.fn(np.atleast_2d(X))


def _costs(stable_cost: np.ndarray, margin: np.ndarray, depth_scale: float
           ) -> tuple[np.ndarray, np.ndarray]:
    """Costs from a stable cost and a fall margin (> 0: fell)."""
    fell = margin > 0
    y = np.where(fell, C1 * (1.0 + np.minimum(1.0, np.maximum(margin, 0) / depth_scale)),
                 np.minimum(stable_cost, STABLE_CAP))
    return y, fell


def halfspace3(boundary: float = 1.2):
    xs = np.array([0.6, 0.5, 0.35])

    def f(X):
        return _costs(10 + 30 * ((X - xs) ** 2).sum(1), X[:, 0] + X[:, 1] - boundary, 0.3)
    return f


def holes6():
    rng = np.random.default_rng(6)
    xs = np.full(6, 0.5) + rng.uniform(-0.15, 0.15, 6)
    u = rng.normal(size=(12, 6))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    C = xs + u * rng.uniform(0.38, 0.55, (12, 1))       # the optimum stays outside every hole

    def f(X):
        dist = np.sqrt(((X[:, None, :] - C[None]) ** 2).sum(-1)).min(1)
        return _costs(10 + 30 * ((X - xs) ** 2).sum(1), 0.33 - dist, 0.1)
    return f


def stableball10():
    c = np.array([0.5, 0.45, 0.55])
    r = 0.35
    direction = np.array([1.0, 1.0, 0.0]) / math.sqrt(2)
    xs = np.full(10, 0.4)
    xs[:3] = c + 0.9 * r * direction
    w = np.linspace(1.0, 0.2, 10)

    def f(X):
        dist = np.linalg.norm(X[:, :3] - c, axis=1)
        return _costs(10 + 20 * (w * (X - xs) ** 2).sum(1), dist - r, 0.2)
    return f


def _cartpole(l: float) -> tuple[np.ndarray, np.ndarray]:
    Mc, m, g = 1.0, 0.1, 9.81
    A = np.array([[0, 1, 0, 0], [0, 0, -m * g / Mc, 0], [0, 0, 0, 1],
                  [0, 0, (Mc + m) * g / (Mc * l), 0]], dtype=float)
    B = np.array([0, 1 / Mc, 0, -1 / (Mc * l)], dtype=float)
    return A, B


def controller8(l: float = 0.5):
    from scipy.linalg import solve_continuous_are

    A0, B0 = _cartpole(0.5)
    P = solve_continuous_are(A0, B0[:, None], np.diag([10.0, 1, 10, 1]), np.array([[0.1]]))
    kstar = (B0[None] @ P / 0.1).ravel()
    A, B = _cartpole(l)
    dt, N = 0.02, 250

    def f(X):
        n = X.shape[0]
        K = kstar[None] * 10 ** ((X[:, :4] - 0.5) * 1.6)
        alpha, umax = 0.9 * X[:, 4], 5 + 25 * X[:, 5]
        tau, kd2 = 0.05 + 1.5 * X[:, 6], 2.0 * X[:, 7]
        s = np.zeros((n, 4))
        s[:, 2] = 0.05
        uf, r, err = np.zeros(n), np.zeros(n), np.zeros(n)
        fall = np.full(n, -1)
        for k in range(N):
            r = r + dt / tau * (0.5 - r)
            e = s.copy()
            e[:, 0] -= r
            u = np.clip(-(K * e).sum(1) - 0.1 * kd2 * s[:, 3], -umax, umax)
            uf = alpha * uf + (1 - alpha) * u
            s = s + dt * (s @ A.T + uf[:, None] * B[None])
            if k == 100:
                s[:, 3] += 0.5
            err += (s[:, 0] - 0.5) ** 2 + s[:, 2] ** 2 + 1e-4 * uf ** 2
            bad = (fall < 0) & ((np.abs(s[:, 2]) > 0.6) | (np.abs(s[:, 0]) > 2.5)
                                | ~np.isfinite(s).all(1))
            fall[bad] = k
            s[fall >= 0] = 0.0
        fell = fall >= 0
        y = np.where(fell, C1 * (2.0 - np.maximum(fall, 0) / N),
                     np.minimum(10 + 400 * err / N, STABLE_CAP))
        return y, fell
    return f


def problems() -> dict[str, Problem]:
    return {
        "halfspace3": Problem("halfspace3", 3, halfspace3(1.2), halfspace3(1.3)),
        "holes6": Problem("holes6", 6, holes6()),
        "stableball10": Problem("stableball10", 10, stableball10()),
        "controller8": Problem("controller8", 8, controller8(0.5), controller8(0.65)),
    }


# ============================================================================ search part
def make(method: str, dim: int, seed: int, batch: int, budget: int):
    from latentune.critic import make_critic
    from latentune.critic.turbo import regions_for_budget

    kw: dict[str, Any] = {"batch_size": batch, "seed": seed}
    if method == "turbo":
        kw["n_regions"] = regions_for_budget(budget)
    return make_critic(method, dim, **kw)


def source_prior(prob: Problem, n: int, batch: int) -> tuple[np.ndarray, np.ndarray]:
    """θ and fell flags of a plain TuRBO-m run of ``n`` evaluations on the source problem."""
    c = make("turbo", prob.dim, 1000, batch, n)
    F = []
    while c.n_told < n:
        X = c.ask(min(batch, n - c.n_told))
        y, f = prob.source(X)
        c.tell(X, y, c.last_tags)
        F.append(f)
    return c.X, np.concatenate(F)


def run_one(prob: Problem, method: str, variant: str, seed: int, budget: int, batch: int,
            max_fall_prob: float, prior: tuple[np.ndarray, np.ndarray] | None) -> dict[str, Any]:
    from latentune.critic.fall_aware import FallAware

    c = make(method, prob.dim, seed, batch, budget)
    if variant != "plain":
        px, pf = prior if variant == "fa+prior" else (None, None)
        c = FallAware(c, max_fall_prob=max_fall_prob, prior_X=px, prior_fell=pf)
    t0 = time.perf_counter()
    falls, ys = 0, []
    while c.n_told < budget:
        X = c.ask(min(batch, budget - c.n_told))
        T = c.last_tags
        y, f = prob.evaluate(X)
        falls += int(f.sum())
        ys.extend(y.tolist())
        if variant == "plain":
            c.tell(X, y, T)
        else:
            c.tell(X, y, T, fell=f)
    y = np.asarray(ys)
    stable = y < C1
    best = float(y[stable].min()) if stable.any() else math.inf
    out = {"problem": prob.name, "method": method, "variant": variant, "seed": seed,
           "budget": budget, "falls": falls, "best": best, "wall_s": time.perf_counter() - t0,
           "falls_first_half": int((y[: budget // 2] >= C1).sum()),
           "falls_second_half": int((y[budget // 2:] >= C1).sum())}
    if variant != "plain":
        out.update({k: v for k, v in c.stats().items() if k in ("n_over", "n_screened")})
    return out


def summarize(runs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    rows = []
    keys = sorted({(r["problem"], r["method"], r["variant"]) for r in runs},
                  key=lambda k: (k[0], k[1], ["plain", "fa", "fa+prior"].index(k[2])))
    for p, m, v in keys:
        rr = [r for r in runs if (r["problem"], r["method"], r["variant"]) == (p, m, v)]
        f = np.array([r["falls"] for r in rr], dtype=float)
        b = np.array([r["best"] for r in rr], dtype=float)
        rows.append({"problem": p, "method": m, "variant": v, "n_seeds": len(rr),
                     "falls_median": float(np.median(f)), "falls_q25": float(np.quantile(f, .25)),
                     "falls_q75": float(np.quantile(f, .75)), "falls_min": float(f.min()),
                     "falls_max": float(f.max()),
                     "best_median": float(np.median(b)), "best_q25": float(np.quantile(b, .25)),
                     "best_q75": float(np.quantile(b, .75)), "best_min": float(b.min()),
                     "best_max": float(b.max()),
                     "wall_s_median": float(np.median([r["wall_s"] for r in rr]))})
    base = {(r["problem"], r["method"]): r for r in rows if r["variant"] == "plain"}
    for r in rows:
        b = base.get((r["problem"], r["method"]))
        if b is None or r["variant"] == "plain":
            continue
        r["falls_ratio"] = (r["falls_median"] / b["falls_median"] if b["falls_median"] > 0
                            else float("nan"))
        r["best_change_pct"] = 100.0 * (r["best_median"] - b["best_median"]) / abs(b["best_median"])
    return rows


def search(a: argparse.Namespace) -> dict[str, Any]:
    probs = problems()
    names = a.problems or list(probs)
    runs: list[dict[str, Any]] = []
    priors: dict[str, Any] = {}
    for name in names:
        prob = probs[name]
        prior = None
        if prob.source is not None and not a.no_prior:
            t = time.perf_counter()
            prior = source_prior(prob, a.prior_n, a.batch_size)
            priors[name] = {"n": int(prior[0].shape[0]), "fell": int(prior[1].sum()),
                            "wall_s": time.perf_counter() - t}
        for method in a.methods:
            variants = ["plain", "fa"] + (["fa+prior"] if prior is not None else [])
            for variant in variants:
                for seed in range(a.seeds):
                    r = run_one(prob, method, variant, seed, a.budget, a.batch_size,
                                a.max_fall_prob, prior)
                    runs.append(r)
                    print(f"{name:13s} {method:6s} {variant:8s} seed {seed}: falls {r['falls']:3d}"
                          f"  best {r['best']:.3f}  {r['wall_s']:.1f}s", file=sys.stderr, flush=True)
    return {"runs": runs, "summary": summarize(runs), "priors": priors,
            "config": {"budget": a.budget, "batch_size": a.batch_size, "seeds": list(range(a.seeds)),
                       "max_fall_prob": a.max_fall_prob, "prior_n": a.prior_n,
                       "problems": names, "methods": a.methods}}


SEARCH_COLUMNS = ["problem", "method", "variant", "falls_median", "falls_q25", "falls_q75",
                  "best_median", "best_q25", "best_q75", "falls_ratio", "best_change_pct"]


# ============================================================================ classifier part
def _clf_problem(kind: str, d: int, rng: np.random.Generator):
    if kind == "half":
        return lambda X: X[:, 0] + X[:, 1] - 1.2
    if kind == "ball":
        c = rng.uniform(0.2, 0.8, d)
        r = np.quantile(np.linalg.norm(rng.random((20000, d)) - c, axis=1), 0.3)
        return lambda X: r - np.linalg.norm(X - c, axis=1)
    if kind == "outside":
        c = rng.uniform(0.3, 0.7, d)
        r = np.quantile(np.linalg.norm((rng.random((20000, d)) - c)[:, :3], axis=1), 0.5)
        return lambda X: np.linalg.norm((X - c)[:, :3], axis=1) - r
    return lambda X: np.maximum(X[:, 0] * X[:, 1] - 0.3, 0.1 - X[:, 2])   # gain product


def _clf_train(n: int, d: int, rng: np.random.Generator) -> np.ndarray:
    nu = int(0.3 * n)
    path = np.clip(np.cumsum(rng.normal(0, 0.08, (10, d)), 0) + rng.random(d), 0.05, 0.95)
    Xc = np.clip(path[rng.integers(0, 10, n - nu)] + rng.normal(0, 0.07, (n - nu, d)), 0, 1)
    return np.vstack([rng.random((nu, d)), Xc])


class _RFFLogistic:
    """Logistic regression on 512 random Fourier features (RBF), L2 penalty, lengthscale by
    3-fold cross-validation over a grid."""

    def __init__(self, D: int = 512, lam: float = 1e-3):
        self.D, self.lam = D, lam

    def _feat(self, X, ls):
        return math.sqrt(2.0 / self.D) * np.cos(X @ (self.W / ls) + self.b)

    def _fit1(self, F, y):
        from scipy.optimize import minimize
        from scipy.special import expit

        n = len(y)

        def f(w):
            z = F @ w[1:] + w[0]
            g = expit(z) - y
            return (float((np.logaddexp(0, z) - y * z).sum() / n + self.lam * w[1:] @ w[1:]),
                    np.concatenate([[g.sum() / n], F.T @ g / n + 2 * self.lam * w[1:]]))
        return minimize(f, np.zeros(F.shape[1] + 1), jac=True, method="L-BFGS-B",
                        options={"maxiter": 200}).x

    def fit(self, X, fell):
        from scipy.special import expit

        y = fell.astype(float)
        n, d = X.shape
        rng = np.random.default_rng(0)
        self.W, self.b = rng.normal(size=(d, self.D)), rng.uniform(0, 2 * np.pi, self.D)
        folds, best = np.arange(n) % 3, (np.inf, None)
        for ls in [v * math.sqrt(d) for v in (0.08, 0.15, 0.3, 0.6)]:
            F, loss = self._feat(X, ls), 0.0
            for k in range(3):
                w = self._fit1(F[folds != k], y[folds != k])
                p = np.clip(expit(F[folds == k] @ w[1:] + w[0]), 1e-6, 1 - 1e-6)
                yt = y[folds == k]
                loss -= float((yt * np.log(p) + (1 - yt) * np.log(1 - p)).sum())
            if loss < best[0]:
                best = (loss, ls)
        self.ls = best[1]
        self.w = self._fit1(self._feat(X, self.ls), y)
        return self

    def predict(self, X):
        from scipy.special import expit

        return expit(self._feat(X, self.ls) @ self.w[1:] + self.w[0])


class _KNN:
    """Distance-weighted 15 nearest neighbours, shrunk to the base rate."""

    def fit(self, X, fell):
        self.X, self.y = X, fell.astype(float)
        return self

    def predict(self, Xs):
        D = ((Xs[:, None, :] - self.X[None]) ** 2).sum(-1)
        k = min(15, len(self.y))
        i = np.argpartition(D, k - 1, axis=1)[:, :k]
        w = 1.0 / (np.sqrt(np.take_along_axis(D, i, 1)) + 1e-3)
        return ((w * self.y[i]).sum(1) + self.y.mean()) / (w.sum(1) + 1)


class _DirichletGP:
    """GPyTorch Dirichlet-based GP classifier (Milios et al. 2018), Matérn-5/2 ARD, 50 Adam
    steps (lr 0.1) on the exact marginal likelihood; probabilities from 256 posterior samples."""

    def fit(self, X, fell):
        import gpytorch
        import torch
        from gpytorch.likelihoods import DirichletClassificationLikelihood

        Xt = torch.as_tensor(X, dtype=torch.float64)
        lik = DirichletClassificationLikelihood(torch.as_tensor(fell.astype(int)),
                                                learn_additional_noise=True, dtype=torch.float64)
        d, bs = X.shape[1], torch.Size((2,))

        class M(gpytorch.models.ExactGP):
            def __init__(s, x, y, l):
                super().__init__(x, y, l)
                s.mean = gpytorch.means.ConstantMean(batch_shape=bs)
                s.cov = gpytorch.kernels.ScaleKernel(gpytorch.kernels.MaternKernel(
                    nu=2.5, ard_num_dims=d, batch_shape=bs), batch_shape=bs)

            def forward(s, x):
                return gpytorch.distributions.MultivariateNormal(s.mean(x), s.cov(x))

        m = M(Xt, lik.transformed_targets, lik).to(torch.float64)
        m.train()
        lik.train()
        opt = torch.optim.Adam(m.parameters(), lr=0.1)
        mll = gpytorch.mlls.ExactMarginalLogLikelihood(lik, m)
        for _ in range(50):
            opt.zero_grad()
            loss = -mll(m(Xt), lik.transformed_targets).sum()
            loss.backward()
            opt.step()
        m.eval()
        self.m = m
        return self

    def predict(self, Xs):
        import gpytorch
        import torch

        with torch.no_grad(), gpytorch.settings.fast_pred_var():
            dist = self.m(torch.as_tensor(Xs, dtype=torch.float64))
            gen = torch.Generator().manual_seed(0)
            z = dist.mean + dist.stddev * torch.randn((256,) + dist.mean.shape, generator=gen,
                                                      dtype=torch.float64)
            s = z.exp()
            return (s / s.sum(-2, keepdim=True)).mean(0)[1].numpy()


class _LSGP:
    """latentune's GPFallModel (the one FallAware uses by default)."""

    def fit(self, X, fell):
        from latentune.critic.fall_model import GPFallModel

        self.c = GPFallModel(X.shape[1])
        self.c.fit(X, fell)
        return self

    def predict(self, Xs):
        return self.c.p_fall(Xs)


def classifiers(a: argparse.Namespace) -> dict[str, Any]:
    from scipy.special import expit

    makers = {"lsgp": _LSGP, "dirichlet_gp": _DirichletGP, "rff_logistic": _RFFLogistic,
              "knn": _KNN}
    sizes = a.clf_sizes
    rows = []
    for kind in ("half", "ball", "outside", "gain"):
        for d in (3, 10):
            for n in sizes:
                for noisy in (False, True):
                    rng = np.random.default_rng([d, n, int(noisy), len(kind)])
                    g = _clf_problem(kind, d, rng)
                    X = _clf_train(n, d, rng)
                    fell = (rng.random(n) < expit(g(X) / 0.03)) if noisy else g(X) > 0
                    Xte = np.vstack([np.clip(X[rng.integers(0, n, 1000)]
                                             + rng.normal(0, 0.05, (1000, d)), 0, 1),
                                     rng.random((1000, d))])
                    yte = (g(Xte) > 0).astype(float)
                    for name, mk in makers.items():
                        if name == "dirichlet_gp" and n > a.dirichlet_max:
                            continue
                        t = time.perf_counter()
                        c = mk().fit(X, fell)
                        t_fit = time.perf_counter() - t
                        p = np.clip(c.predict(Xte), 1e-6, 1 - 1e-6)
                        row = {"kind": kind, "d": d, "n": n, "noisy": noisy, "method": name,
                               "fit_s": t_fit}
                        for part, sl in (("near", slice(0, 1000)), ("uniform", slice(1000, None))):
                            pp, yy = p[sl], yte[sl]
                            row[part] = {
                                "log_loss": float(-np.mean(yy * np.log(pp) + (1 - yy) * np.log(1 - pp))),
                                "brier": float(np.mean((pp - yy) ** 2)),
                                "falls_let_through": float(np.mean(pp[yy == 1] <= 0.5)) if (yy == 1).any() else None,
                                "stable_rejected": float(np.mean(pp[yy == 0] > 0.5)) if (yy == 0).any() else None}
                        rows.append(row)
                        print(f"{kind:8s} d={d:2d} n={n:4d} noisy={int(noisy)} {name:13s} "
                              f"fit {t_fit:6.3f}s near ll {row['near']['log_loss']:.3f} "
                              f"let-through {row['near']['falls_let_through'] or 0:.3f}", file=sys.stderr,
                              flush=True)
    summary = []
    for name in makers:
        for n in sizes:
            rr = [r for r in rows if r["method"] == name and r["n"] == n]
            if not rr:
                continue
            s: dict[str, Any] = {"method": name, "n": n, "cases": len(rr),
                                 "fit_s_mean": float(np.mean([r["fit_s"] for r in rr]))}
            for part in ("near", "uniform"):
                for k in ("log_loss", "brier", "falls_let_through", "stable_rejected"):
                    v = [r[part][k] for r in rr if r[part][k] is not None]
                    s[f"{part}_{k}"] = float(np.mean(v))
            summary.append(s)
    return {"rows": rows, "summary": summary, "config": {"sizes": sizes,
                                                         "dirichlet_max": a.dirichlet_max}}


CLASSIFIER_COLUMNS = ["method", "n", "fit_s_mean", "near_log_loss", "near_brier",
                      "near_falls_let_through", "near_stable_rejected", "uniform_log_loss",
                      "uniform_brier", "uniform_falls_let_through", "uniform_stable_rejected"]


# ============================================================================ overhead part
def overhead(a: argparse.Namespace) -> dict[str, Any]:
    """Seconds per suggested point that FallAware adds at ``--overhead-told`` told points in
    10-d (fall region ``x0 + x1 > 1.2``): its ask minus a plain ask of the inner critic for the
    same batch, median and mean over the asks."""
    import copy

    from latentune.critic import make_critic
    from latentune.critic.fall_aware import FallAware

    d, N = 10, a.overhead_told
    xs = np.full(d, 0.35)

    def f(X):
        return _costs(10 + 30 * ((X - xs) ** 2).sum(1), X[:, 0] + X[:, 1] - 1.2, 0.3)

    rows = []
    for method in a.methods:
        for batch in (4, 10):
            kw: dict[str, Any] = {"batch_size": batch, "seed": 0}
            if method == "turbo":
                kw["n_regions"] = 2
            fa = FallAware(make_critic(method, d, **kw))
            if method == "cma":           # its own history (penalise mode replays generations)
                while fa.n_told < N:
                    X = fa.ask()
                    y, fl = f(X)
                    fa.tell(X, y, fa.last_tags, fell=fl)
            else:                          # a plain run's history, told at once
                plain = make_critic(method, d, **kw)
                fells = []
                while plain.n_told < N:
                    X = plain.ask()
                    y, fl = f(X)
                    plain.tell(X, y, plain.last_tags)
                    fells.append(fl)
                fa.tell(plain.X, plain.y, plain.tags, fell=np.concatenate(fells))
            inner_t, fa_t = [], []
            for _ in range(a.overhead_asks):
                probe = copy.deepcopy(fa.inner)
                t = time.perf_counter()
                probe.ask(batch)
                inner_t.append(time.perf_counter() - t)
                t = time.perf_counter()
                X = fa.ask()
                fa_t.append(time.perf_counter() - t)
                y, fl = f(X)
                fa.tell(X, y, fa.last_tags, fell=fl)
            over = (np.asarray(fa_t) - np.asarray(inner_t)) / batch
            rows.append({"method": method, "batch": batch, "told": N,
                         "ask_s_median": float(np.median(fa_t)), "ask_s_mean": float(np.mean(fa_t)),
                         "inner_ask_s_median": float(np.median(inner_t)),
                         "overhead_s_per_point_median": float(np.median(over)),
                         "overhead_s_per_point_mean": float(np.mean(over)),
                         "s_per_point_mean": float(np.mean(fa_t) / batch)})
            r = rows[-1]
            print(f"{method:6s} batch {batch:2d}: ask {r['ask_s_median']:.3f} s median "
                  f"({r['ask_s_mean']:.3f} mean), inner ask "
                  f"{r['inner_ask_s_median']:.3f} s, overhead {r['overhead_s_per_point_mean']:.4f}"
                  f" s/point (mean)", file=sys.stderr, flush=True)
    return {"rows": rows, "config": {"dim": d, "told": N, "asks": a.overhead_asks}}


# ============================================================================ main
def main(argv: list[str] | None = None) -> int:
    prov = Provenance(argv, "benchmarks.fall_avoidance")
    import torch

    torch.set_num_threads(1)
    p = bench_parser("benchmarks.fall_avoidance", description=__doc__.split("\n\n")[0],
                     formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--part", choices=("search", "classifiers", "overhead"), default="search")
    p.add_argument("--problems", nargs="*", choices=sorted(problems()), default=None)
    p.add_argument("--methods", nargs="*", default=["turbo", "cma", "random"],
                   choices=["turbo", "cma", "random", "sobol"])
    p.add_argument("--seeds", type=int, default=5)
    p.add_argument("--budget", type=int, default=200)
    p.add_argument("--batch-size", type=int, default=5)
    p.add_argument("--max-fall-prob", type=float, default=0.5)
    p.add_argument("--prior-n", type=int, default=200)
    p.add_argument("--no-prior", action="store_true")
    p.add_argument("--clf-sizes", type=int, nargs="*", default=[100, 400, 1000])
    p.add_argument("--dirichlet-max", type=int, default=400,
                   help="largest training set for the Dirichlet GP (it fits on all points)")
    p.add_argument("--overhead-told", type=int, default=1000)
    p.add_argument("--overhead-asks", type=int, default=30)
    add_out_arg(p)
    a = p.parse_args(argv)
    threads = {"torch": torch.get_num_threads(),
               "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS")}
    res = {"search": search, "classifiers": classifiers, "overhead": overhead}[a.part](a)
    rows = res["rows"] if a.part == "overhead" else res["summary"]
    cols = {"search": SEARCH_COLUMNS, "classifiers": CLASSIFIER_COLUMNS}.get(a.part)
    finish(a.out, prov, {"part": a.part, "threads": threads, **res}, rows, columns=cols,
           title=f"fall avoidance, part {a.part}")
    return 0


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.fall_avoidance"))
