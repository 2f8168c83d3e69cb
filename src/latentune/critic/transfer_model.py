"""The transfer model: the target's cost and fall models built from the source run's trials
and the target's own (:class:`~latentune.critic.transfer.Transfer` searches with them).

*Source models* (:class:`SourceModel`, fitted once with BoTorch/GPyTorch on at most
``max_points`` source trials: the best ones and a seeded spread of the rest):
``m_s(θ)``, a GP (Matérn-5/2, ARD) on the source's cost *ranks* (Gaussian copula scores; a fall
ranks below every trial that did not fall), and ``p_s(θ)``, a GP on the source's fall flags (a
least-squares classifier, clipped to [0, 1]). Their ARD lengthscales say how cost and falls vary
across the box; the target models reuse them.

*Target cost model*: the target's cost ranks ``z`` (copula scores of its own trials, falls last)
are modelled as ``z(θ) = a · m_s(θ) + b + r(θ)`` with ``(a, b) ~ N((1, 0), I)`` and a residual
``r ~ GP(0, σ_r² k_s)`` (``k_s``: Matérn-5/2 with the source's lengthscales). Integrating
``a, b`` out gives one GP with the kernel ``σ_r² k_s + h hᵀ + σ_n² I``, ``h(θ) = (m_s(θ), 1)``
(Rasmussen & Williams §2.7): exact posterior, joint Thompson samples. ``σ_r²`` is chosen by
marginal likelihood on a grid at every ask. The posterior of ``a`` is the *agreement*: about 1
when the target ranks θ as the source did, about 0 (or negative) when the source says nothing
about the target. It is computed from the target's trials alone at every ask, so the source is
trusted exactly as far as the target's own evidence supports.

*Target fall model*: the same construction on the target's fall flags with ``h = (p_s(θ), 1)``
and the source's fall lengthscales: the probability that θ fails on the target.

Everything here is a function of the trials it is given: the source models' hyperparameters
are fitted once (BoTorch/GPyTorch, :func:`fit_gp`), the target models are closed-form on top
of them (:class:`TargetModel`), and :class:`TargetGP` is the target-only GP of the explore asks
(``explore_gp``). θ are in the unit box throughout; costs enter as rank scores
(:func:`rank_scores`)."""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

log = logging.getLogger(__name__)

_SIGMA_R2_GRID = (0.01, 0.05, 0.2, 0.5, 1.0, 2.0)
LS_SCALES = (0.25, 0.5, 1.0, 2.0)
"""Multipliers of the source's lengthscales the target cost model may choose (``fit_lengthscale``),
and the target fall model (``fall_fit``)."""
_FALL_NOISES = (1e-2, 5e-2, 0.15)
"""Nuggets (variances of the fall flags' noise, 0/1 labels) the target fall model may choose
(``fall_fit``); the first is the fixed one without it."""
_NOISE = 1e-2
_GP_STARTS = 5
"""``explore_gp``: the starts of the local search of the target GP's log expected improvement."""
_LS_BOUNDS = (0.02, 4.0)
_ARD_PRIOR_SD = 1.0
"""Standard deviation of the log-normal prior of the target's ARD lengthscales (``fit_ard``)
around the source's: a factor e either way is one standard deviation."""


def rank_scores(y: np.ndarray, fell: np.ndarray) -> np.ndarray:
    """Gaussian-copula scores (n,) of costs ``y`` (n,) with falls ranked below every trial that
    did not fall (among falls by cost); non-finite costs rank last. Lower is better."""
    from scipy.special import ndtri

    y = np.asarray(y, dtype=float).reshape(-1)
    n = y.shape[0]
    if n == 0:
        return y.copy()
    fell = np.asarray(fell, dtype=bool).reshape(-1)
    yy = np.where(np.isfinite(y), y, np.inf)
    order = np.lexsort((yy, fell.astype(int)))      # key: fell first, then cost
    key = np.empty(n, dtype=float)
    key[order] = np.arange(n, dtype=float)
    # ties (same fell flag and cost) share their average rank
    _, inv, counts = np.unique(np.stack([fell.astype(float), yy]).T, axis=0,
                               return_inverse=True, return_counts=True)
    inv = inv.reshape(-1)
    sums = np.bincount(inv, weights=key)
    ranks = sums[inv] / counts[inv] + 1.0
    return ndtri((ranks - 0.5) / n)


def value_scores(y: np.ndarray, fell: np.ndarray) -> np.ndarray:
    """Standardized values (n,) of costs ``y`` (n,): the trials that did not fail (finite
    costs) as ``(y − mean) / sd`` over them, every fall (or non-finite cost) one sd above the
    worst of them; lower is better. With fewer than 3 such trials, or all of one cost, the rank
    scores (:func:`rank_scores`): a scale needs a spread. Unlike ranks they keep how much
    better a trial is, which a smooth target's model can extrapolate from."""
    return _standing_scores(y, fell)


def _standing_scores(y: np.ndarray, fell: np.ndarray,
                     warp: Callable[[np.ndarray], np.ndarray] | None = None) -> np.ndarray:
    """Scores (n,) of costs ``y`` (n,): the standing trials' (not failed, finite) costs
    standardized and, with ``warp`` (a monotone map of the standardized costs), through it and
    standardized again; every fall (or non-finite cost) one sd above the worst of them. With
    fewer than 3 standing trials, or all of one cost, the rank scores (:func:`rank_scores`)."""
    y = np.asarray(y, dtype=float).reshape(-1)
    fell = np.asarray(fell, dtype=bool).reshape(-1)
    ok = ~fell & np.isfinite(y)
    if ok.sum() < 3 or np.ptp(y[ok]) <= 0:
        return rank_scores(y, fell)
    u = _standardized(y[ok])
    if warp is not None:
        w = warp(u)
        u = (w - w.mean()) / w.std()
    v = np.empty_like(y)
    v[ok] = u
    v[~ok] = v[ok].max() + 1.0
    return v


def _standardized(y: np.ndarray) -> np.ndarray:
    """``(y − mean) / sd`` of costs ``y`` (n,) of some spread; where the sd overflows (costs
    beyond about 1e154 apart: their squares are inf) or underflows to 0 (about 1e-154 apart),
    the same of ``y − mean`` divided by its largest size first, so the scores stay finite."""
    with np.errstate(over="ignore", under="ignore", invalid="ignore"):
        sd = y.std()
        if np.isfinite(sd) and sd > 0:
            return (y - y.mean()) / sd
        d = y - y.mean()
        d = d / np.max(np.abs(d))
        return d / d.std()


def warped_scores(y: np.ndarray, fell: np.ndarray) -> np.ndarray:
    """Warped values (n,) of costs ``y`` (n,): the trials that did not fail (finite costs)
    standardized, passed through the Yeo-Johnson power transform whose exponent is fitted to
    them by maximum likelihood (:func:`scipy.stats.yeojohnson`), and standardized again; every
    fall (or non-finite cost) one sd above the worst of them; lower is better. The warp is
    monotone, so the order is the costs'; it pulls in a heavy tail of bad costs (which would
    flatten :func:`value_scores` near the best) and keeps how much better a trial is, which
    :func:`rank_scores` hide. With fewer than 3 such trials, or all of one cost, the rank
    scores."""
    from scipy.stats import yeojohnson

    def warp(u: np.ndarray) -> np.ndarray:
        w = np.asarray(yeojohnson(u)[0], dtype=float)
        # a degenerate exponent: the values
        return w if np.all(np.isfinite(w)) and np.ptp(w) > 0 else u

    return _standing_scores(y, fell, warp)


def loo_means(L: np.ndarray, alpha: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Leave-one-out posterior means (n,) of a GP's n training targets ``target`` (n,), from
    the Cholesky factor ``L`` (n, n) of its training covariance (noise included) and
    ``alpha`` = K⁻¹ (target − prior mean) (n,): ``target − alpha / diag(K⁻¹)`` (Rasmussen &
    Williams eq. 5.12), the hyperparameters held at their fitted values."""
    from scipy.linalg import solve_triangular

    Linv = solve_triangular(L, np.eye(len(L)), lower=True)
    return np.asarray(target, float) - alpha / (Linv * Linv).sum(0)


def ranking_loss(pred: np.ndarray, y: np.ndarray, fell: np.ndarray) -> float:
    """The share of trial pairs that predictions ``pred`` (n,) put in the wrong order (RGPE's
    ranking loss, Feurer et al.), in [0, 1]; nan without a pair. Trials are ordered as
    :func:`rank_scores` orders them (costs ``y`` (n,), a fall ``fell`` (n,) below every
    trial that stood); a pair of two falls, or of equal costs, is not counted (the scores
    need not order falls among themselves). A tie in ``pred`` counts as half wrong."""
    pred = np.asarray(pred, float).reshape(-1)
    y = np.asarray(y, float).reshape(-1)
    fell = np.asarray(fell, bool).reshape(-1) | ~np.isfinite(y)
    yy = np.where(fell, np.inf, y)
    better = (yy[:, None] < yy[None, :]) & ~(fell[:, None] & fell[None, :])
    n_pairs = int(better.sum())
    if n_pairs == 0:
        return math.nan
    wrong = (pred[:, None] > pred[None, :]) + 0.5 * (pred[:, None] == pred[None, :])
    return float((wrong * better).sum() / n_pairs)


_CALIB_EPS = 0.01
"""Screen scores are clipped to ``[ε, 1 − ε]`` before the logit of the calibration map."""
_CALIB_PRIOR_SD = (1.0, 0.5)
"""Prior standard deviations of the calibration map's ``(a, b)`` around ``(0, 1)``."""


def calibrated(s: np.ndarray, ab: np.ndarray) -> np.ndarray:
    """The calibrated fall probability (m,) ``σ(a + b · logit s)`` of screen scores ``s`` (m,)
    (clipped to ``[ε, 1 − ε]``, :data:`_CALIB_EPS`) under the map ``ab`` = (a, b)."""
    from scipy.special import expit, logit

    return expit(ab[0] + ab[1] * logit(np.clip(s, _CALIB_EPS, 1.0 - _CALIB_EPS)))


def fit_calibration(s: np.ndarray, fell: np.ndarray) -> np.ndarray:
    """MAP ``(a, b)`` (2,) of the Platt map ``P(fall) = σ(a + b · logit s)`` from screen scores
    ``s`` (n,) and the outcomes ``fell`` (n,) bool: logistic regression on ``logit s`` with the
    Gaussian prior ``(a, b) ~ N((0, 1), diag(1, ½)²)`` (:data:`_CALIB_PRIOR_SD`), by L-BFGS on
    the convex negative log posterior from the prior's mean."""
    from scipy.optimize import minimize
    from scipy.special import expit, logit

    x = logit(np.clip(np.asarray(s, float), _CALIB_EPS, 1.0 - _CALIB_EPS))
    yv = np.asarray(fell, float)
    m0, sd = np.array([0.0, 1.0]), np.array(_CALIB_PRIOR_SD)

    def nlp(ab: np.ndarray) -> tuple[float, np.ndarray]:
        f = ab[0] + ab[1] * x
        r = expit(f) - yv
        val = float(np.logaddexp(0.0, f).sum() - yv @ f + 0.5 * (((ab - m0) / sd) ** 2).sum())
        return val, np.array([r.sum(), r @ x]) + (ab - m0) / sd ** 2

    return np.asarray(minimize(nlp, m0, jac=True, method="L-BFGS-B").x, dtype=float)


def matern52(X1: np.ndarray, X2: np.ndarray, ls: np.ndarray) -> np.ndarray:
    """Matérn-5/2 kernel matrix (n1, n2) of points (n1, d), (n2, d) with lengthscales (d,)."""
    A = X1 / ls
    B = X2 / ls
    d2 = np.maximum((A * A).sum(1)[:, None] + (B * B).sum(1)[None, :] - 2.0 * A @ B.T, 0.0)
    r = np.sqrt(5.0 * d2)
    return (1.0 + r + r * r / 3.0) * np.exp(-r)


def jittered_cholesky(K: np.ndarray) -> np.ndarray:
    """Cholesky factor of a symmetric PSD matrix, with growing jitter when needed."""
    jitter = 1e-9 * max(1.0, float(np.mean(np.diag(K))))
    for _ in range(8):
        try:
            return np.linalg.cholesky(K + jitter * np.eye(K.shape[0]))
        except np.linalg.LinAlgError:
            jitter *= 10.0
    raise np.linalg.LinAlgError("covariance matrix is not positive definite")


def log_expected_improvement(mu: np.ndarray, var: np.ndarray, best: float) -> np.ndarray:
    """log EI (m,) of a minimization at posterior means ``mu`` (m,) and variances ``var`` (m,)
    below ``best``: ``log(σ h(u))``, ``u = (best − μ)/σ``, ``h(u) = φ(u) + u Φ(u)``, written
    with ``erfcx`` so that it stays finite and ordered far below the best (where EI itself
    underflows to 0), as BoTorch's ``LogExpectedImprovement`` does."""
    from scipy.special import erfcx

    sd = np.sqrt(np.maximum(np.asarray(var, dtype=float), 1e-12))
    u = (float(best) - np.asarray(mu, dtype=float)) / sd
    # h(u) = exp(−u²/2) (1/√(2π) + u/2 · erfcx(−u/√2))
    inner = 1.0 / math.sqrt(2.0 * math.pi) + 0.5 * u * erfcx(-u / math.sqrt(2.0))
    return np.log(sd) - 0.5 * u * u + np.log(np.maximum(inner, 1e-300))


def _local_max(f: Callable[[np.ndarray], np.ndarray], X0: np.ndarray,
               maxiter: int = 40) -> np.ndarray:
    """Local maxima (k, d) of ``f`` ((m, d) → (m,)) in the unit box from the starts ``X0``
    (k, d): L-BFGS-B on finite differences, each start's end clipped to the box."""
    from scipy.optimize import minimize

    out = []
    for x0 in X0:
        res = minimize(lambda x: -float(f(x[None, :])[0]), x0, method="L-BFGS-B",
                       bounds=[(0.0, 1.0)] * len(x0), options={"maxiter": maxiter})
        out.append(np.clip(res.x, 0.0, 1.0))
    return np.asarray(out, dtype=float).reshape(-1, X0.shape[1])


def gp_maxima(gp: TargetGP, XB: np.ndarray) -> np.ndarray:
    """The local maxima (k, d) of ``gp``'s log expected improvement (:func:`_local_max`) from
    the :data:`_GP_STARTS` candidates of ``XB`` (m, d) with the highest (``explore_gp``'s and
    ``region_gp``'s)."""
    starts = XB[np.argsort(-gp.log_ei(XB), kind="stable")[:_GP_STARTS]]
    return _local_max(gp.log_ei, starts)


# --------------------------------------------------------------------------- source models
@dataclass
class _GPFit:
    """A fitted GP's numpy predictor: mean(X) = c + k(X, S) α; variance(X) = k(X, X) −
    k(X, S) K⁻¹ k(S, X) with ``chol`` the Cholesky factor of K = k(S, S) + noise·I."""

    S: np.ndarray
    alpha: np.ndarray
    ls: np.ndarray
    outputscale: float
    constant: float
    chol: np.ndarray

    def mean(self, X: np.ndarray) -> np.ndarray:
        if self.S.shape[0] == 0:
            return np.full(X.shape[0], self.constant)
        return self.constant + self.outputscale * matern52(X, self.S, self.ls) @ self.alpha

    def variance(self, X: np.ndarray) -> np.ndarray:
        """Posterior variance (n,) of the latent function at X (n, d), noise excluded."""
        if self.S.shape[0] == 0:
            return np.full(X.shape[0], self.outputscale)
        from scipy.linalg import solve_triangular

        V = solve_triangular(self.chol, self.outputscale * matern52(self.S, X, self.ls),
                             lower=True)
        return np.maximum(self.outputscale - (V * V).sum(0), 0.0)


def _scipy_fit(mll: Any) -> Any:
    """Maximize a GPyTorch marginal likelihood in place with BoTorch's scipy L-BFGS-B (100
    iterations, one torch thread, optimization warnings silenced); its result."""
    import warnings

    import torch
    from botorch.exceptions.warnings import OptimizationWarning
    from botorch.optim.fit import fit_gpytorch_mll_scipy

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", OptimizationWarning)
            return fit_gpytorch_mll_scipy(mll, options={"maxiter": 100})
    finally:
        torch.set_num_threads(before)


def fit_gp(X: np.ndarray, y: np.ndarray, hypers: dict[str, Any] | None) -> tuple[_GPFit, dict]:
    """Fit (or, with ``hypers``, only condition) a Matérn-5/2 ARD GP on (X (n, d), y (n,)) with
    BoTorch; return its numpy predictor and its hyperparameters (JSON-ready; a fit that raised
    leaves the starting values and says why under ``"fit_failed"``)."""
    n, d = X.shape
    failed = None
    if hypers is None:
        import torch
        from botorch.models import SingleTaskGP
        from gpytorch.constraints import Interval
        from gpytorch.kernels import MaternKernel, ScaleKernel
        from gpytorch.likelihoods import GaussianLikelihood
        from gpytorch.mlls import ExactMarginalLogLikelihood

        Xt = torch.as_tensor(X, dtype=torch.float64)
        Yt = torch.as_tensor(y, dtype=torch.float64).reshape(-1, 1)
        kern = ScaleKernel(MaternKernel(nu=2.5, ard_num_dims=d,
                                        lengthscale_constraint=Interval(*_LS_BOUNDS)),
                           outputscale_constraint=Interval(0.01, 20.0))
        lik = GaussianLikelihood(noise_constraint=Interval(1e-4, 0.5))
        model = SingleTaskGP(Xt, Yt, likelihood=lik, covar_module=kern, outcome_transform=None)
        model.covar_module.base_kernel.lengthscale = torch.full((1, d), 0.5, dtype=torch.float64)
        model.covar_module.outputscale = torch.tensor(1.0, dtype=torch.float64)
        model.likelihood.noise = torch.tensor([0.05], dtype=torch.float64)
        model.mean_module.constant = torch.tensor(float(np.mean(y)), dtype=torch.float64)
        mll = ExactMarginalLogLikelihood(model.likelihood, model)
        try:
            res = _scipy_fit(mll)
            if res.status.name == "FAILURE":
                log.warning("source model fit did not converge (%s); using where it stopped",
                            res.message)
        except Exception as exc:  # noqa: BLE001 - reported, starting values kept
            log.warning("source model fit failed (%s: %s); using its starting hyperparameters",
                        type(exc).__name__, exc)
            failed = f"{type(exc).__name__}: {exc}"
        finally:
            model.eval()
        hypers = {"lengthscale": model.covar_module.base_kernel.lengthscale.detach().numpy()
                  .reshape(-1).tolist(),
                  "outputscale": float(model.covar_module.outputscale.detach()),
                  "noise": float(model.likelihood.noise.detach().reshape(-1)[0]),
                  "constant": float(model.mean_module.constant.detach()),
                  **({"fit_failed": failed} if failed is not None else {})}
    ls = np.clip(np.asarray(hypers["lengthscale"], dtype=float).reshape(d), *_LS_BOUNDS)
    os_, noise, c = float(hypers["outputscale"]), float(hypers["noise"]), float(hypers["constant"])
    K = os_ * matern52(X, X, ls) + noise * np.eye(n)
    L = jittered_cholesky(K)
    alpha = np.linalg.solve(L.T, np.linalg.solve(L, y - c))
    return _GPFit(X, alpha, ls, os_, c, L), hypers


class SourceModel:
    """What the source run says about cost and falls across the θ box.

    Args:
        X: (N, d) normalized θ the source tried; ``y`` (N,) their costs; ``fell`` (N,) bools.
        seed: seeds the choice of the fitted subset.
        max_points: at most this many trials per fitted GP.
        hypers: previously fitted hyperparameters (:attr:`hypers`): condition only, no fit.
    """

    def __init__(self, X: np.ndarray, y: np.ndarray, fell: np.ndarray, *, seed: int = 0,
                 max_points: int = 300, hypers: dict[str, Any] | None = None) -> None:
        X = np.asarray(X, dtype=float)
        if X.ndim != 2 or X.shape[0] < 2:
            raise ValueError(f"the source needs at least 2 trials (N, d), got shape {X.shape}")
        self.X, self.d = X, X.shape[1]
        self.y = np.asarray(y, dtype=float).reshape(-1)
        self.fell = np.asarray(fell, dtype=bool).reshape(-1)
        self.z = rank_scores(self.y, self.fell)
        rng = np.random.default_rng([int(seed), 7])
        n = X.shape[0]
        order = np.argsort(self.z, kind="stable")
        m = min(n, int(max_points))
        n_best = (2 * m) // 3
        rest = order[n_best:]
        pick = np.concatenate([order[:n_best],
                               np.sort(rng.choice(rest, size=m - n_best, replace=False))])
        hypers = hypers or {}
        self.cost_gp, hc = fit_gp(X[pick], self.z[pick], hypers.get("cost"))
        self.fall_rate = float(self.fell.mean())
        self.fall_gp: _GPFit | None = None
        hf = None
        if self.fell.sum() >= 5 and (~self.fell).sum() >= 5:
            falls, ok = np.flatnonzero(self.fell), np.flatnonzero(~self.fell)
            kf = min(falls.size, m // 2)
            ko = min(ok.size, m - kf)
            fpick = np.sort(np.concatenate([rng.choice(falls, size=kf, replace=False),
                                            rng.choice(ok, size=ko, replace=False)]))
            self.fall_gp, hf = fit_gp(X[fpick], self.fell[fpick].astype(float),
                                       hypers.get("fall"))
        self.hypers = {"cost": hc, "fall": hf}

    def fit_failures(self) -> dict[str, str]:
        """Which of the fits that made these hyperparameters raised, and why: ``{"source cost
        model" | "source fall model": "ErrorName: message"}`` (empty when both fitted)."""
        return {f"source {name} model": h["fit_failed"]
                for name, h in self.hypers.items() if h and h.get("fit_failed")}

    @property
    def lengthscales(self) -> np.ndarray:
        """(d,) ARD lengthscales of the source cost model (unit-box units)."""
        return self.cost_gp.ls

    @property
    def fall_lengthscales(self) -> np.ndarray:
        """(d,) lengthscales of the fall model (the cost model's when there is none)."""
        return self.cost_gp.ls if self.fall_gp is None else self.fall_gp.ls

    def cost(self, X: np.ndarray) -> np.ndarray:
        """Predicted source cost rank score (n,) at θ (n, d); lower is better."""
        return self.cost_gp.mean(X)

    def fall_prob(self, X: np.ndarray) -> np.ndarray:
        """Predicted source fall probability (n,) at θ (n, d), in [0, 1]."""
        if self.fall_gp is None:
            return np.full(X.shape[0], self.fall_rate)
        return np.clip(self.fall_gp.mean(X), 0.0, 1.0)

    def fall_sd(self, X: np.ndarray) -> np.ndarray:
        """Posterior standard deviation (n,) of the source fall model at θ (n, d): small near
        the source's trials, its prior's (√outputscale) where the source tried nothing; zeros
        without a fall model."""
        if self.fall_gp is None:
            return np.zeros(X.shape[0])
        return np.sqrt(self.fall_gp.variance(X))


# --------------------------------------------------------------------------- target model
class TargetModel:
    """The GP ``v(θ) = a·h0(θ) + b + cᵀ(θ − ½) + r(θ)`` on the target's values ``v`` (n,) at θ
    (n, d) with ``(a, b) ~ N(prior_mean, I)`` and the tilt ``c ~ N(0, σ_t² I)`` integrated out
    (module docstring); ``feature`` maps θ (m, d) to h0 (m,), ``ls`` (d,) are the residual
    kernel's lengthscales. ``σ_r²`` (unless given), the lengthscale multiplier (``ls_scales``),
    ``σ_t`` (``tilts``; ``(0,)``: no tilt) and the nugget, the variance of the values' noise
    (``noises``; the fixed 0.01 by default), are chosen together by marginal likelihood."""

    def __init__(self, X: np.ndarray, v: np.ndarray, feature: Callable[[np.ndarray], np.ndarray],
                 ls: np.ndarray, prior_mean: tuple[float, float] = (1.0, 0.0),
                 sigma_r2: float | None = None, ls_scales: tuple[float, ...] = (1.0,),
                 tilts: tuple[float, ...] = (0.0,), noises: tuple[float, ...] = (_NOISE,)
                 ) -> None:
        self.X, self.v, self.feature = X, np.asarray(v, float), feature
        self.h0X = np.asarray(feature(X), dtype=float)
        grid = (sigma_r2,) if sigma_r2 is not None else \
            _SIGMA_R2_GRID if len(ls_scales) == 1 else _SIGMA_R2_GRID + (4.0,)
        choose = len(grid) * len(ls_scales) * len(tilts) * len(noises) > 1
        fits = []                       # type-II maximum likelihood on the grids
        for rho in ls_scales:
            kX = matern52(X, X, ls * rho)
            for t in tilts:
                hX = self._basis(X, self.h0X, float(t))
                b0 = np.concatenate([prior_mean, np.zeros(hX.shape[1] - 2)])
                fits += [(self._log_evidence(kX, hX, b0, s, e) if choose else 0.0, s, rho,
                          float(t), kX, e) for e in noises for s in grid]
        _, s, rho, self.tilt, self.kX, self.noise = max(fits, key=lambda f: f[0])
        self.hX = self._basis(X, self.h0X)
        self.b0 = np.concatenate([prior_mean, np.zeros(self.hX.shape[1] - 2)])
        self.ls_scale = float(rho)
        self.ls = ls * rho
        self.sigma_r2 = float(s)
        self.L = jittered_cholesky(self._cov(self.kX, self.hX, self.hX)
                                   + self.noise * np.eye(len(v)))
        r = self.v - self.hX @ self.b0
        self.alpha = np.linalg.solve(self.L.T, np.linalg.solve(self.L, r))

    def _basis(self, X: np.ndarray, h0: np.ndarray | None = None,
               tilt: float | None = None) -> np.ndarray:
        """(m, 2) ``(h0(θ), 1)``, or (m, 2 + d) with the tilt's columns ``σ_t (θ − ½)``
        (``tilt``: σ_t, default the chosen one)."""
        h0 = self.feature(X) if h0 is None else h0
        tilt = self.tilt if tilt is None else tilt
        cols = [np.stack([h0, np.ones(X.shape[0])], 1)]
        if tilt > 0:
            cols.append(tilt * (X - 0.5))
        return np.hstack(cols)

    def _cov(self, k: np.ndarray, h1: np.ndarray, h2: np.ndarray,
             sigma_r2: float | None = None) -> np.ndarray:
        s = self.sigma_r2 if sigma_r2 is None else sigma_r2
        return s * k + h1 @ h2.T

    def _log_evidence(self, kX: np.ndarray, hX: np.ndarray, b0: np.ndarray, s: float,
                      noise: float = _NOISE) -> float:
        K = self._cov(kX, hX, hX, s) + noise * np.eye(len(self.v))
        try:
            L = jittered_cholesky(K)
        except np.linalg.LinAlgError:
            return -math.inf
        r = self.v - hX @ b0
        a = np.linalg.solve(L, r)
        return float(-0.5 * a @ a - np.log(np.diag(L)).sum())

    def coefficients(self) -> tuple[np.ndarray, np.ndarray]:
        """Posterior mean (2,) and standard deviation (2,) of (a, b)."""
        H = self.hX
        Kr = self.sigma_r2 * self.kX + self.noise * np.eye(len(self.v))
        Lr = jittered_cholesky(Kr)
        A = np.linalg.solve(Lr, H)
        prec = np.eye(H.shape[1]) + A.T @ A
        cov = np.linalg.inv(prec)
        rhs = self.b0 + A.T @ np.linalg.solve(Lr, self.v)
        return (cov @ rhs)[:2], np.sqrt(np.maximum(np.diag(cov), 0.0))[:2]

    def mean_cov(self, Xs: np.ndarray, with_cov: bool = True
                 ) -> tuple[np.ndarray, np.ndarray | None]:
        """Posterior mean (m,) and, with ``with_cov``, covariance (m, m) at θ ``Xs`` (m, d)."""
        hS = self._basis(Xs)
        Ks = self._cov(matern52(self.X, Xs, self.ls), self.hX, hS)
        mu = hS @ self.b0 + Ks.T @ self.alpha
        if not with_cov:
            return mu, None
        V = np.linalg.solve(self.L, Ks)
        C = self._cov(matern52(Xs, Xs, self.ls), hS, hS) - V.T @ V
        return mu, C

    def loo_mean(self) -> np.ndarray:
        """Leave-one-out posterior means (n,) of the told values ``v`` (:func:`loo_means`)."""
        return loo_means(self.L, self.alpha, self.v)

    def variance(self, Xs: np.ndarray) -> np.ndarray:
        """Posterior marginal variance (m,) at θ ``Xs`` (m, d)."""
        hS = self._basis(Xs)
        Ks = self._cov(matern52(self.X, Xs, self.ls), self.hX, hS)
        V = np.linalg.solve(self.L, Ks)
        prior = self.sigma_r2 + (hS * hS).sum(1)
        return np.maximum(prior - (V * V).sum(0), 0.0)


def target_fall_model(X: np.ndarray, fell: np.ndarray, sm: SourceModel,
                      fit: bool = False) -> TargetModel:
    """The target fall model on told θ ``X`` (n ≥ 1, d) and their fall flags ``fell`` (n,): the
    transfer construction on the flags with ``h = (p_s(θ), 1)`` (``sm``'s fall model) and the
    source's fall lengthscales; with ``fit`` (the ``fall_fit`` option) those times a multiplier
    of :data:`LS_SCALES` and a nugget of :data:`_FALL_NOISES`, chosen with σ_r² by marginal
    likelihood."""
    return TargetModel(X, np.asarray(fell).astype(float), sm.fall_prob, sm.fall_lengthscales,
                       prior_mean=(1.0, 0.0), ls_scales=LS_SCALES if fit else (1.0,),
                       noises=_FALL_NOISES if fit else (_NOISE,))


class TargetGP:
    """A GP on the target's values ``v`` (n,) at θ ``X`` (n, d) alone, fitted as TuRBO-m fits a
    region's GP (``turbo``: a :class:`~latentune.critic.turbo.TurboM` whose ``_build_gp`` /
    ``_fit`` are used): ``v`` standardized (median-centred), constant mean, Matérn-5/2 ARD
    kernel, hyperparameters by L-BFGS-B on the exact marginal likelihood from fixed starting
    values (so they are a function of the data). Predictions are on the scale of ``v``. The
    agreement (:meth:`coefficients`) is that of ``base``, the transfer's own model of the same
    trials."""

    sigma_r2: float
    ls_scale = None

    def __init__(self, X: np.ndarray, v: np.ndarray, turbo: Any, base: TargetModel) -> None:
        self.X, self.v, self.base = X, np.asarray(v, dtype=float), base
        zs, self.med, self.s = turbo._standardize(self.v)
        model = turbo._build_gp(X, zs, None)
        turbo._fit(model, turbo.fit_maxiter)
        h = turbo._hypers_of(model)
        self.ls = np.clip(np.asarray(h["lengthscale"], dtype=float).reshape(-1), *turbo.ls_bounds)
        self.sigma_r2 = float(np.asarray(h["outputscale"]).reshape(-1)[0])
        self.noise = float(np.asarray(h["noise"]).reshape(-1)[0])
        self.constant = float(np.asarray(h["constant"]).reshape(-1)[0])
        self.L = jittered_cholesky(self.sigma_r2 * matern52(X, X, self.ls)
                                   + self.noise * np.eye(len(X)))
        self.alpha = np.linalg.solve(self.L.T, np.linalg.solve(self.L, zs - self.constant))

    def coefficients(self) -> tuple[np.ndarray, np.ndarray]:
        """The transfer model's posterior mean (2,) and standard deviation (2,) of (a, b)."""
        return self.base.coefficients()

    def _cross(self, Xs: np.ndarray) -> np.ndarray:
        """The prior covariance (n, m) of the told θ and θ ``Xs`` (m, d)."""
        return self.sigma_r2 * matern52(self.X, Xs, self.ls)

    def _mean(self, Ks: np.ndarray) -> np.ndarray:
        """Posterior mean (m,) from :meth:`_cross`'s ``Ks`` (n, m)."""
        return self.med + self.s * (self.constant + Ks.T @ self.alpha)

    def _variance(self, Ks: np.ndarray) -> np.ndarray:
        """Posterior marginal variance (m,) from :meth:`_cross`'s ``Ks`` (n, m)."""
        V = np.linalg.solve(self.L, Ks)
        return self.s ** 2 * np.maximum(self.sigma_r2 - (V * V).sum(0), 0.0)

    def mean_cov(self, Xs: np.ndarray, with_cov: bool = True
                 ) -> tuple[np.ndarray, np.ndarray | None]:
        """Posterior mean (m,) and, with ``with_cov``, covariance (m, m) at θ ``Xs`` (m, d)."""
        Ks = self._cross(Xs)
        mu = self._mean(Ks)
        if not with_cov:
            return mu, None
        V = np.linalg.solve(self.L, Ks)
        return mu, self.s ** 2 * (self.sigma_r2 * matern52(Xs, Xs, self.ls) - V.T @ V)

    def variance(self, Xs: np.ndarray) -> np.ndarray:
        """Posterior marginal variance (m,) at θ ``Xs`` (m, d)."""
        return self._variance(self._cross(Xs))

    def loo_mean(self) -> np.ndarray:
        """Leave-one-out posterior means (n,) of the told values ``v``, on their scale
        (:func:`loo_means` of the standardized values)."""
        zs = (self.v - self.med) / self.s
        return self.med + self.s * loo_means(self.L, self.alpha, zs)

    def log_ei(self, Xs: np.ndarray) -> np.ndarray:
        """log expected improvement (m,) at θ ``Xs`` (m, d) below the lowest told value
        (:func:`log_expected_improvement`), mean and variance from one :meth:`_cross` (the
        local search calls it once per point)."""
        Ks = self._cross(Xs)
        return log_expected_improvement(self._mean(Ks), self._variance(Ks), float(self.v.min()))


def fit_residual_kernel(X: np.ndarray, v: np.ndarray, h0: np.ndarray,
                        prior_mean: tuple[float, float], ls0: np.ndarray, sigma_r2_0: float
                        ) -> tuple[np.ndarray, float]:
    """MAP ARD lengthscales (d,) and ``σ_r²`` of :class:`TargetModel`'s residual kernel, fitted
    with GPyTorch/BoTorch on the target's values ``v`` (n,) at θ ``X`` (n, d).

    The model is the target model's own: mean ``(h0(θ), 1) · prior_mean``, covariance
    ``σ_r² k_ls + h hᵀ + σ_n² I`` (``h0`` (n,): the source feature at ``X``; ``(a, b)``
    integrated out), with a log-normal prior on each lengthscale centred at the source's
    ``ls0`` (d,) (standard deviation :data:`_ARD_PRIOR_SD` in log space): the source says how the
    cost varies, the target's trials move it where they disagree. Starts at ``(ls0,
    sigma_r2_0)``; on a failed fit returns them."""
    import gpytorch
    import torch
    from botorch.models.gpytorch import GPyTorchModel
    from gpytorch.constraints import Interval
    from gpytorch.kernels import LinearKernel, MaternKernel, ScaleKernel
    from gpytorch.likelihoods import GaussianLikelihood
    from gpytorch.means import LinearMean
    from gpytorch.mlls import ExactMarginalLogLikelihood
    from gpytorch.priors import LogNormalPrior

    n, d = X.shape
    dt = torch.float64
    lo, hi = _LS_BOUNDS
    ls0 = np.clip(np.asarray(ls0, dtype=float), lo * 1.01, hi * 0.99)
    s_lo, s_hi = 0.005, 8.0
    T = torch.as_tensor(np.column_stack([X, h0, np.ones(n)]), dtype=dt)
    Y = torch.as_tensor(np.asarray(v, dtype=float), dtype=dt)

    class _Model(gpytorch.models.ExactGP, GPyTorchModel):
        _num_outputs = 1

        def __init__(self) -> None:
            super().__init__(T, Y, GaussianLikelihood())
            self.mean_module = LinearMean(d + 2, bias=False)
            self.residual = ScaleKernel(
                MaternKernel(nu=2.5, ard_num_dims=d, active_dims=torch.arange(d),
                             lengthscale_constraint=Interval(lo, hi),
                             lengthscale_prior=LogNormalPrior(
                                 torch.as_tensor(np.log(ls0), dtype=dt),
                                 torch.full((d,), _ARD_PRIOR_SD, dtype=dt))),
                outputscale_constraint=Interval(s_lo, s_hi))
            self.basis = LinearKernel(active_dims=torch.tensor([d, d + 1]))

        def forward(self, x: torch.Tensor) -> gpytorch.distributions.MultivariateNormal:
            return gpytorch.distributions.MultivariateNormal(
                self.mean_module(x), self.residual(x) + self.basis(x))

    model = _Model().to(dt)
    with torch.no_grad():
        w = torch.zeros(d + 2, 1, dtype=dt)
        w[d, 0], w[d + 1, 0] = float(prior_mean[0]), float(prior_mean[1])
        model.mean_module.weights.copy_(w)
        model.basis.variance = torch.tensor(1.0, dtype=dt)
        model.likelihood.noise = torch.tensor([_NOISE], dtype=dt)
        model.residual.base_kernel.lengthscale = torch.as_tensor(ls0, dtype=dt).reshape(1, d)
        model.residual.outputscale = torch.tensor(float(np.clip(sigma_r2_0, s_lo * 1.01,
                                                                s_hi * 0.99)), dtype=dt)
    for prm in (model.mean_module.weights, model.basis.raw_variance,
                model.likelihood.noise_covar.raw_noise):
        prm.requires_grad_(False)
    model.train()
    mll = ExactMarginalLogLikelihood(model.likelihood, model)
    try:
        _scipy_fit(mll)
        ls = model.residual.base_kernel.lengthscale.detach().numpy().reshape(d).copy()
        s2 = float(model.residual.outputscale.detach())
    except Exception as exc:  # noqa: BLE001 - reported, the source's lengthscales kept
        log.warning("target lengthscale fit failed (%s: %s); using the source's",
                    type(exc).__name__, exc)
        return np.asarray(ls0, dtype=float), float(sigma_r2_0)
    if not (np.all(np.isfinite(ls)) and math.isfinite(s2)):
        return np.asarray(ls0, dtype=float), float(sigma_r2_0)
    return ls, s2


def agreement_unmeasured(model: Any) -> str | None:
    """Why the agreement of the target's cost model ``model`` (a :class:`TargetModel`, or a
    model with its ``base``; None: no model yet) is only its prior: no target model yet, the
    target's scores ``v`` do not vary over its trials, or the source model is the same at each
    of them (its feature ``h0X``); None when the data can measure it. Read only: it changes no
    ask (``status``/``report`` print it instead of a number)."""
    if model is None:
        return "no target model yet"
    base = getattr(model, "base", model)
    if np.ptp(np.asarray(model.v, dtype=float)) <= 0:
        return "the target's costs do not vary"
    if np.ptp(np.asarray(getattr(base, "h0X", model.v), dtype=float)) <= 0:
        return "the source's costs do not vary where the target tried"
    return None
