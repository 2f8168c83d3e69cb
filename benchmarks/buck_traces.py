"""What the buck converter does under the manual θ and the best θ each method found: the output
voltage against the specification and the over-voltage protection, and the inductor current
(its average and its peak with the switching ripple) against the 12 A trip and the load, over
the 10 ms (physics before costs).

    python -m benchmarks.buck_traces [--root results/transfer/buck/runs] [--gap 0.5]
        [--methods zero_shot transfer transfer+...] [--seed S] [--default METHOD]
        --png F.png [--out F.json]

Reads ``ROOT/buck/gap<g>/seed<s>/<method>.json`` (``benchmarks.transfer run --systems buck``),
takes each method's best trial that did not fail (the lowest cost when every trial failed; the
zero-shot θ is its only trial), re-runs that θ on the target
(:meth:`examples.buck_converter.BuckSystem.simulate`), checks that the cost is the stored one,
and draws one column per method after a first column for the manual θ on the same target.
Without ``--seed`` the seed is the one whose ``--default`` best is the (lower) median over the
seeds stored (default: today's default phase 3, :data:`benchmarks.transfer.DEFAULT_METHOD`), so
the picture is not a chosen good case. The JSON holds per column the seed, trial index, cost,
whether, when and why it failed, the largest output voltage (V), the deepest dip below the
specification after the soft start (V) and the largest peak inductor current (A).
"""
from __future__ import annotations

import sys
from pathlib import Path

from benchmarks.common import Provenance, error_line
from benchmarks.transfer import DEFAULT_METHOD
from benchmarks.zones_traces import TracesError, method_label, traces_figure, write_figure
from examples.buck_converter import I_TRIP, OVP_GAIN, OVP_OFFSET, make_system


def main(argv: list[str] | None = None) -> int:
    prov = Provenance(argv, "benchmarks.buck_traces")
    try:
        a, seed, reruns, fig, axes = traces_figure(
            argv, __doc__, "buck", make_system, gap=0.5, methods=["zero_shot", DEFAULT_METHOD],
            default=DEFAULT_METHOD, nrows=2, height=6.0, root=Path("results/transfer/buck/runs"),
            manual=True, width=4.0)
    except TracesError as e:
        error_line("benchmarks.buck_traces", e)
        return e.code
    cols = list(zip(["manual", *a.methods], reruns))
    rows = []
    for j, (m, (i, out, tr)) in enumerate(cols):
        t = tr["time_s"] * 1e3
        after = tr["time_s"] > 1e-3
        rows.append({"method": m, "seed": seed, "trial": i, "cost": out.cost,
                     "failed": out.failed, "fall_step": out.info.get("fall_step"),
                     "reason": out.info.get("reason"),
                     "max_vout_v": float(tr["vout"].max()),
                     "max_dip_v": float((tr["spec"] - tr["vout"])[after].max())
                     if after.any() else None,
                     "max_il_peak_a": float(tr["il_peak"].max())})
        ax = axes[0, j]
        ax.plot(t, tr["spec"], lw=0.8, ls="--", color="0.5", label="specification")
        ax.plot(t, OVP_GAIN * tr["setpoint"] + OVP_OFFSET, lw=0.6, ls=":", color="r",
                label="over-voltage limit")
        ax.plot(t, tr["vout"], lw=0.9, color="k", label="output")
        ax.set_title(f"{method_label(m, a.default)}: cost {out.cost:.2f}"
                     + (f" (fell at {t[-1]:.2f} ms: {out.info.get('reason')})"
                        if out.failed else ""), fontsize=8)
        ax = axes[1, j]
        ax.plot(t, tr["il_peak"], lw=0.5, color="C1", alpha=0.7, label="peak current")
        ax.plot(t, tr["il"], lw=0.8, color="C0", label="inductor current")
        ax.plot(t, tr["iload"], lw=0.8, color="C2", label="load current")
        ax.axhline(I_TRIP, color="r", lw=0.6, ls=":")
        ax.set_xlabel("time [ms]")
    axes[0, 0].set_ylabel("output voltage [V]")
    axes[1, 0].set_ylabel("current [A]")
    axes[0, -1].legend(fontsize=7)
    axes[1, -1].legend(fontsize=7)
    fig.suptitle(f"Buck converter, gap {a.gap:g}, seed {seed}: the manual θ and the best θ of "
                 f"each method (limits dotted)", fontsize=10)
    write_figure(fig, a.png, a.out, prov, a.gap, seed, rows, f"buck gap {a.gap:g}, seed {seed}")
    return 0


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.buck_traces"))
