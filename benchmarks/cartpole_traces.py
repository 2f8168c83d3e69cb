"""What the cart-pole does under the best θ each method found: the pole's angle and the cart's
position over the 8 s, and the motor force with the controller's mode (physics before costs).

    python -m benchmarks.cartpole_traces [--root results/transfer/rebuilt/runs] [--gap 2]
        [--methods DEFAULT cma_source_trials plain zero_shot] [--seed S] [--default DEFAULT]
        --png F.png [--out F.json]

Reads ``ROOT/cartpole/gap<g>/seed<s>/<method>.json`` (the ladder's traces: ``benchmarks.transfer
run --systems cartpole``), takes each method's best trial that did not fall (the lowest cost
when every trial fell; the zero-shot θ is its only trial), re-runs that θ on the target
(:meth:`examples.cartpole_swingup.CartPoleSystem.simulate`), checks that the cost is the stored
one, and draws one column per method: the pole's angle from upright with the ±0.25 rad the last
second must hold, the cart's position against the track's ±1.2 m, and the motor force with
the balance mode shaded. Without ``--seed`` the seed is the one whose ``--default`` best is the
(lower) median over the seeds stored, so the picture is not a chosen good case. The JSON holds
per method the seed, trial index, cost, whether and when it fell, the time the pole was caught
(the first step in balance mode, s) and the largest cart excursion (m).
"""
from __future__ import annotations

import sys

import numpy as np

from benchmarks.common import Provenance, error_line
from benchmarks.transfer import DEFAULT_METHOD as DEFAULT
from benchmarks.zones_traces import TracesError, method_label, traces_figure, write_figure
from examples.cartpole_swingup import BALANCED, TRACK, make_system



def main(argv: list[str] | None = None) -> int:
    prov = Provenance(argv, "benchmarks.cartpole_traces")
    try:
        a, seed, reruns, fig, axes = traces_figure(
            argv, __doc__, "cartpole", make_system, gap=2.0,
            methods=[DEFAULT, "cma_source_trials", "plain", "zero_shot"], default=DEFAULT,
            nrows=3, height=7.2)
    except TracesError as e:
        error_line("benchmarks.cartpole_traces", e)
        return e.code
    rows = []
    for j, (m, (i, out, tr)) in enumerate(zip(a.methods, reruns)):
        t = tr["time_s"]
        caught = np.flatnonzero(tr["mode"] > 0)
        rows.append({"method": m, "seed": seed, "trial": i, "cost": out.cost,
                     "failed": out.failed, "fall_step": out.info.get("fall_step"),
                     "caught_s": float(t[caught[0]]) if len(caught) else None,
                     "max_abs_x_m": float(np.abs(tr["x"]).max())})
        axes[0, j].plot(t, tr["phi"], lw=1.0, color="k")
        for s in (-1, 1):
            axes[0, j].axhline(s * BALANCED, color="r", lw=0.6, ls=":")
        short = method_label(m, a.default)
        axes[0, j].set_title(f"{short}: cost {out.cost:.3f}" +
                             (f" (fell at {t[-1]:.1f} s)" if out.failed else ""), fontsize=8)
        axes[1, j].plot(t, tr["x"], lw=1.0, color="C0")
        for s in (-1, 1):
            axes[1, j].axhline(s * TRACK, color="r", lw=0.6, ls=":")
        axes[2, j].plot(t, tr["force"], lw=0.8, label="motor force [N]")
        axes[2, j].fill_between(t, -20, 20, where=tr["mode"] > 0, color="C2", alpha=0.15,
                                label="balance mode")
        axes[2, j].set_xlabel("time [s]")
    axes[0, 0].set_ylabel("pole angle from upright [rad]")
    axes[1, 0].set_ylabel("cart position [m] (track dotted)")
    axes[2, 0].set_ylabel("force")
    axes[2, -1].legend(fontsize=7)
    fig.suptitle(f"Cart-pole swing-up, gap {a.gap:g}, seed {seed}: the best θ of each method",
                 fontsize=10)
    write_figure(fig, a.png, a.out, prov, a.gap, seed, rows,
                 f"cartpole gap {a.gap:g}, seed {seed}")
    return 0


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.cartpole_traces"))
