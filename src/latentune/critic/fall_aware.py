"""Fall-aware critics: a probabilistic classifier of ``fell`` that keeps any critic's suggestions
out of regions where trials are predicted to fail.

:class:`FallAware` wraps a critic (TuRBO-m, CMA-ES, random, Sobol or any other
:class:`~latentune.critic.base.Critic`) and is itself a critic on the same box ``[0, 1]^dim``
with the same ask/tell/tag protocol. It keeps a :class:`FallClassifier` of the ``fell`` flag,
fitted on every told point and on optional prior data (e.g. a source run's stable and fallen θ
mapped into this box), and uses it to screen the inner critic's candidates.

Asking
------
The inner critic only ever receives tells; every ask is made on a copy of it (``copy.deepcopy``),
so the inner critic's state is a function of the told history alone, and points that were asked
but never told leave no trace in it. (For TuRBO-m the GP hyperparameters fitted during the ask
are copied back, so its hyperparameter refits follow TuRBO-m's own schedule.)

* Until the prior or the told points hold both classes (at least one fell and one not), the
  inner critic's points are passed through unchanged: ``ask(n)`` returns the copy's ``ask(n)``.
* TuRBO-m, random, Sobol and other critics (drop mode): the copy is asked for
  ``oversample·n`` candidates; those with predicted fall probability ``> max_fall_prob`` are
  dropped and the first ``n`` of the rest are returned in the inner critic's order. If fewer than
  ``n`` survive, the remainder are the candidates with the lowest predicted probability (counted
  in :attr:`FallAware.last_n_over`). Warm-start points (tag ``-2`` or a row of ``x0``) are never
  screened. TuRBO-m's initial-design points (tag kind 0) are not dropped, since a region needs
  its whole design told before it models anything; one predicted to fall is *replaced*, under
  the same tag, by the first of 64 scrambled-Sobol points of the box (a sequence seeded by the
  critic's seed, the tag and the point's rank among that tag's points) that is not predicted to
  fall (else the one with the lowest probability). TuRBO-m counts design points by their tag,
  not by their position, so its state is the same as if the design had held that point.
* CMA-ES (penalise mode): pycma updates only on complete generations of ``popsize`` points, so
  dropping points would stop it. Instead each generation is sampled whole; members predicted to
  fall are not returned (not evaluated) but are told to CMA-ES, once the generation's evaluated
  members have all been told, with the cost ``M + 1 + p`` (``M`` = the largest finite cost of
  the evaluated members of this and all earlier generations, ``p`` = the member's predicted
  probability), i.e. ranked below every evaluated member and among themselves by ``p``. Every
  generation has at least one evaluated member (the one with the lowest ``p`` if none is under
  the threshold, counted in :attr:`FallAware.last_n_over`). ``oversample`` is not used. A
  generation's classifier is fitted on the prior, the untagged told points and the evaluated
  members of the generations already passed to CMA-ES when it was sampled (the number the
  CMA-ES tag records), so a resumed critic rebuilds the same generations.

Telling
-------
``tell(X, y, tags=None, fell=None)``: ``fell`` (n,) bool are the trials that failed, data of the
trial like its cost (the pipeline tells the stored flags); when absent, only a non-finite cost
counts as failed (a cost alone cannot say it: each system fails on its own scale).
Tags are the inner critic's tags, passed through unchanged, and so are the flags (a TuRBO-m
with ``fall_shrink`` shrinks a region whose batch fell too often; the pipeline's fall-aware
TuRBO-m has it, see :func:`latentune.pipeline.phases.make_phase_critic`).

Resume
------
A fresh ``FallAware`` (with a fresh inner critic of the same options and seed, and the same
options and prior) told a stored history ``(X, y, tags, fell)`` -- in one call or in the
original tell calls, in any order within a batch -- asks the same next batch as the original,
whenever the inner critic's own resume is exact (random, Sobol, CMA-ES, TuRBO-m with
``warm_start=False``; TuRBO-m's warm-started hyperparameters may differ in the last digits, as
without this wrapper). The classifier sees the told points sorted by (tag, point), so the order
of points inside a batch does not matter. Two limits: untagged points told after the first ask
enter a CMA-ES generation's classifier from the next generation on in the original run but at
once in a resumed one, and a CMA-ES restart while a generation is in flight may break the count
a generation's tag records.

Asks are synchronous: a second ``ask`` without a ``tell`` in between continues from the first
(new points); after a tell, points asked and not told are dropped (drop mode) or served again
first (CMA-ES, whose generations must be completed).

The classifier
--------------
:class:`FallClassifier` is a least-squares GP classifier (Rasmussen & Williams 2006, §6.5): a GP
regression on labels ``+1`` (fell) / ``-1`` (did not), constant mean, Matérn-5/2 ARD kernel,
hyperparameters by maximum marginal likelihood, then a probit calibration of the GP's
leave-one-out predictions, ``P(fell | x) = Φ((μ(x) + c) / √(s² + σ²(x)))`` (μ, σ²: the GP's
predictive mean and variance of the label). Far from the data the probability returns to the
level of the GP's constant mean instead of extrapolating. Prior data (a source run) get a GP of
their own whose mean is the prior mean of the told points' GP (:class:`FallClassifier`).
``python -m benchmarks.fall_avoidance --part classifiers`` compares it with a Dirichlet GP, a logistic
regression on random Fourier features and k nearest neighbours (results in
``results/fall_avoidance/``).

Diagnostics
-----------
A hyperparameter fit of the classifier that fails (the optimizer raises or ends at a non-finite
point) keeps the starting hyperparameters; the first failure is logged (a ``WARNING`` of this
module's logger) and every one is counted in :meth:`FallAware.stats` (``n_fit_failed``; the
inner critic's own counts are under ``inner_stats``).
"""
from __future__ import annotations

import copy
import hashlib
import logging
import math
import warnings
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from latentune.critic.base import X0_TAG, Critic, FitReport, as_unit_points

logger = logging.getLogger(__name__)


# ============================================================================ classifier
def _matern52(X1, X2, ls):
    """Matérn-5/2 correlation (n1, n2) of torch points scaled by lengthscales ``ls`` (d,)."""
    import torch

    A, B = X1 / ls, X2 / ls
    d2 = (A * A).sum(1, keepdim=True) - 2.0 * A @ B.T + (B * B).sum(1)[None, :]
    r = torch.sqrt(d2.clamp_min(1e-30))
    s5 = math.sqrt(5.0) * r
    return (1.0 + s5 + s5 * s5 / 3.0) * torch.exp(-s5)


def _matern52_np(X1: np.ndarray, X2: np.ndarray, ls: np.ndarray) -> np.ndarray:
    """NumPy twin of :func:`_matern52` (no gradients; faster for the conditioning)."""
    A, B = X1 / ls, X2 / ls
    d2 = (A * A).sum(1)[:, None] - 2.0 * (A @ B.T) + (B * B).sum(1)[None, :]
    s5 = np.sqrt(5.0 * np.maximum(d2, 1e-30))
    return (1.0 + s5 + s5 * s5 / 3.0) * np.exp(-s5)


def _cholesky(K: np.ndarray) -> np.ndarray | None:
    """Lower Cholesky factor of ``K``, adding jitter if needed; ``None`` if it fails."""
    from scipy.linalg import cholesky

    n = K.shape[0]
    for jitter in (0.0, 1e-6, 1e-4, 1e-2):
        try:
            return cholesky(K + jitter * np.eye(n), lower=True, check_finite=False)
        except np.linalg.LinAlgError:
            continue
    return None


class FallClassifier:
    """Least-squares GP classifier of a binary label over ``[0, 1]^dim`` (module docstring).

    Args:
        dim: dimension of the box.
        max_points: a GP is conditioned on at most this many points (the last ones in data
            order).
        max_fit_points: hyperparameters and the probit calibration are fitted on at most this
            many points: up to half from each class, the last ones in data order.
        refit_fraction: hyperparameters and calibration are refitted when the data grow past a
            checkpoint ``c_{k+1} = c_k + max(1, ⌈refit_fraction·min(c_k, max_fit_points)⌉)``, on
            the first ``c_k`` points, from fixed starting values: a deterministic function of
            the data.

    Prior data (:meth:`set_prior`, e.g. another system's trials) get a GP of their own; its
    posterior mean ``m_prior(x)`` is the prior mean of the GP of the caller's points (which then
    models the residual labels ``±1 − m_prior(x)``). Where the caller's points are, they decide;
    far from them the prior's prediction remains.

    Hyperparameters: lengthscales in [0.01, 10] (box units) with a log-normal prior (median 0.3,
    log-sd 2), outputscale in [0.05, 10], noise variance in [1e-3, 1], constant mean in [-2, 2];
    L-BFGS-B, at most 60 iterations. Calibration ``P(fell | x) = Φ((μ(x) + c)/√(s² + σ²(x)))``
    with ``(c, s)`` by maximum leave-one-out probit likelihood (Rasmussen & Williams §6.5) on
    the fitted points of the caller's GP and of the prior's GP.
    """

    def __init__(self, dim: int, *, max_points: int = 1000, max_fit_points: int = 300,
                 refit_fraction: float = 0.2, fit_report: FitReport | None = None) -> None:
        self.dim = int(dim)
        self.fit_report = fit_report or FitReport("fall classifier GP", logger)
        self.max_points = int(max_points)
        self.max_fit_points = int(max_fit_points)
        self.refit_fraction = float(refit_fraction)
        self._cache: dict[tuple[int, str], dict[str, Any]] = {}
        self._prior: dict[str, Any] | None = None
        self._model: dict[str, Any] | None = None

    # ------------------------------------------------------------------ pieces
    def _checkpoint(self, n: int) -> int:
        c = 2
        while True:
            nxt = c + max(1, math.ceil(self.refit_fraction * min(c, self.max_fit_points)))
            if nxt > n:
                return c
            c = nxt

    def _fit_subset(self, fell: np.ndarray) -> np.ndarray:
        """Indices (sorted) of at most ``max_fit_points`` points: half per class, last first."""
        n = fell.shape[0]
        if n <= self.max_fit_points:
            return np.arange(n)
        pos, neg = np.flatnonzero(fell), np.flatnonzero(~fell)
        half = self.max_fit_points // 2
        k_pos = min(pos.size, max(half, self.max_fit_points - neg.size))
        k_neg = min(neg.size, self.max_fit_points - k_pos)
        return np.sort(np.concatenate([pos[pos.size - k_pos:], neg[neg.size - k_neg:]]))

    def _nll(self, theta: np.ndarray, X, y) -> tuple[float, np.ndarray]:
        import torch

        d = self.dim
        t = torch.as_tensor(theta, dtype=torch.float64).requires_grad_(True)
        ls, os_, nz, m = torch.exp(t[:d]), torch.exp(t[d]), torch.exp(t[d + 1]), t[d + 2]
        K = os_ * _matern52(X, X, ls) + (nz + 1e-6) * torch.eye(X.shape[0], dtype=torch.float64)
        L, info = torch.linalg.cholesky_ex(K)
        if int(info) != 0:
            return 1e10, np.zeros_like(theta)
        r = (y - m).reshape(-1, 1)
        a = torch.cholesky_solve(r, L)
        nll = 0.5 * (r * a).sum() + torch.log(torch.diagonal(L)).sum()
        nll = nll + 0.125 * ((t[:d] - math.log(0.3)) ** 2).sum()      # log-normal prior, sd 2
        nll.backward()
        return float(nll.item()), t.grad.numpy().astype(float).copy()

    def _hypers(self, X: np.ndarray, r: np.ndarray, fell: np.ndarray) -> dict[str, Any]:
        """GP hyperparameters for targets ``r`` (n,) at ``X`` of the checkpoint of ``len(X)``
        points, with the leave-one-out predictions of the fitted points (cached)."""
        import torch
        from scipy.linalg import cho_solve
        from scipy.optimize import minimize

        c = self._checkpoint(X.shape[0])
        Xc, rc, fc = X[:c], r[:c], fell[:c]
        key = (c, hashlib.sha1(np.ascontiguousarray(Xc).tobytes() + rc.tobytes()
                               + fc.tobytes()).hexdigest())
        if key in self._cache:
            return self._cache[key]
        sub = self._fit_subset(fc)
        Xs, rs = Xc[sub], rc[sub]
        d = self.dim
        theta0 = np.concatenate([np.full(d, math.log(0.3)), [0.0, math.log(0.1), 0.0]])
        bounds = ([(math.log(0.01), math.log(10.0))] * d
                  + [(math.log(0.05), math.log(10.0)), (math.log(1e-3), 0.0), (-2.0, 2.0)])
        theta = theta0
        try:
            with warnings.catch_warnings():
                # L-BFGS-B's line search may step past a bound before clipping: harmless
                warnings.filterwarnings("ignore", message="Values in x were outside bounds",
                                        category=RuntimeWarning)
                res = minimize(self._nll, theta0,
                               args=(torch.as_tensor(Xs, dtype=torch.float64),
                                     torch.as_tensor(rs, dtype=torch.float64)),
                               jac=True, method="L-BFGS-B", bounds=bounds,
                               options={"maxiter": 60})
        except (RuntimeError, ValueError, ArithmeticError) as exc:
            self.fit_report.record(False, f"{type(exc).__name__}: {exc}")
        else:
            ok = bool(np.all(np.isfinite(res.x)))
            self.fit_report.record(ok, "" if ok else f"non-finite optimum ({res.message})")
            if ok:
                theta = np.asarray(res.x, dtype=float)
        h = {"ls": np.exp(theta[:d]), "os": float(np.exp(theta[d])),
             "nz": float(np.exp(theta[d + 1])), "mean": float(theta[d + 2]),
             "loo_X": Xs, "loo_lab": np.where(fc[sub], 1.0, -1.0),
             "loo_mu": np.zeros(len(sub)), "loo_var": np.ones(len(sub))}
        L = _cholesky(h["os"] * _matern52_np(Xs, Xs, h["ls"]) + (h["nz"] + 1e-6) * np.eye(len(rs)))
        if L is not None:     # leave-one-out predictions (R&W eq. 5.12) of the targets
            Kinv = cho_solve((L, True), np.eye(len(rs)), check_finite=False)
            dinv = np.maximum(np.diag(Kinv), 1e-12)
            h["loo_mu"] = rs - (Kinv @ (rs - h["mean"])) / dinv
            h["loo_var"] = 1.0 / dinv
        if len(self._cache) > 8:
            self._cache.pop(next(iter(self._cache)))
        self._cache[key] = h
        return h

    def _condition(self, X: np.ndarray, r: np.ndarray, h: dict[str, Any]) -> dict[str, Any] | None:
        """The GP with hyperparameters ``h`` conditioned on the last ``max_points`` points."""
        from scipy.linalg import cho_solve

        keep = slice(max(0, X.shape[0] - self.max_points), None)
        Xc, rc = X[keep], r[keep]
        L = _cholesky(h["os"] * _matern52_np(Xc, Xc, h["ls"]) + (h["nz"] + 1e-6) * np.eye(len(rc)))
        if L is None:
            return None
        return {"X": Xc, "L": L, "alpha": cho_solve((L, True), rc - h["mean"], check_finite=False),
                "ls": h["ls"], "os": h["os"], "nz": h["nz"], "mean": h["mean"]}

    @staticmethod
    def _posterior(gp: dict[str, Any], Xs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Predictive mean and variance (with noise) (n,), (n,) of a conditioned GP."""
        from scipy.linalg import solve_triangular

        Ks = gp["os"] * _matern52_np(Xs, gp["X"], gp["ls"])
        mu = Ks @ gp["alpha"] + gp["mean"]
        v = solve_triangular(gp["L"], Ks.T, lower=True, check_finite=False)
        return mu, np.maximum(gp["os"] + gp["nz"] - (v * v).sum(0), 1e-12)

    @staticmethod
    def _calibrate(mu: np.ndarray, var: np.ndarray, lab: np.ndarray) -> tuple[float, float]:
        """Probit calibration ``(c, s)`` maximizing ``Σ log Φ(lab·(mu + c)/√(s² + var))``
        (R&W's ``(a, b)`` with ``a = 1/s``, ``b = c/s``); ``c`` in [-2, 2], ``s`` in [1e-3, 10]."""
        from scipy.optimize import minimize
        from scipy.special import log_ndtr

        def loss(v: np.ndarray) -> float:
            z = lab * (mu + v[0]) / np.sqrt(np.exp(2.0 * v[1]) + var)
            return float(-log_ndtr(z).sum())

        cal = minimize(loss, np.array([0.0, 0.0]), method="L-BFGS-B",
                       bounds=[(-2.0, 2.0), (math.log(1e-3), math.log(10.0))])
        if not np.all(np.isfinite(cal.x)):
            return 0.0, 1.0
        return float(cal.x[0]), float(np.exp(cal.x[1]))

    # ------------------------------------------------------------------ API
    def set_prior(self, X: np.ndarray, fell: np.ndarray) -> None:
        """Prior data: points ``X`` (m, dim) and labels ``fell`` (m,) bool (see the class
        docstring). Used only if both classes occur; ``m = 0`` removes the prior."""
        X = np.asarray(X, dtype=float).reshape(-1, self.dim)
        fell = np.asarray(fell, dtype=bool).reshape(-1)
        self._prior = None
        if not (fell.any() and (~fell).any()):
            return
        lab = np.where(fell, 1.0, -1.0)
        h = self._hypers(X, lab, fell)
        gp = self._condition(X, lab, h)
        if gp is not None:
            self._prior = {"gp": gp, "loo_mu": h["loo_mu"], "loo_var": h["loo_var"],
                           "loo_lab": h["loo_lab"]}

    def fit(self, X: np.ndarray, fell: np.ndarray) -> bool:
        """Fit on points ``X`` (n, dim) in [0, 1]^dim with labels ``fell`` (n,) bool, in data
        order (later points take precedence when the caps apply). Returns whether the
        classifier is active: the prior or these points hold both classes. An inactive
        classifier predicts nothing."""
        X = np.asarray(X, dtype=float).reshape(-1, self.dim)
        fell = np.asarray(fell, dtype=bool).reshape(-1)
        self._model = None
        both = bool(fell.any() and (~fell).any())
        pr = self._prior
        if not both and pr is None:
            return False
        lab = np.where(fell, 1.0, -1.0)
        if pr is None:
            m0 = np.zeros(len(lab))
        elif len(lab):
            m0 = self._posterior(pr["gp"], X)[0]
        else:
            c, sc = self._calibrate(pr["loo_mu"], pr["loo_var"], pr["loo_lab"])
            self._model = {"gp": None, "c": c, "s": sc}
            return True
        h = self._hypers(X, lab - m0, fell)
        gp = self._condition(X, lab - m0, h)
        if gp is None:
            return False
        # calibration data: the fitted points' leave-one-out predictions of the label
        m_loo = self._posterior(pr["gp"], h["loo_X"])[0] if pr is not None else 0.0
        mu, var, lb = h["loo_mu"] + m_loo, h["loo_var"], h["loo_lab"]
        if pr is not None:
            mu, var = np.concatenate([mu, pr["loo_mu"]]), np.concatenate([var, pr["loo_var"]])
            lb = np.concatenate([lb, pr["loo_lab"]])
        c, sc = self._calibrate(mu, var, lb)
        self._model = {"gp": gp, "c": c, "s": sc}
        return True

    @property
    def active(self) -> bool:
        """Whether the last :meth:`fit` was active."""
        return self._model is not None

    def predict(self, X: np.ndarray) -> np.ndarray:
        """Predicted probability of the positive label (fell) at ``X`` (n, dim): (n,) in [0, 1]."""
        from scipy.special import ndtr

        if self._model is None:
            raise RuntimeError("the classifier is not active (fit it on both classes)")
        md = self._model
        Xs = np.asarray(X, dtype=float).reshape(-1, self.dim)
        mu = np.zeros(Xs.shape[0])
        if self._prior is not None:
            mu, var = self._posterior(self._prior["gp"], Xs)
        if md["gp"] is not None:
            mr, var = self._posterior(md["gp"], Xs)
            mu = mu + mr
        return ndtr((mu + md["c"]) / np.sqrt(md["s"] ** 2 + var))


# ============================================================================ the wrapper
@dataclass
class _Gen:
    """One CMA-ES generation as FallAware handles it."""

    g: int                      # CMA-ES generation number
    c: int                      # generations passed to CMA-ES when it was sampled (tag)
    X: np.ndarray               # (popsize, dim) members, CMA-ES order
    tags: np.ndarray            # (popsize,) CMA-ES tags
    p: np.ndarray               # (popsize,) predicted fall probability (0 when inactive)
    real: np.ndarray            # (popsize,) bool: evaluated (returned by ask)
    over: np.ndarray            # (popsize,) bool: evaluated although p > max_fall_prob
    told: np.ndarray = field(default=None)   # (popsize,) history index of told members, -1

    def __post_init__(self) -> None:
        if self.told is None:
            self.told = np.full(self.X.shape[0], -1, dtype=np.int64)

    @property
    def complete(self) -> bool:
        return bool(np.all(self.told[self.real] >= 0))


class FallAware(Critic):
    """A critic that screens another critic's suggestions with a fall classifier.

    Args:
        inner: a fresh critic (nothing told yet) on [0, 1]^dim; FallAware takes its ``dim``,
            ``batch_size``, ``seed`` and ``x0``.
        max_fall_prob: candidates with predicted fall probability above this are not returned
            (0 < max_fall_prob <= 1; 1 screens nothing).
        prior_X: optional points (m, dim) in [0, 1]^dim with known outcome, e.g. a source run's
            θ mapped into this box; they enter the classifier (as the prior mean of the told
            points' GP, see :class:`FallClassifier`), not the inner critic.
        prior_fell: (m,) bool, whether each prior point's trial failed (required with
            ``prior_X``).
        oversample: candidates asked from the inner critic per returned point (drop mode).
        max_points, max_fit_points, refit_fraction: see :class:`FallClassifier`.
        threads: torch threads while the classifier runs (restored afterwards); ``None`` leaves
            torch's setting alone.

    Raises ``ValueError`` for bad arguments. See the module docstring for the behaviour.
    """

    method = "fall_aware"

    def __init__(self, inner: Critic, max_fall_prob: float = 0.5,
                 prior_X: np.ndarray | None = None, prior_fell: np.ndarray | None = None,
                 oversample: int = 5, *, max_points: int = 1000, max_fit_points: int = 300,
                 refit_fraction: float = 0.2, threads: int | None = 1) -> None:
        if not isinstance(inner, Critic):
            raise ValueError(f"inner must be a Critic, got {type(inner).__name__}")
        if isinstance(inner, FallAware):
            raise ValueError("inner is already a FallAware critic")
        if inner.n_told:
            raise ValueError(f"inner must be a fresh critic, it was told {inner.n_told} points")
        super().__init__(inner.dim, batch_size=inner.batch_size, seed=inner.seed, x0=inner.x0)
        if isinstance(max_fall_prob, bool) or not isinstance(max_fall_prob, (int, float,
                                                                             np.number)):
            raise ValueError(f"max_fall_prob must be a number in (0, 1], got {max_fall_prob!r}")
        if not (0.0 < float(max_fall_prob) <= 1.0):
            raise ValueError(f"max_fall_prob must be in (0, 1], got {max_fall_prob!r}")
        if isinstance(oversample, bool) or not isinstance(oversample, (int, np.integer)) \
                or oversample < 1:
            raise ValueError(f"oversample must be an integer >= 1, got {oversample!r}")
        for name, v, lo in (("max_points", max_points, 4), ("max_fit_points", max_fit_points, 4)):
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < lo:
                raise ValueError(f"{name} must be an integer >= {lo}, got {v!r}")
        if not (isinstance(refit_fraction, (int, float)) and 0.0 < refit_fraction <= 1.0):
            raise ValueError(f"refit_fraction must be in (0, 1], got {refit_fraction!r}")
        if threads is not None and (isinstance(threads, bool) or not isinstance(threads, int)
                                    or threads < 1):
            raise ValueError(f"threads must be None or an integer >= 1, got {threads!r}")
        if (prior_X is None) != (prior_fell is None):
            raise ValueError("prior_X and prior_fell must be given together")
        if prior_X is None:
            self.prior_X = np.empty((0, self.dim))
            self.prior_fell = np.empty(0, dtype=bool)
        else:
            self.prior_X = as_unit_points(prior_X, self.dim, "prior_X")
            self.prior_fell = _as_flags(prior_fell, self.prior_X.shape[0], "prior_fell")
        self.inner = inner
        self.max_fall_prob = float(max_fall_prob)
        self.oversample = int(oversample)
        self.threads = threads
        self.classifier = FallClassifier(self.dim, max_points=int(max_points),
                                         max_fit_points=int(max_fit_points),
                                         refit_fraction=float(refit_fraction),
                                         fit_report=FitReport("fall classifier GP", logger))
        self._prior_set = False
        self._fell = np.empty(0, dtype=bool)
        self._probe: Critic | None = None
        self.last_fall_prob = np.empty(0)
        """(n,) predicted fall probability of the last asked points (nan: classifier inactive)."""
        self.last_n_over = 0
        """Points of the last ask returned although over ``max_fall_prob`` (too few below)."""
        self.last_n_screened = 0
        """Candidates of the last ask predicted to fall and not returned (drop mode: skipped
        before the last returned one; CMA-ES: members of newly sampled generations)."""
        self.n_over = 0
        """Total of :attr:`last_n_over` over all asks."""
        self.n_screened = 0
        """Total of :attr:`last_n_screened` over all asks."""
        from latentune.critic.cmaes import CMAES
        from latentune.critic.turbo import TurboM

        self._turbo = isinstance(inner, TurboM)
        self._cma = isinstance(inner, CMAES)
        # CMA-ES bookkeeping
        self._gens: list[_Gen] = []
        self._n_passed = 0                       # generations told to the inner CMA-ES
        self._max_real = -math.inf               # largest finite cost of evaluated members
        self._untagged: list[int] = []           # history indices of untagged told points
        self._unbuilt: dict[int, list[int]] = {}  # resume: generation -> told indices
        self._unbuilt_c: dict[int, int] = {}
        self._served: set[tuple[int, int]] = set()
        self.inexact_replay = False
        """True when a told history could not be matched to rebuilt CMA-ES generations."""

    # ------------------------------------------------------------------ data
    @property
    def fell(self) -> np.ndarray:
        """The ``fell`` flags (n,) bool of all told points, in tell order."""
        return self._fell.copy()

    def _canonical(self, idx: np.ndarray) -> np.ndarray:
        """``idx`` sorted by (tag, point): independent of the order inside a batch."""
        idx = np.asarray(idx, dtype=np.int64)
        if idx.size == 0:
            return idx
        keys = [self._X[idx, j] for j in range(self.dim - 1, -1, -1)] + [self._tags[idx]]
        return idx[np.lexsort(keys)]

    def _fit(self, idx: np.ndarray) -> FallClassifier | None:
        """The classifier fitted on the prior and told points ``idx`` (in the given order)."""
        with _torch_threads(self.threads):
            if not self._prior_set:
                self.classifier.set_prior(self.prior_X, self.prior_fell)
                self._prior_set = True
            return self.classifier if self.classifier.fit(self._X[idx], self._fell[idx]) else None

    def fall_prob(self, X: np.ndarray) -> np.ndarray | None:
        """Predicted fall probability (n,) at ``X`` (n, dim) from the prior and every told point;
        ``None`` while the data hold only one class."""
        X = as_unit_points(X, self.dim)
        clf = self._fit(self._canonical(np.arange(self.n_told)))
        if clf is None:
            return None
        with _torch_threads(self.threads):
            return clf.predict(X)

    # ------------------------------------------------------------------ tell
    def tell(self, X: np.ndarray, y: np.ndarray, tags: np.ndarray | None = None,
             fell: np.ndarray | None = None) -> None:
        """Report raw costs ``y`` (n,) of ``X`` (n, dim) with the inner critic's ``tags`` and the
        ``fell`` flags (n,) bool (default: the non-finite costs); see the module docstring."""
        Xa = as_unit_points(X, self.dim)
        ya = np.asarray(y, dtype=float).reshape(-1)
        if ya.shape[0] != Xa.shape[0]:
            raise ValueError(f"y must have shape ({Xa.shape[0]},), got {np.shape(y)}")
        if fell is None:
            fa = ~np.isfinite(ya)
        else:
            fa = _as_flags(fell, Xa.shape[0], "fell")
        if Xa.shape[0] == 0:
            return
        if not self._cma:
            self.inner.tell(Xa, ya, tags, fell=fa)   # validates the tags for the inner critic
        self._incoming_fell = fa
        super().tell(Xa, ya, tags)

    def _tell(self, idx: np.ndarray, tags: np.ndarray) -> None:
        self._fell = np.concatenate([self._fell, self._incoming_fell])
        self._probe = None
        self._served.clear()
        if self._cma:
            self._tell_cma(idx, tags)

    # ------------------------------------------------------------------ ask
    def _ask(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        if self._cma:
            return self._ask_cma(n)
        probe = self._probe if self._probe is not None else copy.deepcopy(self.inner)
        self._probe = probe
        clf = self._fit(self._canonical(np.arange(self.n_told)))
        if clf is None:
            X = probe.ask(n)
            T = probe.last_tags.copy()
            self._sync(probe)
            self.last_fall_prob = np.full(n, np.nan)
            self.last_n_over = self.last_n_screened = 0
            return X, T
        C = probe.ask(n * self.oversample)
        T = probe.last_tags.copy()
        self._sync(probe)
        with _torch_threads(self.threads):
            p = clf.predict(C)
        ex = self._exempt(C, T)
        design = self._design(T) & ~ex
        ok = ex | design | (p <= self.max_fall_prob)
        sel = np.flatnonzero(ok)[:n]
        n_over = 0
        if sel.size < n:
            rest = np.flatnonzero(~ok)
            fill = rest[np.argsort(p[rest], kind="stable")[: n - sel.size]]
            sel = np.sort(np.concatenate([sel, fill]))
            n_over = int(fill.size)
        screened = int(np.count_nonzero(~ok[: sel[-1] + 1])) - n_over
        rank: dict[int, int] = {}
        for i in sel[design[sel]]:
            j = rank[int(T[i])] = rank.get(int(T[i]), -1) + 1
            if p[i] > self.max_fall_prob:
                C[i], p[i] = self._replacement(clf, int(T[i]), j)
                screened += 1
                n_over += int(p[i] > self.max_fall_prob)
        self.last_fall_prob = p[sel]
        self.last_n_over, self.last_n_screened = n_over, screened
        self.n_over += n_over
        self.n_screened += screened
        return C[sel], T[sel]

    def _exempt(self, X: np.ndarray, tags: np.ndarray) -> np.ndarray:
        """Candidates that are never screened: the warm-start points (tag -2 or a row of x0)."""
        ex = tags == X0_TAG
        if self.x0 is not None:
            ex |= np.any(np.all(X[:, None, :] == self.x0[None, :, :], axis=2), axis=1)
        return ex

    def _design(self, tags: np.ndarray) -> np.ndarray:
        """TuRBO-m initial-design points among ``tags`` (always False for other critics)."""
        if not self._turbo:
            return np.zeros(tags.shape[0], dtype=bool)
        from latentune.critic.turbo import KIND_DESIGN, decode_tag

        return np.array([t >= 0 and decode_tag(int(t))[1] == KIND_DESIGN for t in tags],
                        dtype=bool)

    def _replacement(self, clf: FallClassifier, tag: int, rank: int) -> tuple[np.ndarray, float]:
        """A design point not predicted to fall: the first of 64 scrambled-Sobol points of the
        region's design box (:meth:`TurboM.design_box <latentune.critic.turbo.TurboM.design_box>`;
        seeded by the seed, ``tag`` and ``rank``) under the threshold, else the one of lowest
        probability; returns ``(x (dim,), p)``."""
        import torch
        from torch.quasirandom import SobolEngine

        from latentune.critic.turbo import decode_tag

        r = decode_tag(tag)[2]
        lo, hi = self.inner.design_box(r, self.inner.regions[r].epoch)
        s = int(np.random.default_rng([self.seed, 7, tag, rank]).integers(2 ** 31))
        Z = SobolEngine(self.dim, scramble=True, seed=s).draw(64, dtype=torch.float64).numpy()
        Z = lo + Z * (hi - lo)
        with _torch_threads(self.threads):
            pz = clf.predict(Z)
        good = np.flatnonzero(pz <= self.max_fall_prob)
        k = int(good[0]) if good.size else int(np.argmin(pz))
        return Z[k], float(pz[k])

    def _sync(self, probe: Critic) -> None:
        """Keep what the ask computed that TuRBO-m caches across asks (GP hyperparameters)."""
        if not self._turbo:
            return
        for ri, rp in zip(self.inner.regions, probe.regions):
            if ri.index == rp.index and ri.epoch == rp.epoch and rp.hypers is not None:
                ri.hypers = copy.deepcopy(rp.hypers)
                ri.fit_count = rp.fit_count

    def state_dict(self) -> dict[str, Any]:
        """The inner critic's :meth:`~latentune.critic.base.Critic.state_dict`."""
        return {"inner": self.inner.state_dict()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        if state and "inner" in state:
            self.inner.load_state_dict(state["inner"])
            self._probe = None

    # ------------------------------------------------------------------ CMA-ES
    def _ask_cma(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        out: list[tuple[int, int]] = []
        p_out: list[float] = []
        self.last_n_over = self.last_n_screened = 0
        while len(out) < n:
            nxt = self._next_member()
            if nxt is None:
                gen = self._build(len(self._gens))
                self.last_n_screened += int(np.count_nonzero(~gen.real))
                continue
            self._served.add(nxt)
            out.append(nxt)
            gen = self._gens[nxt[0]]
            p_out.append(float(gen.p[nxt[1]]) if self._active_at(gen) else math.nan)
            self.last_n_over += int(gen.over[nxt[1]])
        self.n_over += self.last_n_over
        self.n_screened += self.last_n_screened
        self.last_fall_prob = np.asarray(p_out)
        X = np.array([self._gens[k].X[j] for k, j in out])
        T = np.array([self._gens[k].tags[j] for k, j in out], dtype=np.int64)
        return X, T

    @staticmethod
    def _active_at(gen: _Gen) -> bool:
        return bool(np.any(gen.p > 0))

    def _next_member(self) -> tuple[int, int] | None:
        for k in range(self._n_passed, len(self._gens)):
            gen = self._gens[k]
            for j in np.flatnonzero(gen.real & (gen.told < 0)):
                if (k, int(j)) not in self._served:
                    return k, int(j)
        return None

    def _cma_data(self) -> np.ndarray:
        """Told indices a new generation's classifier is fitted on: untagged points, then the
        evaluated members of the generations passed to CMA-ES, in generation order."""
        idx = list(self._untagged)
        for gen in self._gens[: self._n_passed]:
            idx.extend(int(i) for i in gen.told[gen.real])
        return np.asarray(idx, dtype=np.int64)

    def _build(self, g: int) -> _Gen:
        """Sample CMA-ES generation ``g`` (from a copy of the inner CMA-ES) and screen it."""
        from latentune.critic.cmaes import decode_tag

        probe = copy.deepcopy(self.inner)
        P = int(self.inner.popsize)
        X, T = [], []
        while len(X) < P:
            Z = probe.ask(P)
            for x, t in zip(Z, probe.last_tags):
                gg = decode_tag(int(t))[0]
                if gg == g and len(X) < P:
                    X.append(x)
                    T.append(int(t))
                elif gg > g:
                    raise RuntimeError(f"CMA-ES skipped generation {g}")  # pragma: no cover
        Xa, Ta = np.asarray(X), np.asarray(T, dtype=np.int64)
        clf = self._fit(self._cma_data())
        if clf is None:
            p = np.zeros(P)
        else:
            with _torch_threads(self.threads):
                p = np.maximum(clf.predict(Xa), 1e-300)
        ex = self._exempt(Xa, Ta)
        real = ex | (p <= self.max_fall_prob)
        if not real.any():
            real[int(np.argmin(p))] = True
        gen = _Gen(g=g, c=decode_tag(int(Ta[0]))[1], X=Xa, tags=Ta, p=p, real=real,
                   over=real & ~ex & (p > self.max_fall_prob))
        self._gens.append(gen)
        return gen

    def _pass(self, k: int) -> None:
        """Tell the inner CMA-ES generation ``k``: evaluated costs, virtual ones penalised."""
        gen = self._gens[k]
        y = np.empty(gen.X.shape[0])
        yr = self._y[gen.told[gen.real]]
        fin = yr[np.isfinite(yr)]
        if fin.size:
            self._max_real = max(self._max_real, float(fin.max()))
        y[gen.real] = yr
        M = self._max_real if math.isfinite(self._max_real) else 0.0
        y[~gen.real] = M + 1.0 + gen.p[~gen.real]
        self.inner.tell(gen.X, y, gen.tags)
        self._n_passed += 1

    def _tell_cma(self, idx: np.ndarray, tags: np.ndarray) -> None:
        from latentune.critic.cmaes import decode_tag

        for i, t in zip(idx.tolist(), tags.tolist()):
            if t < 0:
                self._untagged.append(i)
                self.inner.tell(self._X[i:i + 1], self._y[i:i + 1], np.array([t]))
                continue
            g, c = decode_tag(int(t))
            if g < len(self._gens):
                self._match(self._gens[g], [i])
            else:
                self._unbuilt.setdefault(g, []).append(i)
                self._unbuilt_c.setdefault(g, c)
        # resume: rebuild the generations in order, each after as many generations were
        # passed to CMA-ES as when it was first sampled (read from its tags)
        while self._unbuilt:
            g = len(self._gens)
            c = self._unbuilt_c.get(g, self._n_passed)
            while self._n_passed < min(c, g) and self._gens[self._n_passed].complete:
                self._pass(self._n_passed)
            if self._n_passed != c:
                self.inexact_replay = True
            gen = self._build(g)
            self._match(gen, self._unbuilt.pop(g, []))
            self._unbuilt_c.pop(g, None)
        while self._n_passed < len(self._gens) and self._gens[self._n_passed].complete:
            self._pass(self._n_passed)

    def _match(self, gen: _Gen, idx: list[int]) -> None:
        """Attach told points to the members of ``gen`` they equal; others become untagged."""
        for i in idx:
            hit = np.flatnonzero(np.all(gen.X == self._X[i], axis=1) & (gen.told < 0))
            if hit.size:
                j = int(hit[0])
                gen.told[j] = i
                if not gen.real[j]:            # told although screened (history mismatch)
                    gen.real[j] = True
                    self.inexact_replay = True
            else:
                self.inexact_replay = True
                self._untagged.append(i)
                self.inner.tell(self._X[i:i + 1], self._y[i:i + 1], None)

    # ------------------------------------------------------------------ report
    def stats(self) -> dict[str, Any]:
        """Counters for logs and run records: asks screened, points over the threshold, the
        classifier's hyperparameter fits (``n_fits``, ``n_fit_failed``) and the inner critic's
        :meth:`~latentune.critic.base.Critic.stats` (``inner_stats``)."""
        return {"method": self.method, "inner": self.inner.method,
                "max_fall_prob": self.max_fall_prob,
                "n_told": self.n_told, "n_fell": int(self._fell.sum()),
                "n_prior": int(self.prior_X.shape[0]),
                "n_over": self.n_over,
                "n_screened": self.n_screened,
                "mode": "penalise" if self._cma else "drop",
                **self.classifier.fit_report.as_dict(),
                "inner_stats": self.inner.stats()}

    def __repr__(self) -> str:
        return (f"FallAware({self.inner!r}, max_fall_prob={self.max_fall_prob}, "
                f"n_prior={self.prior_X.shape[0]}, n_fell={int(self._fell.sum())})")


def _as_flags(v: Any, n: int, name: str) -> np.ndarray:
    """Validate (n,) boolean flags (bool or 0/1 values)."""
    a = np.asarray(v)
    if a.ndim != 1 or a.shape[0] != n:
        raise ValueError(f"{name} must have shape ({n},), got {a.shape}")
    if a.dtype != bool:
        if not np.issubdtype(a.dtype, np.number) or not np.all(np.isin(a, (0, 1))):
            raise ValueError(f"{name} must be booleans (or 0/1)")
        a = a.astype(bool)
    return a.copy()


class _torch_threads:
    """Run a block with ``n`` torch threads and at most ``n`` BLAS/OpenMP threads (``None``:
    unchanged), restoring the settings. The classifier's linear algebra is small; with several
    threads on a busy machine scipy's L-BFGS-B and torch's Cholesky are many times slower."""

    def __init__(self, n: int | None) -> None:
        self.n, self.before, self.limits = n, None, None

    def __enter__(self) -> None:
        if self.n is None:
            return
        import torch
        from threadpoolctl import threadpool_limits

        self.limits = threadpool_limits(self.n)
        self.before = torch.get_num_threads()
        if self.before != self.n:
            torch.set_num_threads(self.n)

    def __exit__(self, *exc: Any) -> None:
        if self.n is None:
            return
        import torch

        if self.before is not None and self.before != self.n:
            torch.set_num_threads(self.before)
        if self.limits is not None:
            self.limits.restore_original_limits()
