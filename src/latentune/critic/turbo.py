"""TuRBO-m: Bayesian optimization with m trust regions (Eriksson et al., NeurIPS 2019).

A from-scratch implementation on BoTorch/GPyTorch (the reference code is not used).

Trust regions
-------------
``n_regions`` regions (default 10, the paper's m; callers that know the budget use
:func:`regions_for_budget`), each with its own GP fitted only on the points attributed to it
since its last restart (its *epoch*). Region ``r`` has a side length ``L`` (start 0.8) and a
centre, its best point (a trial that stood beats a failed one, else the lower cost). Its box is
``centre ± L·w/2`` clipped to [0, 1], with ``w = ℓ / geomean(ℓ)`` from the GP's ARD
lengthscales ``ℓ``. After a tell, every region that got Thompson points in that ask (one
*group* per ask generation and region) counts a success if the group's best stands where the
region's best fell, or beats the region's best of its own kind by more than ``1e-3·|best|``,
else one failure per point of the group (a region gets a varying share of each batch, so
failures are counted in evaluations): 3 consecutive successes double ``L`` (max 1.6),
``max(5, d)`` consecutive failed evaluations halve it; when ``L < 0.5**7`` the region restarts:
a fresh scrambled-Sobol design of
``n_init`` points, its old points stay in the global history but leave the region.

Asking
------
1. Regions still in their initial design hand out design points (region 0's first design starts
   with the warm-start points ``x0``).
2. The remaining slots are Thompson samples: every ready region draws ``q`` (= remaining slots)
   pathwise posterior samples (``botorch.sampling.pathwise.draw_matheron_paths``, random Fourier
   prior features) on ``min(100·d, 5000)`` candidates: Sobol points of its box where each
   coordinate replaces the centre's with probability ``min(20/d, 1)`` (at least one per
   candidate). Slot ``k`` takes the global argmin over all regions of sample ``k`` (values mapped
   back to the common warped scale); a taken candidate is not taken twice. Each point is
   attributed to the region it came from.

What the GP sees (the cost transform)
-------------------------------------
Raw costs are stored untouched. For a fit, all told costs are replaced by non-finite → worst
finite, the failed trials are ranked after every trial that stood
(:meth:`~latentune.critic.base.Critic.ranked_costs`), then warped by a global rank-based
Gaussian copula, ``z = Φ⁻¹((rank − ½)/N)`` over the
whole history (ties share their average rank). Monotone, so argmins and the trust-region rules
are unchanged, but immune to the dynamic range of the costs (fall costs in [C1, 2·C1) next to
much smaller stable costs) and to outliers, with the best points spread out in the lower tail.
Each region then standardizes its own ``z``: median-centred, divided by the std (or IQR/1.349
when the std vanishes). Its samples are mapped back through that affine map, so samples of all regions live on
the common ``z`` scale when the global argmin is taken. ``y_transform="log"`` (``log(y − min +
δ)`` with δ = 1e-3·(IQR or 1)) or ``"none"`` are available for comparison.

GP and cost control
-------------------
``SingleTaskGP`` with a constant mean and a ``ScaleKernel(MaternKernel(ν=5/2, ARD))``;
lengthscale ∈ [0.005, 4], outputscale ∈ [0.05, 20], noise ∈ [1e-4, 0.2]; hyperparameters by
L-BFGS-B on the exact marginal likelihood (``botorch.optim.fit.fit_gpytorch_mll_scipy``),
by default without a prior (``lengthscale_prior=None``). With a log-normal lengthscale prior
the fit is the MAP estimate:

* ``lengthscale_prior="dim_tr"``: ``loc = √2 + ½·ln d + ln(L / length_init)``,
  ``scale = √3``, with ``L`` the region's side right after the tell that brought it to the
  checkpoint's number of points (so the fit is a function of the data). At the initial side
  this is BoTorch's dimension-scaled default prior (since BoTorch 0.12); as the region shrinks,
  the prior's lengthscales shrink with it (as in AdaScale-style methods), so the GP of a small
  region is not pulled to the long lengthscales that fit the whole box.
* ``"dim"``: the dimension-scaled prior without the side term.

With a prior, cold fits start at its mode (clipped to [0.02, 4]). ``results/peers/README.md``
compares ``"dim_tr"`` with the default on the problems of ``benchmarks.peers`` and on the
main job.

* A region's GP is conditioned on at most ``max_gp_points`` (default 256) of its points, and its
  hyperparameters are fitted on at most ``max_fit_points`` (default 256): in both cases the best
  half plus the most recent others (``gp_select="recent"``; ``"near"`` = best quarter plus the
  points nearest to the region's best point). Hyperparameter fits use the transform applied to
  the fitted points alone (e.g. their own copula ranks), so they depend only on those points.
* Hyperparameters are refitted only at *checkpoints* of the region's epoch size ``c``:
  ``c_{k+1} = c_k + max(1, ⌈refit_fraction·min(c_k, max_fit_points)⌉)`` (10 %), on the first
  ``c_k`` epoch points (capped as above), i.e. a deterministic function of the data; between
  checkpoints the GP is re-conditioned on the current data with the cached hyperparameters
  (a Cholesky of ≤ 256 points), and a region with no new data reuses them unchanged.
* ``warm_start=True`` (default) starts each refit from the previous hyperparameters (pulled off
  the constraint edges: lengthscales clipped to [0.02, 1], outputscale to [0.1, 10], noise to
  [1e-3, 0.1], so a dimension that looked irrelevant on a few points can come back) with at most
  ``refit_maxiter`` (15) L-BFGS iterations; the first fit of an epoch (or every fit with
  ``warm_start=False``) starts from fixed values with ``fit_maxiter`` (50) iterations.

Design choices
--------------
* About 500 evaluations per region (:func:`regions_for_budget`): with ~100 per region the budget
  goes into initial designs and no region shrinks far enough to polish a basin.
* Hyperparameters fitted on up to 256 points: more fitted points give better ARD lengthscales,
  hence better-shaped boxes; beyond 256 the results are not clearly better and every fit is
  slower.
* On multi-basin functions (e.g. Levy) the best value over seeds has a heavy tail: compare
  medians over several seeds.

``python -m benchmarks.peers`` runs ``minimize``'s defaults against the reference TuRBO, Optuna's
samplers and CMA-ES on ten problems (``--variant NAME='{"option": value}'`` compares other
options).

Diagnostics
-----------
A hyperparameter fit that raises (a numerical failure of the optimizer) keeps the starting
hyperparameters; the first failure is logged (a ``WARNING`` of this module's logger) and every
one is counted in :meth:`TurboM.stats` (``n_fit_failed``, with ``n_fits``).

Threads
-------
The GPs are small (at most ``max_gp_points`` points) and their linear algebra does not gain
from several threads; with torch's default threads and a busy second core an ask is many times
slower. So :meth:`TurboM.ask` runs with ``threads`` (default 1) torch threads and restores the
caller's setting afterwards (``python -m benchmarks.turbo_overhead`` compares both settings).

Tags and resume
---------------
``tag = generation·2**20 + kind·2**16 + region``, ``kind`` 0 = design point, 1 = Thompson point,
``generation`` = the ask counter. :meth:`TurboM.tell` groups points by tag and processes the
groups in generation order, so telling a stored history (X, y, tags) to a fresh critic with the
same options and seed replays the region updates batch by batch: lengths, counters, centres,
bests, epochs and designs are identical. Randomness of ask ``g`` comes only from
``(seed, g)``. With ``warm_start=False`` the hyperparameters are a function of the data too, so
the next ask is exactly the original's. With the default warm start they also depend on the
previous fits: :meth:`TurboM.state_dict` holds them (the pipeline stores it after every batch),
and a resumed critic given :meth:`TurboM.load_state_dict` asks exactly the original's next
batch; without it, it refits from fixed values and may differ in the last digits of the
hyperparameters (same trust-region state, slightly different candidates). A group whose region restarted after it was asked (only
with asynchronous asks) stays in the history but not in the region.

Untagged points (``tags=None``): each goes to the region with the fewest epoch points while some
region has fewer than ``n_init`` points, else to the region with the nearest centre; they update
that region's data and best but not its success/failure counters.

Falls (for trials on a robot)
-----------------------------
Two options keep the search near what is known to work when a trial can fail (``tell(...,
fell=)``); the pipeline sets both with the fall-aware option (``max_fall_prob``):

* ``design_side``: with a warm start ``x0``, region 0's first design (after the ``x0`` rows) is
  a scrambled-Sobol design of the box ``x0[0] ± design_side/2`` (clipped to [0, 1]) instead of
  the whole box (:meth:`TurboM.design_box`). With ``fall_shrink`` set, that lasts as long as at
  most half of its told design points fell: the box is worth searching only while the warm
  start's neighbourhood mostly stands on the target. Once more than half of them fell, its
  remaining design points fill the whole box. Later epochs and other regions keep the whole
  box.
* ``fall_shrink``: a Thompson group in which more than this share of the points fell halves
  its region's side (once, and resets its counters), whatever the success rule says: the share of
  falls estimates the fall probability of the region's trials, and a smaller region stays
  closer to its best, stable point. Only a region that holds a trial that did not fall shrinks
  so (while all of them fell, its centre is a fall too). Falls are known only from ``fell``
  (without it, the non-finite costs). The flags enter the tell like the costs, so a replay of the
  store is exact.

Screened by a fall model (the critic protocol's screening hooks, :mod:`latentune.critic.base`),
TuRBO-m has the ``"drop"`` batch policy; its initial-design points are replace-only (a region
counts design points by their tag, not their position, so its state is the same as if the
design had held the replacement), replaced by scrambled-Sobol points of the region's
:meth:`TurboM.design_box` (:meth:`TurboM.replacement_candidates`), and the GP hyperparameters a
proposal fits are kept (:meth:`TurboM.propose`).
"""
from __future__ import annotations

import contextlib
import functools
import logging
import math
import warnings
from dataclasses import dataclass, field
from typing import Any, Iterator

import numpy as np

from latentune.critic.base import (REPLACE, SCREENED, Critic, FitReport, best_of,
                                   fall_last, fill_nonfinite, gaussian_copula,
                                   refit_checkpoint)

logger = logging.getLogger(__name__)


@contextlib.contextmanager
def gp_warnings_filtered() -> Iterator[None]:
    """Silence the known, handled GP warnings inside the block (and only those):

    * BoTorch's ``InputDataWarning`` that the targets are not standardized (each region's
      targets are median-centred on purpose, see "What the GP sees");
    * linear_operator's ``NumericalWarning`` that jitter was added to a Cholesky factor (the
      jitter is the remedy);
    * BoTorch's ``OptimizationWarning`` that L-BFGS-B stopped with a non-success status (the
      fit keeps the best hyperparameters reached; the status is logged at DEBUG level).
    """
    from botorch.exceptions.warnings import InputDataWarning, OptimizationWarning
    from linear_operator.utils.warnings import NumericalWarning

    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=r"Data \(outcome observations\) is not "
                                "standardized", category=InputDataWarning)
        warnings.filterwarnings("ignore", message=r"A not p\.d\., added jitter",
                                category=NumericalWarning)
        warnings.filterwarnings("ignore", message=r"`scipy_minimize` terminated with status",
                                category=OptimizationWarning)
        yield

_GEN = 1 << 20
_KIND = 1 << 16
KIND_DESIGN = 0
KIND_THOMPSON = 1


def encode_tag(generation: int, kind: int, region: int) -> int:
    """TuRBO-m tag of a point: ask ``generation``, ``kind`` (0 design, 1 Thompson), ``region``."""
    return int(generation) * _GEN + int(kind) * _KIND + int(region)


def regions_for_budget(budget: int) -> int:
    """Trust regions for a known evaluation budget: ``round(budget / 500)`` clipped to [1, 10]
    (about 500 evaluations per region; the paper's 10 from 5,000 on). See "Design choices" in
    the module docstring."""
    return int(min(10, max(1, round(budget / 500))))


def decode_tag(tag: int) -> tuple[int, int, int]:
    """Inverse of :func:`encode_tag`: ``(generation, kind, region)``."""
    tag = int(tag)
    return tag // _GEN, (tag % _GEN) // _KIND, tag % _KIND


def _improves(new: tuple[float, bool], best: tuple[float, bool], rel: float) -> bool:
    """Whether a trial ``new`` = (cost, fell) improves on ``best`` (cost ``inf``: none yet): a
    trial that stood beats a failed one; of the same kind, the cost must be lower than the
    best's by more than ``rel·|best|``."""
    (y, fell), (b, b_fell) = new, best
    if not math.isfinite(b):
        return math.isfinite(y)
    if fell != b_fell:
        return b_fell
    return y < b - rel * abs(b)


def _evaluate_paths(path, x):
    """Evaluate pathwise samples ``path`` (sample shape (q,)) at ``x`` (n, d) -> (q, n).

    Same result as ``path(x)``, but computes ``weight @ features(x).T`` once instead of
    broadcasting the (n, m) features against every sample (BoTorch's batched matvec), which is
    much faster for thousands of candidates. Falls back to ``path(x)`` for other structures.
    """
    from botorch.sampling.pathwise import GeneralizedLinearPath, PathDict

    if getattr(path, "input_transform", None) is not None:
        x = path.input_transform(x)
    if isinstance(path, PathDict) and path.join is not None:
        out = path.join([_evaluate_paths(p, x) for p in path.paths.values()])
    elif (isinstance(path, GeneralizedLinearPath) and not path.is_ensemble
          and path.weight.ndim == 2):
        feat = path.feature_map(x)
        if feat.ndim != 2:
            return path(x)
        out = path.weight @ feat.transpose(-1, -2)
        if path.bias_module is not None:
            out = out + path.bias_module(x)
    else:
        return path(x)
    if getattr(path, "output_transform", None) is not None:
        out = path.output_transform(out)
    return out


@dataclass
class TrustRegion:
    """State of one trust region (all indices point into the critic's global history)."""

    index: int
    length: float
    design: np.ndarray                      # (k, d) initial design of the current epoch
    design_ptr: int = 0                     # design points handed out (or told)
    n_design_told: int = 0
    n_design_fell: int = 0                  # told design points whose trial fell
    n_success: int = 0
    n_failure: int = 0
    epoch: int = 0                          # number of restarts so far
    epoch_gen: int = 0                      # first ask generation of the current epoch
    points: list[int] = field(default_factory=list)
    length_log: list[tuple[int, float]] = field(default_factory=list)   # (n_points, length)
    best_y: float = math.inf                # raw cost of the epoch's best (module docstring)
    best_fell: bool = False                 # whether that trial fell (every trial fell)
    best_index: int = -1                    # its global index (-1: none)
    # GP hyperparameter cache
    hypers: dict[str, np.ndarray] | None = None
    fit_count: int = 0                      # epoch size at the last hyperparameter fit
    n_restarts_seen: int = 0

    @property
    def n_points(self) -> int:
        return len(self.points)


class TurboM(Critic):
    """TuRBO-m trust-region Bayesian optimization (see the module docstring).

    Args:
        dim, batch_size, seed, x0: see :class:`~latentune.critic.base.Critic`.
        n_regions: number of trust regions m (default 10, the paper's m at its 10,000
            evaluations; the critic does not know the budget: callers that do (``minimize``,
            the pipeline's phases) pass :func:`regions_for_budget`).
        n_init: initial (Sobol) design size per region and epoch; default
            ``max(5, min(dim, 10))``.
        length_init, length_min, length_max: side length rules (0.8, 0.5**7, 1.6).
        success_tol: consecutive successful groups to double the side (3).
        failure_tol: consecutive failed evaluations to halve it (default ``max(5, dim)``).
        n_candidates: candidates per region (default ``min(100·dim, 5000)``).
        perturb_prob: per-coordinate perturbation probability (default ``min(20/dim, 1)``).
        max_gp_points: cap on the points one region's GP is conditioned on (256).
        max_fit_points: cap on the points its hyperparameters are fitted on (256).
        num_features: random Fourier features of the pathwise prior samples (512).
        refit_fraction: relative growth of a region's data between hyperparameter refits (0.1).
        warm_start: warm-start refits from the previous hyperparameters (True).
        fit_maxiter, refit_maxiter: L-BFGS-B iteration limits for cold / warm fits (50 / 15).
        y_transform: "copula" (default), "log" or "none" (see the module docstring).
        gp_select: which points a capped GP keeps: "recent" (default) or "near" (see
            :meth:`_select`).
        lengthscale_prior: ``None`` (default), ``"dim_tr"`` or ``"dim"`` (see "GP and cost
            control" in the module docstring).
        threads: torch threads used inside :meth:`ask` (default 1; the previous setting is
            restored afterwards); ``None`` leaves torch's setting alone. See "Threads" in the
            module docstring.
        thompson: ``"paths"`` (default: pathwise samples, random Fourier prior features) or
            ``"exact"`` (joint samples of the GP posterior on the candidates, a Cholesky of
            the candidates' covariance: as the reference TuRBO does up to 2,000 candidates;
            cubic in the number of candidates, for comparisons).
        design_side: side of the box around ``x0`` that region 0's first design fills (in
            (0, 1]; None: the whole box). See "Falls" in the module docstring.
        fall_shrink: halve a region whose Thompson group's share of fallen trials exceeds this
            (in [0, 1]; 1 or None: falls do not shrink regions). See "Falls".
    """

    method = "turbo"

    def __init__(self, dim: int, *, batch_size: int = 1, seed: int = 0,
                 x0: np.ndarray | None = None, n_regions: int = 10, n_init: int | None = None,
                 length_init: float = 0.8, length_min: float = 0.5 ** 7,
                 length_max: float = 1.6, success_tol: int = 3, failure_tol: int | None = None,
                 n_candidates: int | None = None, perturb_prob: float | None = None,
                 max_gp_points: int = 256, max_fit_points: int = 256, num_features: int = 512,
                 refit_fraction: float = 0.1, warm_start: bool = True, fit_maxiter: int = 50,
                 refit_maxiter: int = 15, y_transform: str = "copula",
                 gp_select: str = "recent", lengthscale_prior: str | None = None,
                 threads: int | None = 1, thompson: str = "paths",
                 design_side: float | None = None, fall_shrink: float | None = None) -> None:
        super().__init__(dim, batch_size=batch_size, seed=seed, x0=x0)
        d = self.dim
        if n_regions < 1 or n_regions >= _KIND:
            raise ValueError(f"n_regions must be in [1, {_KIND}), got {n_regions}")
        self.n_regions = int(n_regions)
        self.n_init = int(n_init) if n_init is not None else max(5, min(d, 10))
        if self.n_init < 2:
            raise ValueError(f"n_init must be >= 2, got {n_init}")
        if not 0 < length_min <= length_init <= length_max:
            raise ValueError("need 0 < length_min <= length_init <= length_max")
        self.length_init, self.length_min, self.length_max = (
            float(length_init), float(length_min), float(length_max))
        self.success_tol = int(success_tol)
        self.failure_tol = int(failure_tol) if failure_tol is not None else max(5, d)
        self.n_candidates = int(n_candidates) if n_candidates is not None else min(100 * d, 5000)
        self.perturb_prob = float(perturb_prob) if perturb_prob is not None else min(20.0 / d, 1.0)
        self.max_gp_points = int(max_gp_points)
        self.max_fit_points = min(int(max_fit_points), self.max_gp_points)
        if self.max_fit_points < 4:
            raise ValueError("max_gp_points and max_fit_points must be >= 4")
        self.num_features = int(num_features)
        self.refit_fraction = float(refit_fraction)
        self.warm_start = bool(warm_start)
        self.fit_maxiter, self.refit_maxiter = int(fit_maxiter), int(refit_maxiter)
        if y_transform not in ("copula", "log", "none"):
            raise ValueError(f"y_transform must be 'copula', 'log' or 'none', got {y_transform!r}")
        self.y_transform = y_transform
        if gp_select not in ("near", "recent"):
            raise ValueError(f"gp_select must be 'near' or 'recent', got {gp_select!r}")
        self.gp_select = gp_select
        self.ls_bounds = (0.005, 4.0)
        if lengthscale_prior not in (None, "dim", "dim_tr"):
            raise ValueError("lengthscale_prior must be None, 'dim' or 'dim_tr', "
                             f"got {lengthscale_prior!r}")
        self.lengthscale_prior = lengthscale_prior
        if threads is not None and (isinstance(threads, bool) or int(threads) < 1):
            raise ValueError(f"threads must be None or an integer >= 1, got {threads!r}")
        self.threads = None if threads is None else int(threads)
        if thompson not in ("paths", "exact"):
            raise ValueError(f"thompson must be 'paths' or 'exact', got {thompson!r}")
        self.thompson = thompson
        if design_side is not None and not 0 < design_side <= 1:
            raise ValueError(f"design_side must be in (0, 1], got {design_side!r}")
        self.design_side = None if design_side is None else float(design_side)
        if fall_shrink is not None and not 0 <= fall_shrink <= 1:
            raise ValueError(f"fall_shrink must be in [0, 1], got {fall_shrink!r}")
        self.fall_shrink = None if fall_shrink is None else float(fall_shrink)
        self._gen = 0
        self.regions = [self._fresh_region(r, epoch=0, epoch_gen=0)
                        for r in range(self.n_regions)]
        self._z_cache: tuple[int, np.ndarray] | None = None
        self.fit_report = FitReport("TuRBO-m GP", logger)

    # ------------------------------------------------------------------ regions
    def design_box(self, r: int, epoch: int) -> tuple[np.ndarray, np.ndarray]:
        """(lower (dim,), upper (dim,)) of the box that region ``r``'s design of ``epoch`` fills
        now: ``x0[0] ± design_side/2`` clipped to [0, 1] for region 0's first epoch with a warm
        start and ``design_side`` (with ``fall_shrink``: while at most half of its told design
        points fell); else the unit box."""
        if self.design_side is not None and r == 0 and epoch == 0 and self.x0 is not None:
            tr = self.regions[0] if getattr(self, "regions", None) else None
            widened = (tr is not None and tr.epoch == 0 and self.fall_shrink is not None
                       and tr.n_design_told > 0
                       and tr.n_design_fell > 0.5 * tr.n_design_told)
            if not widened:
                h = self.design_side / 2.0
                return np.clip(self.x0[0] - h, 0.0, 1.0), np.clip(self.x0[0] + h, 0.0, 1.0)
        return np.zeros(self.dim), np.ones(self.dim)

    def _design(self, r: int, epoch: int) -> np.ndarray:
        """The design rows of a fresh region: the warm-start rows (region 0's first epoch), then
        scrambled-Sobol points of the unit cube, mapped into :meth:`design_box` when asked."""
        from torch.quasirandom import SobolEngine
        import torch

        s = int(np.random.default_rng([self.seed, 1, r, epoch]).integers(2 ** 31))
        D = SobolEngine(self.dim, scramble=True, seed=s).draw(self.n_init, dtype=torch.float64)
        D = D.numpy()
        if r == 0 and epoch == 0 and self.x0 is not None:
            D = np.vstack([self.x0, D[: max(self.n_init - self.x0.shape[0], 0)]])
        return D

    def design_point(self, tr: TrustRegion, k: int) -> np.ndarray:
        """Design point ``k`` of region ``tr`` as it is asked now (d,): a warm-start row as it
        is, a Sobol row mapped into the region's current :meth:`design_box`."""
        if tr.index == 0 and tr.epoch == 0 and self.x0 is not None and k < self.x0.shape[0]:
            return tr.design[k].copy()
        lo, hi = self.design_box(tr.index, tr.epoch)
        return lo + tr.design[k] * (hi - lo)

    def _fresh_region(self, r: int, epoch: int, epoch_gen: int) -> TrustRegion:
        return TrustRegion(index=r, length=self.length_init, design=self._design(r, epoch),
                           epoch=epoch, epoch_gen=epoch_gen)

    def _restart(self, tr: TrustRegion, epoch_gen: int) -> None:
        self.regions[tr.index] = self._fresh_region(tr.index, tr.epoch + 1, epoch_gen)

    def _ready(self, tr: TrustRegion) -> bool:
        design_done = tr.design_ptr >= len(tr.design) or tr.n_points >= self.n_init
        return design_done and tr.n_points >= 2

    def _lowest(self, idx: list[int]) -> int:
        """The global index of the best of the points ``idx`` (-1 if no cost is finite): the
        lowest finite cost of a trial that stood, else of a failed one."""
        j = best_of(self._y[idx], self._fell[idx])
        return -1 if j is None else int(idx[j])

    def _add_points(self, tr: TrustRegion, idx: list[int]) -> None:
        """Attribute told points to a region and update its best: a trial that stood beats
        a failed one, else the lower finite raw cost."""
        tr.points.extend(idx)
        tr.length_log.append((tr.n_points, tr.length))
        j = self._lowest(idx)
        if j < 0:
            return
        if _improves((float(self._y[j]), bool(self._fell[j])), (tr.best_y, tr.best_fell), 0.0):
            tr.best_y, tr.best_fell, tr.best_index = float(self._y[j]), bool(self._fell[j]), j

    def _update_region(self, tr: TrustRegion, group_best: tuple[float, bool],
                       group_size: int) -> None:
        """Success/failure bookkeeping for one Thompson group (called before adding it).

        ``group_best`` is the group's best (cost, fell). A group whose best stands where the
        region's best fell, or that improves the region's best of its own kind by more than
        1e-3·|best|, is one success; a group that does not adds ``group_size`` failures
        (failures are counted in evaluations, as regions get a varying share of each batch).
        """
        success = _improves(group_best, (tr.best_y, tr.best_fell), 1e-3)
        if success:
            tr.n_success += 1
            tr.n_failure = 0
        else:
            tr.n_failure += group_size
            tr.n_success = 0
        if tr.n_success >= self.success_tol:
            tr.length = min(2.0 * tr.length, self.length_max)
            tr.n_success = 0
        elif tr.n_failure >= self.failure_tol:
            tr.length /= 2.0
            tr.n_failure = 0

    # ------------------------------------------------------------------ tell
    def _tell(self, idx: np.ndarray, tags: np.ndarray) -> None:
        self._z_cache = None
        tagged = tags >= 0
        untagged = [int(i) for i, t in zip(idx, tags) if t < 0]
        groups: dict[tuple[int, int, int], list[int]] = {}
        for i, t in zip(idx[tagged], tags[tagged]):
            g, kind, r = decode_tag(int(t))
            if r >= self.n_regions or kind not in (KIND_DESIGN, KIND_THOMPSON):
                raise ValueError(f"tag {int(t)} does not belong to this TuRBO-m critic")
            groups.setdefault((g, kind, r), []).append(int(i))
        for (g, kind, r) in sorted(groups, key=lambda k: k[0]):
            self._gen = max(self._gen, g + 1)
            tr = self.regions[r]
            members = groups[(g, kind, r)]
            if g < tr.epoch_gen:
                continue                      # asked before this region restarted: history only
            if kind == KIND_DESIGN:
                tr.n_design_told += len(members)
                tr.n_design_fell += int(self._fell[members].sum())
                tr.design_ptr = max(tr.design_ptr, min(tr.n_design_told, len(tr.design)))
                self._add_points(tr, members)
                continue
            j = self._lowest(members)
            group_best = (math.inf, False) if j < 0 else (float(self._y[j]), bool(self._fell[j]))
            side = tr.length
            self._update_region(tr, group_best, len(members))
            if self._fall_shrink_due(tr, members):
                tr.length = min(tr.length, side / 2.0)     # once, even if the failures halved it
                tr.n_success = tr.n_failure = 0
            self._add_points(tr, members)
            if tr.length < self.length_min:
                self._restart(tr, epoch_gen=g + 1)
        for i in untagged:
            self._add_untagged(i)

    def _fall_shrink_due(self, tr: TrustRegion, members: list[int]) -> bool:
        """``fall_shrink``'s rule for a Thompson group ``members`` of region ``tr``: more than
        that share of the group fell, and the region (with the group) holds a trial that did
        not fall -- while every trial of the region fell, its centre is a fall and shrinking
        would only search closer to it."""
        if self.fall_shrink is None or self._fell[members].mean() <= self.fall_shrink:
            return False
        return bool((~self._fell[tr.points + members]).any())

    def _add_untagged(self, i: int) -> None:
        counts = np.array([tr.n_points for tr in self.regions])
        if counts.min() < self.n_init:
            r = int(np.argmin(counts))
        else:
            centres = np.array([self._X[self._centre_index(tr)] for tr in self.regions])
            r = int(np.argmin(((centres - self._X[i]) ** 2).sum(1)))
        self._add_points(self.regions[r], [i])

    # ------------------------------------------------------------------ ask
    def _ask(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        if self.threads is None:
            return self._ask_impl(n)
        import torch

        before = torch.get_num_threads()
        if before == self.threads:
            return self._ask_impl(n)
        torch.set_num_threads(self.threads)
        try:
            return self._ask_impl(n)
        finally:
            torch.set_num_threads(before)

    def _ask_impl(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        g = self._gen
        self._gen += 1
        X_out: list[np.ndarray] = []
        tags: list[int] = []
        for tr in self.regions:
            while tr.design_ptr < len(tr.design) and tr.n_points < self.n_init and len(X_out) < n:
                X_out.append(self.design_point(tr, tr.design_ptr))
                tags.append(encode_tag(g, KIND_DESIGN, tr.index))
                tr.design_ptr += 1
        q = n - len(X_out)
        if q > 0:
            ready = [tr for tr in self.regions if self._ready(tr)]
            if ready:
                Xt, rt = self._thompson(ready, q, g)
            else:   # nothing to model yet (e.g. two asks without a tell): uniform points
                rng = np.random.default_rng([self.seed, 3, g])
                Xt = rng.random((q, self.dim))
                counts = np.array([tr.n_points + tr.design_ptr for tr in self.regions])
                rt = [int(np.argmin(counts))] * q
            X_out.extend(Xt)
            tags.extend(encode_tag(g, KIND_THOMPSON, r) for r in rt)
        return np.asarray(X_out).reshape(n, self.dim), np.asarray(tags, dtype=np.int64)

    # ------------------------------------------------------------------ GP
    def _warped(self) -> np.ndarray:
        """Transformed costs of the whole history (n,), cached until the next tell."""
        if self._z_cache is not None and self._z_cache[0] == self.n_told:
            return self._z_cache[1]
        z = self._local_targets(self.ranked_costs())
        self._z_cache = (self.n_told, z)
        return z

    def _select(self, pts: list[int], v: np.ndarray, cap: int) -> np.ndarray:
        """At most ``cap`` of the global indices ``pts``, ``v`` (len(pts),) their costs/scores.

        ``gp_select="recent"`` (default): the best half, then the most recent others.
        ``"near"``: the best quarter, then the points nearest (Euclidean, unit box) to the best
        point.
        """
        pts_a = np.asarray(pts, dtype=np.int64)
        if pts_a.size <= cap:
            return pts_a
        order = np.argsort(v, kind="stable")
        if self.gp_select == "near":
            n_best = cap // 4
            keep = np.zeros(pts_a.size, dtype=bool)
            keep[order[:n_best]] = True
            dist = ((self._X[pts_a] - self._X[pts_a[order[0]]]) ** 2).sum(1)
            dist[keep] = np.inf
            keep[np.argsort(dist, kind="stable")[: cap - n_best]] = True
            return np.sort(pts_a[keep])
        n_best = cap // 2
        best = set(pts_a[order[:n_best]].tolist())
        rest = [p for p in pts_a.tolist() if p not in best]
        recent = rest[len(rest) - (cap - n_best):]
        return np.sort(np.asarray(sorted(best) + recent, dtype=np.int64))

    def _local_targets(self, y: np.ndarray) -> np.ndarray:
        """The transform (``y_transform``) of ranked costs ``y`` (n,) (:func:`fall_last`): of
        the whole history, or of a subset only (hyperparameter fits, so that they depend on the
        fitted points alone)."""
        if self.y_transform == "copula":
            return gaussian_copula(y)
        z = fill_nonfinite(y)
        if self.y_transform == "log":
            z = self._log_warp(z)
        return z

    @staticmethod
    def _log_warp(z: np.ndarray) -> np.ndarray:
        q75, q25 = np.percentile(z, [75, 25]) if z.size else (1.0, 0.0)
        delta = 1e-3 * (q75 - q25 if q75 > q25 else 1.0)
        return np.log(z - z.min() + delta)

    @staticmethod
    def _standardize(z: np.ndarray) -> tuple[np.ndarray, float, float]:
        med = float(np.median(z))
        s = float(np.std(z))
        if not s > 1e-9:
            q75, q25 = np.percentile(z, [75, 25])
            s = float(q75 - q25) / 1.349
        if not s > 1e-9:
            s = 1.0
        return (z - med) / s, med, s

    def _ls_prior(self, length: float) -> tuple[float, float] | None:
        """(loc, scale) of the log-normal lengthscale prior for a region of side ``length``."""
        if self.lengthscale_prior is None:
            return None
        loc = math.sqrt(2.0) + 0.5 * math.log(self.dim)
        if self.lengthscale_prior == "dim_tr":
            loc += math.log(length / self.length_init)
        return loc, math.sqrt(3.0)

    def _build_gp(self, Xt: np.ndarray, yt: np.ndarray, hypers: dict[str, np.ndarray] | None,
                  prior_ls: tuple[float, float] | None = None):
        import torch
        from botorch.models import SingleTaskGP
        from gpytorch.constraints import Interval
        from gpytorch.kernels import MaternKernel, ScaleKernel
        from gpytorch.likelihoods import GaussianLikelihood

        X = torch.as_tensor(Xt, dtype=torch.float64)
        Y = torch.as_tensor(yt, dtype=torch.float64).reshape(-1, 1)
        lik = GaussianLikelihood(noise_constraint=Interval(1e-4, 0.2))
        prior = None
        if prior_ls is not None:
            from gpytorch.priors import LogNormalPrior
            prior = LogNormalPrior(*prior_ls)
        kern = ScaleKernel(MaternKernel(nu=2.5, ard_num_dims=self.dim, lengthscale_prior=prior,
                                        lengthscale_constraint=Interval(*self.ls_bounds)),
                           outputscale_constraint=Interval(0.05, 20.0))
        with gp_warnings_filtered():
            model = SingleTaskGP(X, Y, likelihood=lik, covar_module=kern, outcome_transform=None)
        model.to(torch.float64)
        ls0 = 0.5
        if prior_ls is not None and hypers is None:   # start at the prior's mode
            ls0 = float(np.clip(math.exp(prior_ls[0] - prior_ls[1] ** 2), 0.02, self.ls_bounds[1]))
        h = hypers or {"lengthscale": np.full(self.dim, ls0), "outputscale": np.array(1.0),
                       "noise": np.array(1e-3), "constant": np.array(0.0)}
        model.covar_module.base_kernel.lengthscale = torch.as_tensor(
            h["lengthscale"], dtype=torch.float64).reshape(1, self.dim)
        model.covar_module.outputscale = torch.as_tensor(h["outputscale"], dtype=torch.float64)
        model.likelihood.noise = torch.as_tensor(h["noise"], dtype=torch.float64).reshape(1)
        model.mean_module.constant = torch.as_tensor(float(np.asarray(h["constant"]).reshape(-1)[0]),
                                                     dtype=torch.float64)
        return model

    @staticmethod
    def _hypers_of(model) -> dict[str, np.ndarray]:
        return {
            "lengthscale": model.covar_module.base_kernel.lengthscale.detach().numpy().reshape(-1).copy(),
            "outputscale": model.covar_module.outputscale.detach().numpy().copy(),
            "noise": model.likelihood.noise.detach().numpy().reshape(-1)[:1].copy(),
            "constant": model.mean_module.constant.detach().numpy().reshape(-1)[:1].copy(),
        }

    def _fit(self, model, maxiter: int) -> bool:
        """Fit ``model``'s hyperparameters by L-BFGS-B (at most ``maxiter`` iterations) on its
        exact marginal likelihood. Returns ``False`` when the fit raised (the model keeps its
        starting hyperparameters); every fit is counted in :attr:`fit_report`."""
        from botorch.optim.fit import fit_gpytorch_mll_scipy
        from gpytorch.mlls import ExactMarginalLogLikelihood

        model.train()
        mll = ExactMarginalLogLikelihood(model.likelihood, model)
        try:
            with gp_warnings_filtered():
                result = fit_gpytorch_mll_scipy(mll, options={"maxiter": maxiter})
        except (RuntimeError, ValueError, ArithmeticError) as exc:
            # torch's linear algebra errors (NotPSDError, LinAlgError) are RuntimeErrors
            self.fit_report.record(False, f"{type(exc).__name__}: {exc}")
            return False
        finally:
            model.eval()
        logger.debug("GP fit: %s after %d iterations", result.status.name, result.step)
        self.fit_report.record(True)
        return True

    def _checkpoint(self, n: int) -> int:
        """Largest refit checkpoint <= n (:func:`~latentune.critic.base.refit_checkpoint`)."""
        return refit_checkpoint(n, self.refit_fraction, self.max_fit_points)

    def _region_model(self, tr: TrustRegion, z: np.ndarray):
        """Fitted GP of a region on its standardized warped costs, with (median, scale)."""
        c = self._checkpoint(tr.n_points)
        if tr.hypers is None or tr.fit_count != c:
            prefix = tr.points[:c]
            v = np.full(self.n_told, np.nan)
            v[prefix] = fall_last(fill_nonfinite(self._y[prefix]), self._fell[prefix])
            fit_pts = self._select(prefix, v[prefix], self.max_fit_points)
            zs, _, _ = self._standardize(self._local_targets(v[fit_pts]))
            warm = self.warm_start and tr.hypers is not None
            start = None
            if warm:   # pull the start off the constraint edges, where L-BFGS-B would stick
                h = tr.hypers
                start = {"lengthscale": np.clip(h["lengthscale"], 0.02, 1.0),
                         "outputscale": np.clip(h["outputscale"], 0.1, 10.0),
                         "noise": np.clip(h["noise"], 1e-3, 0.1), "constant": h["constant"]}
            model = self._build_gp(self._X[fit_pts], zs, start,
                                   self._ls_prior(self._length_at(tr, c)))
            self._fit(model, self.refit_maxiter if warm else self.fit_maxiter)
            tr.hypers = self._hypers_of(model)
            tr.fit_count = c
        pts = self._select(tr.points, z[tr.points], self.max_gp_points)
        zs, med, s = self._standardize(z[pts])
        model = self._build_gp(self._X[pts], zs, tr.hypers)
        model.eval()
        return model, med, s

    @staticmethod
    def _length_at(tr: TrustRegion, c: int) -> float:
        """The region's side right after the tell that brought its epoch to ``c`` points (a
        function of the told data, whatever the timing of the asks)."""
        for n, length in tr.length_log:
            if n >= c:
                return length
        return tr.length

    def _candidates(self, tr: TrustRegion, lengthscale: np.ndarray,
                    rng: np.random.Generator) -> np.ndarray:
        """(n_candidates, d) perturbed Sobol candidates in the region's box."""
        import torch
        from torch.quasirandom import SobolEngine

        centre = self._X[self._centre_index(tr)]
        lb, ub = self.region_box(tr, lengthscale)
        s = int(rng.integers(2 ** 31))
        sob = SobolEngine(self.dim, scramble=True, seed=s).draw(
            self.n_candidates, dtype=torch.float64).numpy()
        pert = lb + (ub - lb) * sob
        mask = rng.random((self.n_candidates, self.dim)) <= self.perturb_prob
        none = ~mask.any(axis=1)
        if none.any():
            mask[np.flatnonzero(none), rng.integers(0, self.dim, size=int(none.sum()))] = True
        cand = np.where(mask, pert, centre[None, :])
        return cand

    @staticmethod
    def _centre_index(tr: TrustRegion) -> int:
        """Global index of a region's centre: its best point (its last point if no cost is
        finite yet, -1 if it has no points)."""
        if tr.best_index >= 0:
            return tr.best_index
        return tr.points[-1] if tr.points else -1

    def region_box(self, tr: TrustRegion, lengthscale: np.ndarray | None = None
                   ) -> tuple[np.ndarray, np.ndarray]:
        """Box ``(lb, ub)`` (each (d,)) of a region: centre ± length·w/2 clipped to [0, 1].

        ``w = ℓ / geomean(ℓ)`` from ``lengthscale`` (default: the region's cached GP
        lengthscales, or all ones before its first fit).
        """
        if lengthscale is None:
            lengthscale = (tr.hypers["lengthscale"] if tr.hypers is not None
                           else np.ones(self.dim))
        ls = np.asarray(lengthscale, dtype=float).reshape(self.dim)
        w = ls / np.exp(np.mean(np.log(ls)))
        i = self._centre_index(tr)
        centre = self._X[i] if i >= 0 else np.full(self.dim, 0.5)
        lb = np.clip(centre - tr.length * w / 2.0, 0.0, 1.0)
        ub = np.clip(centre + tr.length * w / 2.0, 0.0, 1.0)
        return lb, ub

    def _thompson(self, ready: list[TrustRegion], q: int, g: int
                  ) -> tuple[np.ndarray, list[int]]:
        """Fill ``q`` slots by the global argmin of pathwise Thompson samples of all regions."""
        import torch
        from botorch.sampling.pathwise import draw_kernel_feature_paths, draw_matheron_paths

        z = self._warped()
        cands: list[np.ndarray] = []
        samples: list[np.ndarray] = []
        prior = functools.partial(draw_kernel_feature_paths, num_features=self.num_features)
        for tr in ready:
            rng = np.random.default_rng([self.seed, 4, g, tr.index])
            model, med, s = self._region_model(tr, z)
            ls = tr.hypers["lengthscale"]
            cand = self._candidates(tr, ls, rng)
            with torch.random.fork_rng(devices=[]):
                torch.manual_seed(int(rng.integers(2 ** 62)))
                with torch.no_grad(), gp_warnings_filtered():
                    ct = torch.as_tensor(cand, dtype=torch.float64)
                    if self.thompson == "exact":
                        f = model.posterior(ct).rsample(torch.Size([q])).squeeze(-1).numpy()
                    else:
                        paths = draw_matheron_paths(model, sample_shape=torch.Size([q]),
                                                    prior_sampler=prior)
                        f = _evaluate_paths(paths, ct).numpy()
            f = med + s * f.reshape(q, -1)
            f[~np.isfinite(f)] = np.inf
            cands.append(cand)
            samples.append(f)
        X_out: list[np.ndarray] = []
        regions: list[int] = []
        for k in range(q):
            best_val, best_r, best_j = np.inf, -1, -1
            for i, f in enumerate(samples):
                j = int(np.argmin(f[k]))
                if f[k, j] < best_val or best_r < 0:
                    best_val, best_r, best_j = f[k, j], i, j
            X_out.append(cands[best_r][best_j].copy())
            regions.append(ready[best_r].index)
            samples[best_r][:, best_j] = np.inf
        return np.asarray(X_out), regions

    # ------------------------------------------------------------------ state
    def state_dict(self) -> dict[str, Any]:
        """Each region's fitted GP hyperparameters with the epoch and refit checkpoint they
        belong to (floats as JSON numbers, which round-trip float64 exactly), and ``n_told``."""
        return {"method": self.method, "n_told": self.n_told,
                "regions": [{"index": tr.index, "epoch": tr.epoch, "fit_count": tr.fit_count,
                             "hypers": {k: np.asarray(v, dtype=float).tolist()
                                        for k, v in tr.hypers.items()}}
                            for tr in self.regions if tr.hypers is not None]}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore the hyperparameters of :meth:`state_dict` (regions of another epoch, e.g.
        restarted since, or another index are skipped; they refit as usual)."""
        if not state or state.get("method") != self.method:
            return
        self._proposer = None
        for r in state.get("regions", []):
            i = int(r.get("index", -1))
            if not 0 <= i < self.n_regions or self.regions[i].epoch != int(r.get("epoch", -1)):
                continue
            tr = self.regions[i]
            tr.hypers = {k: np.asarray(v, dtype=float) for k, v in r["hypers"].items()}
            tr.fit_count = int(r["fit_count"])

    # ------------------------------------------------------------------ screening hooks
    def propose(self, m: int) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`Critic.propose <latentune.critic.base.Critic.propose>`; the GP
        hyperparameters the proposal fitted are kept, so refits follow the region's own
        checkpoints whether or not its asks are screened."""
        X, T = super().propose(m)
        for ri, rp in zip(self.regions, self._proposer.regions):
            if ri.index == rp.index and ri.epoch == rp.epoch and rp.hypers is not None:
                ri.hypers = {k: np.array(v, copy=True) for k, v in rp.hypers.items()}
                ri.fit_count = rp.fit_count
        return X, T

    def screen_roles(self, X: np.ndarray, tags: np.ndarray) -> np.ndarray:
        """Initial-design points are :data:`~latentune.critic.base.REPLACE`: a region needs its
        whole design told before it models anything, and counts design points by their tag,
        not their position (warm-start points stay exempt)."""
        roles = super().screen_roles(X, tags)
        design = np.array([t >= 0 and decode_tag(int(t))[1] == KIND_DESIGN for t in tags],
                          dtype=bool)
        roles[(roles == SCREENED) & design] = REPLACE
        return roles

    def replacement_candidates(self, tag: int, rank: int, m: int) -> np.ndarray:
        """``m`` scrambled-Sobol points (m, dim) of the design box (:meth:`design_box`) of the
        region of design tag ``tag``, seeded by the critic's seed, ``tag`` and ``rank``."""
        import torch
        from torch.quasirandom import SobolEngine

        r = decode_tag(tag)[2]
        lo, hi = self.design_box(r, self.regions[r].epoch)
        s = int(np.random.default_rng([self.seed, 7, int(tag), int(rank)]).integers(2 ** 31))
        Z = SobolEngine(self.dim, scramble=True, seed=s).draw(int(m), dtype=torch.float64).numpy()
        return lo + Z * (hi - lo)

    # ------------------------------------------------------------------ inspection
    def stats(self) -> dict[str, Any]:
        """Counters for logs and run records: ``method``, ``n_told``, ``n_fits`` (hyperparameter
        fits made) and ``n_fit_failed`` (fits that raised, see "Diagnostics")."""
        return {**super().stats(), **self.fit_report.as_dict()}

    def region_state(self) -> list[dict[str, Any]]:
        """Plain summary of every region (for tests, logs and resume checks)."""
        return [{"index": tr.index, "length": tr.length, "n_success": tr.n_success,
                 "n_failure": tr.n_failure, "epoch": tr.epoch, "epoch_gen": tr.epoch_gen,
                 "n_points": tr.n_points, "best_y": tr.best_y, "best_index": tr.best_index,
                 "design_ptr": tr.design_ptr} for tr in self.regions]
