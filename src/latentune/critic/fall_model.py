"""The fall model: the probability that a trial at a point of ``[0, 1]^dim`` fails, learnt from
trials with a known outcome.

:class:`FallModel` is the interface a fall-aware critic (:class:`~latentune.critic.fall_aware.
FallAware`) consults: :meth:`FallModel.fit` on points and their ``fell`` flags (and optional
prior data, e.g. another system's trials mapped into this box, :meth:`FallModel.set_prior`),
then :meth:`FallModel.p_fall` (the predicted probability, or an upper bound of it with
``kappa > 0``). Any model with these methods can be given to ``FallAware(model=...)``, e.g. a GP
on the fall flags whose prior mean is a source model's fall probability.

:class:`GPFallModel` (the default) is a least-squares GP classifier (Rasmussen & Williams 2006,
§6.5) on BoTorch/GPyTorch: an exact GP regression (``SingleTaskGP``, constant mean,
``ScaleKernel(MaternKernel(ν=5/2, ARD))``, Gaussian likelihood) on the labels ``+1`` (fell) /
``−1`` (did not), hyperparameters by maximum a posteriori with a normal prior on the log
lengthscales (``botorch.optim.fit.fit_gpytorch_mll_scipy``, L-BFGS-B on log parameters), then a probit calibration of the
GP's leave-one-out predictions: ``P(fell | x) = Φ((μ(x) + c) / √(s² + σ²(x)))`` (μ, σ²: the GP's
predictive mean and variance of the label, observation noise included). Far from the data the
probability returns to the level of the GP's constant mean instead of extrapolating.

Prior data get a GP of their own; its posterior mean is the prior mean of the GP of the fitted
points, which models the residual labels ``±1 − m_prior(x)``. Where the fitted points are, they
decide; far from them the prior's prediction remains.

Determinism: no randomness is involved; hyperparameters are refitted only at checkpoints of the
number of points (:func:`~latentune.critic.base.refit_checkpoint`), on the first ``c`` points,
from fixed starting values, and every linear solve is an exact Cholesky
(``gpytorch.settings.max_cholesky_size`` above ``max_points``): a fit is a deterministic
function of the data.

A hyperparameter fit that fails (the optimizer raises) keeps the starting hyperparameters; the
first failure is logged (a ``WARNING`` of this module's logger) and every one is counted in
:attr:`FallModel.fit_report`.
"""
from __future__ import annotations

import contextlib
import hashlib
import logging
import math
from abc import ABC, abstractmethod
from typing import Any, Iterator

import numpy as np

from latentune.critic.base import FitReport, refit_checkpoint

logger = logging.getLogger(__name__)

_LS_MIN, _OS_MIN, _NOISE_MIN = 0.01, 0.05, 1e-3      # lower bounds (log parameterization)
_MEAN_BOUNDS = (-2.0, 2.0)
_LS_PRIOR = (math.log(0.3), 2.0)          # normal on log ℓ (loc, scale): median 0.3
_START = {"lengthscale": 0.3, "outputscale": 1.0, "noise": 0.1, "constant": 0.0}


def _log_bound(lower: float):
    """A lower bound with a log parameterization (``value = lower + exp(raw)``)."""
    import torch
    from gpytorch.constraints import GreaterThan

    return GreaterThan(lower, transform=torch.exp, inv_transform=torch.log)


class FallModel(ABC):
    """Predicted probability that a trial at ``x`` in ``[0, 1]^dim`` fails (module docstring).

    Attributes:
        dim: the box's dimension.
        fit_report: the model's hyperparameter fits and failed fits (:class:`FitReport`).
    """

    dim: int
    fit_report: FitReport

    def set_prior(self, X: np.ndarray, fell: np.ndarray) -> None:
        """Prior data: points ``X`` (m, dim) and their flags ``fell`` (m,) bool (e.g. a source
        run's trials in this box); ``m = 0`` removes the prior. Models without a prior raise
        ``ValueError`` for ``m > 0``."""
        if np.asarray(fell).size:
            raise ValueError(f"{type(self).__name__} takes no prior data")

    @abstractmethod
    def fit(self, X: np.ndarray, fell: np.ndarray) -> bool:
        """Fit on points ``X`` (n, dim) and flags ``fell`` (n,) bool, in data order (later
        points take precedence where the model caps its data). Returns whether the model is
        :attr:`active`."""

    @property
    @abstractmethod
    def active(self) -> bool:
        """Whether the last :meth:`fit` can predict (the data hold both classes)."""

    @abstractmethod
    def p_fall(self, X: np.ndarray, kappa: float = 0.0) -> np.ndarray:
        """Probability (n,) in [0, 1] that a trial at ``X`` (n, dim) fails; ``kappa > 0`` adds
        ``kappa`` predictive standard deviations of the model's latent function before the link
        (an upper bound, as in safe Bayesian optimization). Raises ``RuntimeError`` when the
        model is not active."""


@contextlib.contextmanager
def torch_threads(n: int | None) -> Iterator[None]:
    """Run a block with ``n`` torch threads and at most ``n`` BLAS/OpenMP threads (``None``:
    unchanged), restoring the settings afterwards. The model's linear algebra is small; with
    several threads on a busy machine it is many times slower."""
    if n is None:
        yield
        return
    import torch
    from threadpoolctl import threadpool_limits

    limits = threadpool_limits(n)
    before = torch.get_num_threads()
    if before != n:
        torch.set_num_threads(n)
    try:
        yield
    finally:
        if before != n:
            torch.set_num_threads(before)
        limits.restore_original_limits()


@contextlib.contextmanager
def _exact_gp(max_points: int) -> Iterator[None]:
    """Exact Cholesky solves (no conjugate gradients or Lanczos) up to ``max_points`` points,
    with the known, handled GP warnings silenced (see :func:`~latentune.critic.turbo.
    gp_warnings_filtered`)."""
    import gpytorch

    from latentune.critic.turbo import gp_warnings_filtered

    with gpytorch.settings.max_cholesky_size(max_points + 1), \
            gpytorch.settings.fast_computations(False, False, False), gp_warnings_filtered():
        yield


class GPFallModel(FallModel):
    """Least-squares GP classifier of the fall flag on BoTorch/GPyTorch (module docstring).

    Args:
        dim: dimension of the box.
        max_points: a GP is conditioned on at most this many points (the last ones in data
            order).
        max_fit_points: hyperparameters and the probit calibration are fitted on at most this
            many points: up to half from each class, the last ones in data order.
        refit_fraction: hyperparameters and calibration are refitted when the data grow past a
            checkpoint (:func:`~latentune.critic.base.refit_checkpoint` with this fraction and
            ``max_fit_points``), on the first ``c`` points, from fixed starting values.
        maxiter: L-BFGS-B iterations of a hyperparameter fit.
        threads: torch threads while the model fits and predicts (restored afterwards);
            ``None`` leaves torch's setting alone.
        fit_report: where fits are counted (default: a new :class:`FitReport`).

    Hyperparameters (log-parameterized): lengthscales >= 0.01 (box units) with a normal prior on
    their logarithm (median 0.3, sd 2), outputscale >= 0.05, noise variance >= 1e-3, constant
    mean in [-2, 2]; the fit starts at lengthscales 0.3, outputscale 1, noise 0.1, mean 0. Calibration ``(c, s)`` by maximum leave-one-out probit likelihood (R&W §6.5) on the
    fitted points of the GP and of the prior's GP, ``c`` in [-2, 2], ``s`` in [1e-3, 10].
    """

    def __init__(self, dim: int, *, max_points: int = 1000, max_fit_points: int = 300,
                 refit_fraction: float = 0.2, maxiter: int = 60, threads: int | None = 1,
                 fit_report: FitReport | None = None) -> None:
        self.dim = int(dim)
        self.max_points = int(max_points)
        self.max_fit_points = int(max_fit_points)
        self.refit_fraction = float(refit_fraction)
        self.maxiter = int(maxiter)
        self.threads = threads
        self.fit_report = fit_report or FitReport("fall model GP", logger)
        self._cache: dict[tuple[int, str], dict[str, Any]] = {}
        self._prior: dict[str, Any] | None = None
        self._model: dict[str, Any] | None = None
        self._fit_key: str | None = None

    # ------------------------------------------------------------------ GP pieces
    def _gp(self, X: np.ndarray, r: np.ndarray, h: dict[str, Any] | None):
        """A ``SingleTaskGP`` on targets ``r`` (n,) at ``X`` (n, dim) with hyperparameters ``h``
        (default: the fixed starting values)."""
        import torch
        from botorch.models import SingleTaskGP
        from gpytorch.constraints import Interval
        from gpytorch.kernels import MaternKernel, ScaleKernel
        from gpytorch.likelihoods import GaussianLikelihood
        from gpytorch.means import ConstantMean
        from gpytorch.priors import NormalPrior

        h = h or {k: np.full(self.dim if k == "lengthscale" else 1, v) for k, v in _START.items()}
        matern = MaternKernel(nu=2.5, ard_num_dims=self.dim,
                              lengthscale_constraint=_log_bound(_LS_MIN))
        # a normal prior on log ℓ (no Jacobian term: its MAP is the median's neighbourhood, not
        # the log-normal density's mode exp(μ − σ²), which is far below the median here)
        matern.register_prior("log_lengthscale_prior", NormalPrior(*_LS_PRIOR),
                              lambda m: m.lengthscale.log(),
                              lambda m, v: m._set_lengthscale(v.exp()))
        kern = ScaleKernel(matern, outputscale_constraint=_log_bound(_OS_MIN))
        model = SingleTaskGP(torch.as_tensor(X, dtype=torch.float64),
                             torch.as_tensor(r, dtype=torch.float64).reshape(-1, 1),
                             likelihood=GaussianLikelihood(noise_constraint=_log_bound(_NOISE_MIN)),
                             covar_module=kern,
                             mean_module=ConstantMean(constant_constraint=Interval(*_MEAN_BOUNDS)),
                             outcome_transform=None)
        model.to(torch.float64)
        t = {k: torch.as_tensor(np.asarray(v, dtype=float), dtype=torch.float64)
             for k, v in h.items()}
        model.covar_module.base_kernel.lengthscale = t["lengthscale"].reshape(1, self.dim)
        model.covar_module.outputscale = t["outputscale"].reshape(())
        model.likelihood.noise = t["noise"].reshape(1)
        model.mean_module.constant = t["constant"].reshape(())
        model.eval()
        return model

    @staticmethod
    def _hypers_of(model) -> dict[str, np.ndarray]:
        return {"lengthscale": model.covar_module.base_kernel.lengthscale.detach().numpy()
                .reshape(-1).copy(),
                "outputscale": model.covar_module.outputscale.detach().numpy().reshape(1).copy(),
                "noise": model.likelihood.noise.detach().numpy().reshape(-1)[:1].copy(),
                "constant": model.mean_module.constant.detach().numpy().reshape(1).copy()}

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

    def _hypers(self, X: np.ndarray, r: np.ndarray, fell: np.ndarray) -> dict[str, Any]:
        """Hyperparameters for targets ``r`` (n,) at ``X``, fitted at the checkpoint of
        ``len(X)`` points, with the leave-one-out predictions of the fitted points (cached)."""
        import torch
        from botorch.optim import fit as botorch_fit
        from gpytorch.mlls import ExactMarginalLogLikelihood

        c = refit_checkpoint(X.shape[0], self.refit_fraction, self.max_fit_points)
        Xc, rc, fc = X[:c], r[:c], fell[:c]
        key = (c, hashlib.sha1(np.ascontiguousarray(Xc).tobytes() + rc.tobytes()
                               + fc.tobytes()).hexdigest())
        if key in self._cache:
            return self._cache[key]
        sub = self._fit_subset(fc)
        Xs, rs = Xc[sub], rc[sub]
        model = self._gp(Xs, rs, None)
        model.train()
        mll = ExactMarginalLogLikelihood(model.likelihood, model)
        try:
            botorch_fit.fit_gpytorch_mll_scipy(mll, options={"maxiter": self.maxiter})
        except (RuntimeError, ValueError, ArithmeticError) as exc:
            self.fit_report.record(False, f"{type(exc).__name__}: {exc}")
            model = self._gp(Xs, rs, None)
        else:
            self.fit_report.record(True)
        model.eval()
        h: dict[str, Any] = {"hypers": self._hypers_of(model), "loo_lab": np.where(fc[sub], 1.0, -1.0)}
        with torch.no_grad():           # leave-one-out predictions (R&W eq. 5.12) of the targets
            Xt = torch.as_tensor(Xs, dtype=torch.float64)
            K = model.covar_module(Xt).to_dense() + model.likelihood.noise * torch.eye(
                len(rs), dtype=torch.float64)
            L, info = torch.linalg.cholesky_ex(K)
            if int(info) == 0:
                Kinv = torch.cholesky_inverse(L).numpy()
                dinv = np.maximum(np.diag(Kinv), 1e-12)
                mean = float(h["hypers"]["constant"][0])
                h["loo_mu"] = rs - (Kinv @ (rs - mean)) / dinv
                h["loo_var"] = 1.0 / dinv
            else:
                h["loo_mu"], h["loo_var"] = np.zeros(len(rs)), np.ones(len(rs))
        h["loo_X"] = Xs
        if len(self._cache) > 8:
            self._cache.pop(next(iter(self._cache)))
        self._cache[key] = h
        return h

    def _condition(self, X: np.ndarray, r: np.ndarray, h: dict[str, Any]):
        """The GP with hyperparameters ``h`` conditioned on the last ``max_points`` points."""
        keep = slice(max(0, X.shape[0] - self.max_points), None)
        return self._gp(X[keep], r[keep], h["hypers"])

    @staticmethod
    def _posterior(model, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Predictive mean and variance (observation noise included) (n,), (n,)."""
        import torch

        with torch.no_grad():
            post = model.posterior(torch.as_tensor(X, dtype=torch.float64),
                                   observation_noise=True)
            return (post.mean.reshape(-1).numpy().copy(),
                    np.maximum(post.variance.reshape(-1).numpy(), 1e-12))

    @staticmethod
    def _calibrate(mu: np.ndarray, var: np.ndarray, lab: np.ndarray) -> tuple[float, float]:
        """Probit calibration ``(c, s)`` maximizing ``Σ log Φ(lab·(mu + c)/√(s² + var))``
        (R&W's ``(a, b)`` with ``a = 1/s``, ``b = c/s``)."""
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

    # ------------------------------------------------------------------ interface
    def set_prior(self, X: np.ndarray, fell: np.ndarray) -> None:
        """Prior data ``X`` (m, dim), ``fell`` (m,) bool; used only if both classes occur
        (module docstring)."""
        X = np.asarray(X, dtype=float).reshape(-1, self.dim)
        fell = np.asarray(fell, dtype=bool).reshape(-1)
        self._prior = None
        self._model = self._fit_key = None
        if not (fell.any() and (~fell).any()):
            return
        lab = np.where(fell, 1.0, -1.0)
        with torch_threads(self.threads), _exact_gp(self.max_points):
            h = self._hypers(X, lab, fell)
            self._prior = {"gp": self._condition(X, lab, h), "loo_mu": h["loo_mu"],
                           "loo_var": h["loo_var"], "loo_lab": h["loo_lab"]}

    def fit(self, X: np.ndarray, fell: np.ndarray) -> bool:
        X = np.asarray(X, dtype=float).reshape(-1, self.dim)
        fell = np.asarray(fell, dtype=bool).reshape(-1)
        key = hashlib.sha1(np.ascontiguousarray(X).tobytes() + fell.tobytes()).hexdigest()
        if key == self._fit_key:
            return self.active
        self._model, self._fit_key = None, key
        pr = self._prior
        if not bool(fell.any() and (~fell).any()) and pr is None:
            return False
        lab = np.where(fell, 1.0, -1.0)
        with torch_threads(self.threads), _exact_gp(self.max_points):
            if pr is None:
                m0 = np.zeros(len(lab))
            elif len(lab):
                m0 = self._posterior(pr["gp"], X)[0]
            else:
                c, s = self._calibrate(pr["loo_mu"], pr["loo_var"], pr["loo_lab"])
                self._model = {"gp": None, "c": c, "s": s}
                return True
            h = self._hypers(X, lab - m0, fell)
            gp = self._condition(X, lab - m0, h)
            # calibration data: the fitted points' leave-one-out predictions of the label
            m_loo = self._posterior(pr["gp"], h["loo_X"])[0] if pr is not None else 0.0
            mu, var, lb = h["loo_mu"] + m_loo, h["loo_var"], h["loo_lab"]
            if pr is not None:
                mu = np.concatenate([mu, pr["loo_mu"]])
                var = np.concatenate([var, pr["loo_var"]])
                lb = np.concatenate([lb, pr["loo_lab"]])
            c, s = self._calibrate(mu, var, lb)
        self._model = {"gp": gp, "c": c, "s": s}
        return True

    @property
    def active(self) -> bool:
        return self._model is not None

    def p_fall(self, X: np.ndarray, kappa: float = 0.0) -> np.ndarray:
        from scipy.special import ndtr

        if self._model is None:
            raise RuntimeError("the fall model is not active (fit it on both classes)")
        md = self._model
        Xs = np.asarray(X, dtype=float).reshape(-1, self.dim)
        mu, var = np.zeros(Xs.shape[0]), np.ones(Xs.shape[0])
        with torch_threads(self.threads), _exact_gp(self.max_points):
            if self._prior is not None:
                mu, var = self._posterior(self._prior["gp"], Xs)
            if md["gp"] is not None:
                mr, var = self._posterior(md["gp"], Xs)
                mu = mu + mr
        return ndtr((mu + md["c"] + float(kappa) * np.sqrt(var)) / np.sqrt(md["s"] ** 2 + var))
