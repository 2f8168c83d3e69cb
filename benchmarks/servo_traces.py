"""What the servo drive does under the best θ each method found: the load's angle against its
reference, the tracking error against the 0.3 rad limit, and the torque command against the
drive's limit, over the 1.5 s (physics before costs).

    python -m benchmarks.servo_traces [--root results/transfer/servo/runs] [--gap 0.5]
        [--methods transfer cma_source_trials gp zero_shot] [--seed S] [--default transfer]
        --png F.png [--out F.json]

Reads ``ROOT/servo/gap<g>/seed<s>/<method>.json`` (``benchmarks.transfer run --systems
servo``), takes each method's best trial that did not fail (the lowest cost when every trial
failed; the zero-shot θ is its only trial), re-runs that θ on the target
(:meth:`examples.servo_cascade.ServoSystem.simulate`), checks that the cost is the stored one,
and draws one column per method. Without ``--seed`` the seed is the one whose ``--default``
best is the (lower) median over the seeds stored, so the picture is not a chosen good case.
The JSON holds per method the seed, trial index, cost, whether and when it failed, the
largest tracking error (rad) and the RMS torque command (N·m).
"""
from __future__ import annotations

import sys

import numpy as np

from benchmarks.common import Provenance, error_line
from benchmarks.zones_traces import TracesError, method_label, traces_figure, write_figure
from examples.servo_cascade import ERR_LIMIT, make_system


def main(argv: list[str] | None = None) -> int:
    prov = Provenance(argv, "benchmarks.servo_traces")
    try:
        a, seed, reruns, fig, axes = traces_figure(
            argv, __doc__, "servo", make_system, gap=0.5,
            methods=["transfer", "cma_source_trials", "gp", "zero_shot"],
            default="transfer", nrows=3, height=7.2)
    except TracesError as e:
        error_line("benchmarks.servo_traces", e)
        return e.code
    tau_max = make_system(gap=a.gap).tau_max
    rows = []
    for j, (m, (i, out, tr)) in enumerate(zip(a.methods, reruns)):
        t, err = tr["time_s"], tr["load"] - tr["ref"]
        rows.append({"method": m, "seed": seed, "trial": i, "cost": out.cost,
                     "failed": out.failed, "fall_step": out.info.get("fall_step"),
                     "max_abs_err_rad": float(np.abs(err).max()),
                     "rms_torque_Nm": float(np.sqrt(np.mean(tr["torque"] ** 2)))})
        axes[0, j].plot(t, tr["ref"], lw=0.8, ls="--", color="0.5", label="reference")
        axes[0, j].plot(t, tr["load"], lw=1.0, color="k", label="load")
        axes[0, j].set_title(f"{method_label(m, a.default)}: cost {out.cost:.2f}"
                             + (f" (failed at {t[-1]:.2f} s)" if out.failed else ""), fontsize=8)
        axes[1, j].plot(t, err, lw=1.0, color="C0")
        for s in (-1, 1):
            axes[1, j].axhline(s * ERR_LIMIT, color="r", lw=0.6, ls=":")
            axes[2, j].axhline(s * tau_max, color="r", lw=0.6, ls=":")
        axes[2, j].plot(t, tr["torque"], lw=0.7, color="C1")
        axes[2, j].set_xlabel("time [s]")
    axes[0, 0].set_ylabel("load angle [rad]")
    axes[0, -1].legend(fontsize=7)
    axes[1, 0].set_ylabel("tracking error [rad]")
    axes[2, 0].set_ylabel("torque command [N·m]")
    fig.suptitle(f"Servo drive, gap {a.gap:g}, seed {seed}: the best θ of each method (limits dotted)",
                 fontsize=10)
    write_figure(fig, a.png, a.out, prov, a.gap, seed, rows, f"servo gap {a.gap:g}, seed {seed}")
    return 0


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.servo_traces"))
