"""What the thermal zones do under the best θ each method found: room temperatures, set-points
and heater power over the 4 hours (physics before costs).

    python -m benchmarks.zones_traces [--root results/transfer/rebuilt/runs] [--gap 2]
        [--methods transfer turbo_manual zero_shot] [--seed S] --png F.png [--out F.json]

Reads ``ROOT/zones/gap<g>/seed<s>/<method>.json`` (the ladder's traces: ``benchmarks.transfer
run --systems zones``), takes each method's best trial that did not fail (its lowest cost; the
zero-shot θ is its only trial), re-runs that θ on the target
(:meth:`examples.thermal_zones.ZonesSystem.simulate`), checks that the cost is the stored one,
and draws one column per method: the five rooms' temperatures against their set-points and the
comfort band (±3 K, counted after the first hour), and the heaters' power. Without ``--seed``
the seed is the one whose ``transfer`` best is the median over the seeds stored (the lower
median), so the picture is not a chosen good case. The JSON holds per method the seed, trial
index, cost and its largest band excursion after the first hour (K) and RMS power (kW).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.common import Provenance, add_out_arg, bench_parser, error_line, finish
from benchmarks.common import out_file  # noqa: E402
from examples.thermal_zones import BAND, SETTLE, make_system


def stored_run(root: Path, gap: float, seed: int, method: str, system: str = "zones"
               ) -> dict[str, Any]:
    """The ladder's trace ``ROOT/<system>/gap<g>/seed<s>/<method>.json``."""
    return json.loads((root / system / f"gap{gap:g}" / f"seed{seed}" /
                       f"{method}.json").read_text())


def best_trial(run: dict[str, Any]) -> int:
    """The index of a run's best trial that did not fail (its lowest cost; the lowest cost when
    every trial failed)."""
    c = np.asarray(run["costs"], float)
    ok = ~np.asarray(run["failed"], bool)
    return int(np.argmin(np.where(ok, c, np.inf))) if ok.any() else int(np.argmin(c))


class TracesError(Exception):
    """A stored run that is missing (``code`` 2) or re-runs to another cost (``code`` 1)."""

    def __init__(self, code: int, message: str) -> None:
        super().__init__(message)
        self.code = code


def rerun_best(system: Any, root: Path, gap: float, seed: int, method: str, name: str
               ) -> tuple[int, Any, dict[str, np.ndarray]]:
    """Re-run the best trial (:func:`best_trial`) of the stored run of ``method`` on the
    ladder system ``name`` (:func:`stored_run`) on ``system`` (its ``simulate``): ``(index,
    outcome, trace)``. :class:`TracesError` when the run is missing or its cost differs from
    the stored one (the traces and the system no longer agree)."""
    try:
        run = stored_run(root, gap, seed, method, name)
    except FileNotFoundError as e:
        raise TracesError(2, f"no stored run: {e.filename}") from None
    i = best_trial(run)
    out, tr = system.simulate(np.asarray(run["thetas"][i], float))
    if not np.isclose(out.cost, run["costs"][i], rtol=1e-9):
        raise TracesError(1, f"{method} trial {i} re-runs to {out.cost}, stored "
                             f"{run['costs'][i]}")
    return i, out, tr


def write_figure(fig: Any, png: Path, out: Any, prov: Provenance, gap: float, seed: int,
                 rows: list[dict[str, Any]], title: str) -> None:
    """Lay out and save ``fig`` to ``png`` and write the rows (:func:`benchmarks.common.finish`)."""
    fig.tight_layout()
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, dpi=110)
    finish(out, prov, {"gap": gap, "seed": seed, "png": str(png)}, rows, title=title)


def median_seed(root: Path, gap: float, method: str = "transfer", system: str = "zones") -> int:
    """The seed whose ``method`` best is the (lower) median over the seeds stored;
    :class:`TracesError` (code 2) when no seed has a run of ``method`` there."""
    seeds = sorted(int(p.name[4:]) for p in (root / system / f"gap{gap:g}").glob("seed*")
                   if (p / f"{method}.json").is_file())
    if not seeds:
        raise TracesError(2, f"no {method} run under {root}/{system}/gap{gap:g}")
    best = [min(stored_run(root, gap, s, method, system)["costs"]) for s in seeds]
    order = np.argsort(best, kind="stable")
    return seeds[int(order[(len(seeds) - 1) // 2])]


def method_label(method: str, default: str | None) -> str:
    """A method's panel title: ``default`` for the default phase 3's long variant name, else the
    method's own name."""
    return "default" if method == default else method


def traces_figure(argv: list[str] | None, doc: str, name: str, make_system: Any, *, gap: float,
                  methods: list[str], default: str | None, nrows: int, height: float,
                  root: Path = Path("results/transfer/rebuilt/runs"), manual: bool = False,
                  width: float = 4.2
                  ) -> tuple[argparse.Namespace, int, list[tuple[int, Any, dict]], Any, Any]:
    """The common part of the ladder systems' trace figures: parse ``argv`` (``--root``, default
    ``root``, ``--gap``, ``--methods``, ``--default`` when ``default`` is given, ``--seed``,
    ``--png``, ``--out``), choose the seed (:func:`median_seed` of the default method), re-run
    each method's best trial on ``make_system(gap)`` (:func:`rerun_best`) and open a figure of
    ``nrows`` rows and one column (``width`` inches) per method: ``(args, seed, reruns, fig,
    axes)``. With ``manual`` the first column and rerun are the target's manual θ (trial index
    None). :class:`TracesError` as :func:`rerun_best` and :func:`median_seed` raise it, and
    (code 2) for a gap ``make_system`` refuses."""
    ap = bench_parser(f"benchmarks.{name}_traces", description=doc.splitlines()[0])
    ap.add_argument("--root", type=Path, default=root)
    ap.add_argument("--gap", type=float, default=gap)
    ap.add_argument("--methods", nargs="+", default=methods)
    if default is not None:
        ap.add_argument("--default", default=default,
                        help="the method whose median seed is drawn when --seed is not given")
    ap.add_argument("--seed", type=int, default=None)
    ap.add_argument("--png", type=out_file, required=True)
    add_out_arg(ap)
    a = ap.parse_args(argv)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    seed = median_seed(a.root, a.gap, getattr(a, "default", "transfer"), name) \
        if a.seed is None else a.seed
    try:
        system = make_system(a.gap)
    except ValueError as e:
        raise TracesError(2, f"--gap: {e}") from None
    reruns = [(None, *system.simulate(system.space.manual))] if manual else []
    reruns += [rerun_best(system, a.root, a.gap, seed, m, name) for m in a.methods]
    fig, axes = plt.subplots(nrows, len(reruns), figsize=(width * len(reruns), height),
                             sharex=True, sharey="row", squeeze=False)
    return a, seed, reruns, fig, axes


def main(argv: list[str] | None = None) -> int:
    prov = Provenance(argv, "benchmarks.zones_traces")
    try:
        a, seed, reruns, fig, axes = traces_figure(
            argv, __doc__, "zones", make_system, gap=2.0,
            methods=["transfer", "turbo_manual", "zero_shot"], default=None, nrows=2,
            height=5.6)
    except TracesError as e:
        error_line("benchmarks.zones_traces", e)
        return e.code
    rows = []
    for j, (m, (i, out, tr)) in enumerate(zip(a.methods, reruns)):
        h = tr["time_s"] / 3600.0
        late = tr["time_s"] > SETTLE
        dev = np.abs(tr["temperature"] - tr["setpoint"])
        rows.append({"method": m, "seed": seed, "trial": i, "cost": out.cost,
                     "failed": out.failed,
                     "max_excursion_after_1h_K": float(dev[late].max()) if late.any() else None,
                     "rms_power_kw": float(np.sqrt(np.mean(tr["power_kw"] ** 2)))})
        ax = axes[0, j]
        for r in range(tr["temperature"].shape[1]):
            line, = ax.plot(h, tr["temperature"][:, r], lw=1.2, label=f"room {r + 1}")
            ax.plot(h, tr["setpoint"][:, r], lw=0.8, ls="--", color=line.get_color())
        ax.axvline(SETTLE / 3600.0, color="0.6", lw=0.8)
        ax.set_title(f"{m}: cost {out.cost:.3f}" + (" (failed)" if out.failed else ""),
                     fontsize=9)
        axes[1, j].plot(h, tr["power_kw"], lw=1.0)
        axes[1, j].set_xlabel("time [h]")
    axes[0, 0].set_ylabel(f"temperature [°C] (set-point dashed, band ±{BAND:g} K after 1 h)",
                          fontsize=8)
    axes[1, 0].set_ylabel("heater power [kW]")
    axes[0, -1].legend(fontsize=7)
    fig.suptitle(f"Thermal zones, gap {a.gap:g}, seed {seed}: the best θ of each method",
                 fontsize=10)
    write_figure(fig, a.png, a.out, prov, a.gap, seed, rows, f"zones gap {a.gap:g}, seed {seed}")
    return 0


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.zones_traces"))
