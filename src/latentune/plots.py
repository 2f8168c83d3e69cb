"""Figures: CoM velocity and height of rollouts; best-cost-so-far curves. Matplotlib, Agg backend."""
from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_rollouts(results: Mapping[str, object], path: str, v_des: float = 0.5,
                  title: str = "") -> None:
    """CoM forward velocity and base height vs time for recorded rollouts (label -> RolloutResult)."""
    plt = _plt()
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(8, 5.5), sharex=True)
    for label, res in results.items():
        tr = res.trace  # type: ignore[attr-defined]
        if not tr:
            continue
        cost = res.cost  # type: ignore[attr-defined]
        ax1.plot(tr["t"], tr["vel"][:, 0], lw=0.8, label=f"{label} (L = {cost:.2f})")
        ax2.plot(tr["t"], tr["height"], lw=0.8, label=label)
    ax1.axhline(v_des, color="k", ls="--", lw=1, label="v_des")
    ax1.set_ylabel("CoM v_x [m/s]")
    ax2.set_ylabel("base height [m]")
    ax2.set_xlabel("time [s]")
    ax1.legend(fontsize=8, loc="lower right")
    ax1.set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_best_so_far(curves: Mapping[str, Sequence[float]], path: str, title: str = "",
                     manual: float | None = None) -> None:
    """Best cost so far vs evaluation index, one line per label (log y)."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 4))
    for label, y in curves.items():
        y = np.asarray(y, dtype=float)
        if y.size:
            ax.plot(np.arange(1, y.size + 1), np.minimum.accumulate(y), label=label)
    if manual is not None:
        ax.axhline(manual, color="k", ls="--", lw=1, label="manual")
    ax.set_yscale("log")
    ax.set_xlabel("evaluations")
    ax.set_ylabel("best path cost so far")
    ax.set_title(title)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
