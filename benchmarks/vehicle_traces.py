"""What the car does under the best θ each method found: its lateral and heading errors along
the road, and its steering, over the 20 s (physics before costs).

    python -m benchmarks.vehicle_traces [--root results/transfer/rebuilt/runs] [--gap 2]
        [--methods DEFAULT cma_source_trials plain zero_shot] [--seed S] [--default DEFAULT]
        --png F.png [--out F.json]

Reads ``ROOT/vehicle/gap<g>/seed<s>/<method>.json`` (the ladder's traces: ``benchmarks.transfer
run --systems vehicle``), takes each method's best trial that did not fall (the lowest cost
when every trial fell; the zero-shot θ is its only trial), re-runs that θ on the target
(:meth:`examples.vehicle_lateral.VehicleSystem.simulate`), checks that the cost is the stored
one, and draws one column per method: the lateral error against the lane's ±1.5 m, the
heading error, and the steering angle with the road's curvature (scaled). Without ``--seed``
the seed is the one whose ``--default`` best is the (lower) median over the seeds stored, so
the picture is not a chosen good case. The JSON holds per method the seed, trial index, cost,
whether and when it left the lane, its largest lateral error (m) and its RMS steering (rad).
"""
from __future__ import annotations

import sys

import numpy as np

from benchmarks.common import Provenance, error_line
from benchmarks.transfer import DEFAULT_METHOD as DEFAULT
from benchmarks.zones_traces import TracesError, method_label, traces_figure, write_figure
from examples.vehicle_lateral import LANE, make_system



def main(argv: list[str] | None = None) -> int:
    prov = Provenance(argv, "benchmarks.vehicle_traces")
    try:
        a, seed, reruns, fig, axes = traces_figure(
            argv, __doc__, "vehicle", make_system, gap=2.0, methods=[DEFAULT, "cma_source_trials", "plain", "zero_shot"],
            default=DEFAULT, nrows=3, height=7.2)
    except TracesError as e:
        error_line("benchmarks.vehicle_traces", e)
        return e.code
    rows = []
    for j, (m, (i, out, tr)) in enumerate(zip(a.methods, reruns)):
        t = tr["time_s"]
        rows.append({"method": m, "seed": seed, "trial": i, "cost": out.cost,
                     "failed": out.failed, "fall_step": out.info.get("fall_step"),
                     "max_abs_e_y_m": float(np.abs(tr["e_y"]).max()),
                     "rms_delta_rad": float(np.sqrt(np.mean(tr["delta"] ** 2)))})
        axes[0, j].plot(t, tr["e_y"], lw=1.0, color="k")
        for s in (-1, 1):
            axes[0, j].axhline(s * LANE, color="r", lw=0.6, ls=":")
        short = method_label(m, a.default)
        axes[0, j].set_title(f"{short}: cost {out.cost:.3f}" +
                             (f" (left at {t[-1]:.1f} s)" if out.failed else ""), fontsize=8)
        axes[1, j].plot(t, tr["e_psi"], lw=1.0, color="C0")
        axes[2, j].plot(t, tr["delta"], lw=0.9, label="steering δ [rad]")
        axes[2, j].plot(t, 10.0 * tr["curvature"], lw=0.8, ls="--",
                        label="10 · curvature [1/m]")
        axes[2, j].set_xlabel("time [s] (speed 12 → 28 m/s)")
    axes[0, 0].set_ylabel("lateral error [m] (lane dotted)")
    axes[1, 0].set_ylabel("heading error [rad]")
    axes[2, 0].set_ylabel("steering")
    axes[2, -1].legend(fontsize=7)
    fig.suptitle(f"Lane keeping, gap {a.gap:g}, seed {seed}: the best θ of each method",
                 fontsize=10)
    write_figure(fig, a.png, a.out, prov, a.gap, seed, rows, f"vehicle gap {a.gap:g}, seed {seed}")
    return 0


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.vehicle_traces"))
