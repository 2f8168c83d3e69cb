"""What the quadrotor does under the best θ each method found: its path against the set-points,
its pitch and its inputs over the 6 s (physics before costs).

    python -m benchmarks.quadrotor_traces [--root results/transfer/rebuilt/runs] [--gap 2.5]
        [--methods DEFAULT turbo_manual zero_shot] [--seed S] [--default DEFAULT]
        --png F.png [--out F.json]

Reads ``ROOT/quadrotor/gap<g>/seed<s>/<method>.json`` (the ladder's traces: ``benchmarks.transfer
run --systems quadrotor``), takes each method's best trial that did not fall (the lowest cost
when every trial fell; the zero-shot θ is its only trial), re-runs that θ on the target
(:meth:`examples.quadrotor_mpc.QuadrotorSystem.simulate`), checks that the cost is the stored
one, and draws one column per method: x and z against their set-points, the pitch against its
±1 rad limit, and the inputs the motors gave (normalized thrust deviation and torque, after
the delay and the vehicle's limits). Without ``--seed``
the seed is the one whose ``--default`` best is the (lower) median over the seeds stored, so the
picture is not a chosen good case. The JSON holds per method the seed, trial index, cost, how it
fell (if it did), its largest pitch (rad) and its RMS position error over the last second (m).
"""
from __future__ import annotations

import sys

import numpy as np

from benchmarks.common import Provenance, error_line
from benchmarks.transfer import DEFAULT_METHOD as DEFAULT
from benchmarks.zones_traces import TracesError, traces_figure, write_figure
from examples.quadrotor_mpc import PITCH_MAX, make_system



def main(argv: list[str] | None = None) -> int:
    prov = Provenance(argv, "benchmarks.quadrotor_traces")
    try:
        a, seed, reruns, fig, axes = traces_figure(
            argv, __doc__, "quadrotor", make_system, gap=2.5, methods=[DEFAULT, "turbo_manual", "zero_shot"],
            default=DEFAULT, nrows=3, height=7.2)
    except TracesError as e:
        error_line("benchmarks.quadrotor_traces", e)
        return e.code
    rows = []
    for j, (m, (i, out, tr)) in enumerate(zip(a.methods, reruns)):
        t = tr["time_s"]
        err = np.hypot(*(tr["position"] - tr["setpoint"]).T)
        last = t > t[-1] - 1.0
        rows.append({"method": m, "seed": seed, "trial": i, "cost": out.cost,
                     "failed": out.failed, "fall": out.info.get("fall"),
                     "max_pitch_rad": float(np.abs(tr["pitch"]).max()),
                     "rms_error_last_1s_m": float(np.sqrt(np.mean(err[last] ** 2)))})
        ax = axes[0, j]
        for k, (name, col) in enumerate((("x", "C0"), ("z", "C1"))):
            ax.plot(t, tr["position"][:, k], color=col, lw=1.2, label=name)
            ax.plot(t, tr["setpoint"][:, k], color=col, lw=0.8, ls="--")
        ax.set_title(f"{m}: cost {out.cost:.3f}" + (f" (fell: {out.info['fall']})"
                                                     if out.failed else ""), fontsize=8)
        axes[1, j].plot(t, tr["pitch"], lw=1.0, color="k")
        for s in (-1, 1):
            axes[1, j].axhline(s * PITCH_MAX, color="r", lw=0.6, ls=":")
        axes[2, j].plot(t, tr["input"][:, 0], lw=0.8, label="thrust δT/(m g)")
        axes[2, j].plot(t, tr["input"][:, 1], lw=0.8, label="torque τ/τ_max")
        axes[2, j].set_xlabel("time [s]")
    axes[0, 0].set_ylabel("position [m] (set-point dashed)")
    axes[1, 0].set_ylabel("pitch [rad] (limit dotted)")
    axes[2, 0].set_ylabel("input the motors gave")
    axes[0, -1].legend(fontsize=7)
    axes[2, -1].legend(fontsize=7)
    fig.suptitle(f"Planar quadrotor MPC, gap {a.gap:g}, seed {seed}: the best θ of each method",
                 fontsize=10)
    write_figure(fig, a.png, a.out, prov, a.gap, seed, rows,
                 f"quadrotor gap {a.gap:g}, seed {seed}")
    return 0


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.quadrotor_traces"))
