"""Phase 3 without the latent space's floor: search the latent space first, then hand over to
the full θ space.

:class:`Handover` is a critic on the full θ box ``[0, 1]^d`` that starts with a *latent critic*
searching the latent box ``[0, 1]^k`` through the decoder (plain phase 3: a fast, mostly stable
start) and, once that search stalls, continues with a *full critic* on θ itself, so the run is
no longer capped by what the decoder can express.

The hand-over rule (stated in :meth:`Handover.rule` and recorded with the run)
-----------------------------------------------------------------------------
The latent points are ordered as they were asked (by tag, i.e. by ask generation); ``b_k`` is the
best cost among the first ``k``. Before an ask, with ``n`` latent points told, the critic hands
over when ``n >= patience`` and ``b_{n−patience} − b_n <= tol·|b_n|``: the last ``patience``
evaluations improved the best by at most the fraction ``tol`` (defaults 20 and 1 %). It never
hands back. The rule is a function of the told latent points, so a resumed critic hands over at
the same point.

The full critic
---------------
Built at the hand-over by ``make_full(length)``, a fresh critic on ``[0, 1]^d`` (TuRBO-m with one
trust region in the pipeline, optionally fall-aware), then told every latent-stage point as
untagged warm data (θ = the decoded point, its cost and fell flag, in a fixed order), so its first
trust region is centred on the best decoded θ and its GP starts with the latent stage's data.
``length`` is ``handover_length`` (default 0.2, in the unit box: a quarter of TuRBO's usual
initial side). The decoder's own local spread is not used to shape the box: decoded points near
the best code differ far less than that side in every θ entry, so a box of that shape would keep
the search on the decoder's surface, which is the floor.

Tags, z and resume
------------------
``tag = 2·(inner tag + 2) + stage`` (stage 0 latent, 1 full; inner tags are ≥ −2), so every tag is
≥ 0 and the stage of a stored point is known. After each ask :attr:`last_z` (n, k) holds the latent
codes (unit box) of latent-stage points and NaN rows for full-space points; the run store keeps
them in its ``z`` column (so the store says which space each evaluation came from) and the
pipeline passes them back to :meth:`tell` (``z=``). A fresh critic told the stored history
(θ, y, tags, fell, z) in one call replays the latent critic on (z, y, tags), rebuilds the full
critic from the latent points if any full-space point is stored, and tells it the full-space
points with their tags: the same state as the original whenever the inner critics' own resume is
exact (see :mod:`latentune.critic.base`).
"""
from __future__ import annotations

import math
from typing import Any, Callable

import numpy as np

from latentune.checks import is_whole
from latentune.critic.base import UNTAGGED, Critic, TwoSpaceCritic

LATENT = 0
FULL = 1

HANDOVER_DEFAULTS = {"patience": 20, "tol": 0.01, "length": 0.2}
"""The hand-over's default options: ``patience`` latent evaluations, relative ``tol``, the full
trust region's initial side ``length`` (:class:`Handover`'s ``handover_length``)."""


def encode_tag(inner: int, stage: int) -> int:
    """The Handover tag of a point with the inner critic's tag ``inner`` (≥ −2) in ``stage``."""
    return 2 * (int(inner) + 2) + int(stage)


def decode_tag(tag: int) -> tuple[int, int]:
    """Inverse of :func:`encode_tag`: ``(inner tag, stage)``."""
    tag = int(tag)
    return tag // 2 - 2, tag % 2


class Handover(TwoSpaceCritic):
    """Latent critic first, full-space critic after the hand-over rule fires (module docstring).

    Args:
        latent: a fresh critic on the latent unit box ``[0, 1]^k`` (its batch size and seed are
            used).
        decode: the decoder ``(n, k) unit latent -> (n, d) normalized θ``.
        dim: d, the length of θ.
        make_full: ``length -> fresh critic on [0, 1]^d`` (e.g. TuRBO-m with that initial side).
        patience: latent evaluations over which the best must improve (default 20).
        tol: relative improvement over ``patience`` evaluations below which the latent search
            counts as stalled (default 0.01).
        handover_length: initial trust-region side of the full critic (default 0.2).
    """

    method = "handover"

    def __init__(self, latent: Critic, decode: Callable[[np.ndarray], np.ndarray], dim: int,
                 make_full: Callable[[float], Critic], *,
                 patience: int = HANDOVER_DEFAULTS["patience"],
                 tol: float = HANDOVER_DEFAULTS["tol"],
                 handover_length: float = HANDOVER_DEFAULTS["length"]) -> None:
        if not isinstance(latent, Critic) or latent.n_told:
            raise ValueError("latent must be a fresh Critic")
        super().__init__(dim, batch_size=latent.batch_size, seed=latent.seed)
        if not is_whole(patience, 1):
            raise ValueError(f"patience must be an integer >= 1, got {patience!r}")
        if not (isinstance(tol, (int, float)) and not isinstance(tol, bool) and tol >= 0):
            raise ValueError(f"tol must be a number >= 0, got {tol!r}")
        if not (isinstance(handover_length, (int, float)) and 0 < handover_length <= 1.6):
            raise ValueError(f"handover_length must be in (0, 1.6], got {handover_length!r}")
        self.latent = latent
        self.decode = decode
        self.make_full = make_full
        self.patience = int(patience)
        self.tol = float(tol)
        self.handover_length = float(handover_length)
        self.full: Critic | None = None
        self.handover_at: int | None = None
        """Latent evaluations told when the search handed over (None: not yet)."""
        self.last_z = np.empty((0, latent.dim))
        self._incoming: tuple[np.ndarray, np.ndarray] | None = None
        self._lat_idx: list[int] = []            # history indices of latent-stage points
        self._ext_idx: list[int] = []            # untagged points told before the hand-over

    @property
    def k(self) -> int:
        """Dimension of the latent box."""
        return self.latent.dim

    @property
    def stage(self) -> int:
        """0 while searching the latent space, 1 after the hand-over."""
        return LATENT if self.full is None else FULL

    def rule(self) -> dict[str, Any]:
        """The hand-over rule and where it fired, for the run's record."""
        return {"rule": f"hand over when the last {self.patience} latent evaluations improved "
                        f"the best cost by at most {self.tol:g} of it",
                "patience": self.patience, "tol": self.tol,
                "handover_length": self.handover_length, "handover_at": self.handover_at}

    # ------------------------------------------------------------------ the rule
    def _latent_order(self) -> np.ndarray:
        """History indices of the latent points in ask order (by tag, then by index)."""
        idx = np.asarray(self._lat_idx, dtype=np.int64)
        if idx.size == 0:
            return idx
        return idx[np.lexsort((idx, self._tags[idx]))]

    def stalled(self) -> bool:
        """True when the rule says the latent search has stalled (see the module docstring)."""
        order = self._latent_order()
        n = order.size
        if n < self.patience:
            return False
        y = self._y[order]
        y = np.where(np.isfinite(y), y, np.inf)
        b = np.minimum.accumulate(y)
        now, before = b[-1], b[n - self.patience - 1] if n > self.patience else np.inf
        if not math.isfinite(now):
            return True
        return before - now <= self.tol * abs(now)

    def _hand_over(self) -> None:
        full = self.make_full(self.handover_length)
        if not isinstance(full, Critic) or full.dim != self.dim or full.n_told:
            raise ValueError("make_full must return a fresh Critic on the full θ box")
        order = self._latent_order()
        self.handover_at = int(order.size)
        self.full = full
        warm = np.concatenate([order, np.asarray(self._ext_idx, dtype=np.int64)])
        if warm.size:
            self._tell_full(warm, np.full(warm.size, UNTAGGED))

    # ------------------------------------------------------------------ ask / tell
    def _ask(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        if self.full is None and self.stalled():
            self._hand_over()
        if self.full is None:
            Z = self.latent.ask(n)
            tags = [encode_tag(t, LATENT) for t in self.latent.last_tags]
            X = np.clip(np.atleast_2d(self.decode(Z)), 0.0, 1.0)
            self.last_z = Z.copy()
            return X, np.asarray(tags, dtype=np.int64)
        X = self.full.ask(n)
        self.last_z = np.full((n, self.k), np.nan)
        return X, np.asarray([encode_tag(t, FULL) for t in self.full.last_tags], dtype=np.int64)

    def _tell(self, idx: np.ndarray, tags: np.ndarray) -> None:
        fa, za = self._incoming_told()
        stage = np.array([decode_tag(t)[1] if t >= 0 else -1 for t in tags])
        lat = np.flatnonzero(stage == LATENT)
        if lat.size:
            Z = za[lat]
            if not np.all(np.isfinite(Z)):
                raise ValueError("latent-stage points need their latent codes (z=)")
            self.latent.tell(Z, self._y[idx[lat]],
                             np.array([decode_tag(t)[0] for t in tags[lat]], dtype=np.int64),
                             fell=fa[lat])
            if self.full is None:
                self._lat_idx.extend(int(i) for i in idx[lat])
            else:       # asked before the hand-over, told after it (ask/tell): warm data
                self._tell_full(idx[lat], np.full(lat.size, UNTAGGED))
        ext = np.flatnonzero(stage == -1)
        if ext.size:
            if self.full is None:
                self._ext_idx.extend(int(i) for i in idx[ext])
            else:
                self._tell_full(idx[ext], np.full(ext.size, UNTAGGED))
        full = np.flatnonzero(stage == FULL)
        if full.size:
            if self.full is None:
                self._hand_over()
            self._tell_full(idx[full], np.array([decode_tag(t)[0] for t in tags[full]],
                                                dtype=np.int64))

    def _tell_full(self, idx: np.ndarray, inner_tags: np.ndarray) -> None:
        self.full.tell(self._X[idx], self._y[idx], inner_tags, fell=self._fell[idx])

    def state_dict(self) -> dict[str, Any]:
        """The inner critics' states (``full`` only after the hand-over)."""
        return {"latent": self.latent.state_dict(),
                "full": None if self.full is None else self.full.state_dict()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        if not state:
            return
        self.latent.load_state_dict(state.get("latent") or {})
        if self.full is not None and state.get("full"):
            self.full.load_state_dict(state["full"])

    def stats(self) -> dict[str, Any]:
        """Counters for logs and run records: the stage and each stage critic's
        :meth:`~latentune.critic.base.Critic.stats` (``full_stats`` is None before the
        hand-over)."""
        return {**super().stats(), "stage": self.stage,
                "latent_stats": self.latent.stats(),
                "full_stats": None if self.full is None else self.full.stats()}

    def __repr__(self) -> str:
        return (f"Handover(dim={self.dim}, k={self.k}, stage={self.stage}, "
                f"handover_at={self.handover_at}, n_told={self.n_told}, best_y={self.best_y:.6g})")
