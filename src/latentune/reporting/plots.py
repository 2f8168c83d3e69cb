"""Figures of the run and paper reports (matplotlib, Agg backend, PNG files).

* :func:`plot_rollouts`: CoM forward velocity and base height against time of recorded rollouts.
* :func:`plot_best_so_far`: per panel (one per phase or budget, each with its own evaluation
  axis, numbered from 0 as the run store's ``idx``, status, best and tell number them) the cost of every evaluation on a log axis with falls marked ×, and below it the best
  cost so far on a linear axis zoomed to the tuned costs.
* :func:`plot_cost_transform`: the path cost against the Gaussian-copula score the GP models.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from latentune.constants import C1
from latentune.reporting.metrics import best_so_far, fell_mask

_DISPLAY_MAX = 1e6
"""Costs above this (a non-finite cost is stored as 1e300) are drawn at this value."""


def _num(v: float) -> str:
    """A cost for a legend: 3 decimals (``12.346``) below 1e6 in magnitude, else 4 significant
    digits (``1.235e+290``): a cost near 1e290 written with 3 decimals is a 294-character label
    that leaves tight_layout no room for the axes."""
    return f"{v:.3f}" if abs(v) < 1e6 else f"{v:.4g}"


def pyplot():
    """matplotlib.pyplot on the non-interactive Agg backend."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_rollouts(results: Mapping[str, object], path: str | Path, v_des: float | None = 0.5,
                  title: str = "") -> None:
    """CoM forward velocity [m/s] and base height [m] against time [s] of recorded rollouts.

    ``results``: label → a rollout result with ``cost`` and ``trace`` (``t`` (n,) [s], ``vel``
    (n, 3) [m/s], ``height`` (n,) [m]), e.g. :class:`~latentune.task.RolloutResult` from
    ``rollout(theta, record=True)``; results without a trace are skipped. The legend gives each
    path cost L and, when the result has one, its RMS velocity error. ``v_des``: the desired
    forward velocity drawn dashed (None: not drawn).
    """
    plt = pyplot()
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(8, 5.5), sharex=True)
    for label, res in results.items():
        tr = getattr(res, "trace", None)
        if not tr:
            continue
        text = f"{label} (L = {float(res.cost):.2f}"  # type: ignore[attr-defined]
        rms = getattr(res, "rms_vel_error", None)
        text += f", RMS {rms:.3f} m/s)" if rms is not None else ")"
        ax1.plot(tr["t"], tr["vel"][:, 0], lw=0.8, label=text)
        ax2.plot(tr["t"], tr["height"], lw=0.8, label=label)
    if v_des is not None:
        ax1.axhline(v_des, color="k", ls="--", lw=1, label="v_des")
    ax1.set_ylabel("CoM v_x [m/s]")
    ax2.set_ylabel("base height [m]")
    ax2.set_xlabel("time [s]")
    ax1.legend(fontsize=8, loc="lower right")
    ax1.set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


@dataclass
class CurvePanel:
    """One column of :func:`plot_best_so_far`: curves that share an evaluation axis.

    Attributes:
        title: the column's title.
        curves: label → (n,) costs in evaluation order (n may differ between curves).
        refs: label → a reference cost drawn as a horizontal line (e.g. the manual θ's cost).
        fell: label → (n,) fall flags of that curve; default: cost ≥ C1.
    """

    title: str
    curves: dict[str, Sequence[float]]
    refs: dict[str, float | None] = field(default_factory=dict)
    fell: dict[str, Sequence[bool]] = field(default_factory=dict)


def _log_axis(ax, values: Sequence[float] | np.ndarray | None = None) -> str:
    """Log y axis with plain tick labels at 1, 2, 5 × 10^k, unless a finite one of ``values``
    (what the axis shows) is ≤ 0 (a log axis would drop it) or none is finite (every trial
    failed: matplotlib cannot log-scale an axis with no positive value): then the axis stays
    linear. Returns the scale, ``"log"`` or ``"linear"``."""
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    v = np.asarray([] if values is None else values, dtype=float).reshape(-1)
    v = v[np.isfinite(v)]
    if v.size == 0 or (v <= 0).any():
        return "linear"
    ax.set_yscale("log")
    ax.yaxis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
    ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    ax.yaxis.set_minor_formatter(NullFormatter())
    return "log"


def _zoom(bests: list[np.ndarray], stable: list[np.ndarray], refs: list[float]) -> tuple | None:
    """(low, high) of the linear best-so-far axis: from the lowest final best to the highest
    reference below C1, or, without one, to the highest best-so-far at a curve's first stable
    evaluation. None when no curve has a stable evaluation."""
    starts = [b[np.flatnonzero(s)[0]] for b, s in zip(bests, stable) if s.any()]
    if not starts:
        return None
    lo = min(float(b[-1]) for b in bests)
    hi = max(refs) if refs else max(float(v) for v in starts)
    span = hi - lo if hi > lo else max(abs(lo) * 0.05, 1e-3)
    return lo - 0.08 * span, max(hi, lo) + 0.2 * span


def plot_best_so_far(panels: Sequence[CurvePanel] | CurvePanel, path: str | Path,
                     title: str = "") -> None:
    """The best-cost figure: one column per :class:`CurvePanel`.

    Top row: the cost of every evaluation (log axis, linear where a cost is ≤ 0; stable ·,
    fell ×, C1 dotted where a cost reaches it) against the evaluation number 0..n-1 of that
    panel (the run store's ``idx``, as ``status``, ``best`` and ``tell`` number evaluations; the
    legend's "best C at k" names evaluation k so). Bottom row: the best cost so far of the trials that did not fail (none before the
    first one that stood) on a linear axis zoomed from the best cost found to the panel's
    highest reference (falls at 100–200 and early costs above the zoom leave it through the
    top; where no trial stood, the references alone on a log axis, or a panel without one
    says so; the axis label names the scale). Empty curves are
    skipped; a figure with no curve raises ``ValueError``.
    """
    if isinstance(panels, CurvePanel):
        panels = [panels]
    panels = [p for p in panels if any(len(v) for v in p.curves.values())]
    if not panels:
        raise ValueError("plot_best_so_far: no costs to plot")
    plt = pyplot()
    labels = list(dict.fromkeys(k for p in panels for k, v in p.curves.items() if len(v)))
    color = {k: f"C{i % 10}" for i, k in enumerate(labels)}
    ncol = len(panels)
    nleg = max(len(p.curves) + len(p.refs) for p in panels)
    fig, axes = plt.subplots(2, ncol, figsize=(max(7.0, 5.8 * ncol), 7.0 + 0.17 * nleg),
                             squeeze=False,
                             sharex="col", gridspec_kw={"height_ratios": [1.0, 1.5]})
    first_bot = ""                              # the first column's best-so-far scale
    for j, p in enumerate(panels):
        top, bot = axes[0, j], axes[1, j]
        bests, stables, shown, nmax = [], [], [], 1     # nmax: the longest curve's length
        for label, costs in p.curves.items():
            raw = np.asarray(costs, dtype=float).reshape(-1)
            y = np.minimum(raw, _DISPLAY_MAX)
            if y.size == 0:
                continue
            shown.append(y)
            x = np.arange(y.size)               # the store's idx: 0 .. n-1
            nmax = max(nmax, y.size)
            f = fell_mask(y, p.fell.get(label), fall_cost=C1)
            c = color[label]
            top.scatter(x[~f], y[~f], s=6, color=c, alpha=0.7, linewidths=0)
            top.scatter(x[f], y[f], s=14, color=c, marker="x", linewidths=0.8)
            b = best_so_far(y, fell=f)          # a failed trial is never the best
            if f.all():
                lab = f"{label}: no trial stood, {int(f.sum())} fell"
            else:
                bests.append(b)
                stables.append(~f)
                k = int(np.argmin(b))
                lab = f"{label}: best {_num(raw[k])} at {k}, {int(f.sum())} fell"
            bot.plot(x, np.where(np.isfinite(b), b, np.nan), color=c, lw=1.4,
                     drawstyle="steps-post", label=lab)
        refs = {k: float(v) for k, v in p.refs.items() if v is not None}
        for (label, v), ls in zip(refs.items(), ("--", "-.", ":", (0, (5, 1)))):
            bot.axhline(v, color="k", ls=ls, lw=1, label=f"{label} ({_num(v)})")
        if any((y >= C1).any() for y in shown):     # costs on the path-cost scale reach it
            top.axhline(C1, color="0.4", ls=":", lw=1)
            top.text(0.99, C1, f"C1 = {C1:g} (fall)", transform=top.get_yaxis_transform(),
                     fontsize=7, va="bottom", ha="right", color="0.3")
        scale = _log_axis(top, np.concatenate(shown + [np.array(list(refs.values()))]))
        top.set_title(p.title, fontsize=10)
        lim = _zoom(bests, stables, [v for v in refs.values() if v < C1])
        bot_scale = "linear, zoomed"
        if lim is None:
            bot_scale = _log_axis(bot, list(refs.values()))
            if not refs:     # nothing to draw: no trial stood and no reference cost
                bot.text(0.5, 0.5, "no trial stood: no best cost so far", transform=bot.transAxes,
                         ha="center", va="center", fontsize=9, color="0.3")
        else:
            bot.set_ylim(*lim)
        bot.set_xlim(-0.5, nmax - 0.5)
        bot.set_xlabel(f"evaluation (0–{nmax - 1})")
        bot.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.13), ncol=2,
                   frameon=False)
        bot.grid(alpha=0.3)
        top.grid(alpha=0.3)
        if j == 0 or scale == "linear":
            top.set_ylabel(f"cost of each evaluation\n(· stable, × fell; {scale})")
        if j == 0 or bot_scale != first_bot:        # a column's own scale is named
            bot.set_ylabel(f"best cost so far ({bot_scale})")
        first_bot = bot_scale if j == 0 else first_bot
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_cost_transform(costs: Sequence[float] | np.ndarray, path: str | Path, title: str) -> None:
    """Path cost (log axis) against its rank-based Gaussian-copula score (what TuRBO-m's GP
    models) for (n,) costs; falls (cost ≥ C1) in red."""
    from latentune.critic import gaussian_copula

    plt = pyplot()
    y = np.asarray(costs, dtype=float).reshape(-1)
    z = gaussian_copula(y)
    fig, ax = plt.subplots(figsize=(6, 4))
    st = y < C1
    ax.scatter(y[st], z[st], s=8, label="stable")
    ax.scatter(y[~st], z[~st], s=8, c="tab:red", label=f"fell (L ≥ {C1:g})")
    ax.set_xscale("log")
    ax.set_xlabel("path cost L (original)")
    ax.set_ylabel("copula score (what the GP models)")
    ax.set_title(title)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
