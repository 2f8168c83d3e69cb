"""Where the transfer phase 3 loses on the ladder: its trust region, agreement, pools and falls
over the 40 trials, and where the winning peer's best θ lies.

    python -m benchmarks.transfer_diagnose [--sources runs/transfer] [--runs runs/transfer_diag]
        [--ladder results/transfer/ladder.json] [--targets arm:1.5 chain:1.5 chain:2 hopper:1.5]
        [--seeds 0 1 2] [--method transfer] [--options OPTION=VALUE[:OPTION=VALUE]]
        [--out results/transfer/selection/diagnosis.json]

The stored ladder traces keep cost and fall flag per trial but not θ, so the transfer and the
target's best peer (from ``--ladder``) are run again with :func:`benchmarks.transfer.run_method`
(every run is deterministic: ``reproduces`` checks the best cost against the ladder's) on the
sources under ``--sources``; the traces, with θ, go to ``--runs`` (resumed when there).
Per (target, seed) the JSON keeps:

* the transfer's trust-region side (log2) after 10, 20, 30 and 40 trials and the first trial at
  the minimum side; the agreement ``a`` (median after the design); the pools picked; its falls in
  trials 1–5 and after; the design asks whose predicted fall probability exceeded
  ``max_fall_prob`` (the screen kept them because no elite passed it);
* distances in the unit θ box (RMS over coordinates, ``‖Δ‖ / √d``, and the largest
  coordinate step) between the source's best θ (the zero-shot trial), the transfer's best and
  the peer's best (the lowest cost, as ``summary`` counts it), the trial at which each found
  its best, and the share of each one's coordinates at the box's faces (within 0.01).

``screen_calibration``: over every stored trace under ``--stored``, the asks the fall screen
admitted and those asked over it (when no candidate passed), with how many fell.
"""
from __future__ import annotations

import json
import math
import sys
from pathlib import Path
from typing import Any

from latentune.threads import one_thread_env

one_thread_env()

import numpy as np  # noqa: E402

from benchmarks.common import error_line  # noqa: E402


def _dist(a: np.ndarray, b: np.ndarray) -> dict[str, float]:
    d = np.asarray(a, float) - np.asarray(b, float)
    return {"rms": float(np.linalg.norm(d) / math.sqrt(d.size)), "max": float(np.abs(d).max())}


def _at_bounds(x: np.ndarray, tol: float = 0.01) -> float:
    """Share of the coordinates of θ (d,) within ``tol`` of the unit box's faces."""
    x = np.asarray(x, float)
    return float(np.mean((x < tol) | (x > 1 - tol)))


def _trace(runs: Path, sources: Path, system: str, gap: float, seed: int, method: str,
           options: dict[str, Any] | None, name: str) -> dict[str, Any]:
    """The run with θ (loaded from ``runs`` or made there)."""
    from benchmarks import transfer as tr

    f = runs / system / f"gap{gap:g}" / f"seed{seed}" / f"{name}.json"
    if f.is_file():
        return json.loads(f.read_text())
    src = sources / system / f"seed{seed}" / "source"
    if not (src / "vae.json").is_file():
        raise FileNotFoundError(f"no source run at {src}")
    res = tr.run_method(method, tr.SYSTEMS[system]["target"](gap), src, 40, seed, options)
    res.update(system=system, gap=gap, seed=seed, method=name, budget=40)
    f.parent.mkdir(parents=True, exist_ok=True)
    f.write_text(json.dumps(res))
    return res


def diagnose_seed(t: dict[str, Any], p: dict[str, Any], length_min: float,
                  max_fall_prob: float) -> dict[str, Any]:
    """The per-seed record (module docstring) of transfer trace ``t`` and peer trace ``p``."""
    D = t["decisions"]
    L = [d.get("length") for d in D]          # decision i asks trial i + 2
    def side(trial: int) -> float | None:
        v = L[min(trial, len(L)) - 2] if trial >= 2 else None
        return None if v is None else float(np.log2(v))
    at_min = [i + 2 for i, v in enumerate(L) if v is not None and v <= length_min * (1 + 1e-9)]
    agree = [d["agreement"] for d in D if d.get("agreement") is not None and not d.get("design")]
    pools: dict[str, int] = {}
    for d in D:
        for q in d["pools"]:
            pools[q] = pools.get(q, 0) + 1
    f = np.asarray(t["failed"], bool)
    forced = [i + 2 for i, d in enumerate(D) if d.get("design")
              and d.get("max_fall_prob_asked", 0.0) > max_fall_prob]
    Xt, Xp = np.asarray(t["thetas"]), np.asarray(p["thetas"])
    it, ip = int(np.argmin(t["costs"])), int(np.argmin(p["costs"]))
    src = Xt[0]
    return {
        "transfer_best": float(min(t["costs"])), "peer_best": float(min(p["costs"])),
        "transfer_best_trial": it + 1, "peer_best_trial": ip + 1,
        "log2_side_at": {str(k): side(k) for k in (10, 20, 30, 40)},
        "first_trial_at_min_side": at_min[0] if at_min else None,
        "agreement_median": float(np.median(agree)) if agree else None,
        "pools": pools, "falls_1_5": int(f[:5].sum()), "falls_after_5": int(f[5:].sum()),
        "peer_falls": int(np.sum(p["failed"])),
        "design_asks_over_fall_screen": forced,
        "dist_source_to_peer_best": _dist(src, Xp[ip]),
        "dist_source_to_transfer_best": _dist(src, Xt[it]),
        "dist_transfer_best_to_peer_best": _dist(Xt[it], Xp[ip]),
        "peer_first_theta_is_source_best": bool(np.allclose(Xp[0], src)),
        "at_bounds": {"source": _at_bounds(src), "transfer_best": _at_bounds(Xt[it]),
                      "peer_best": _at_bounds(Xp[ip])},
    }


def screen_calibration(stored: Path, method: str, max_fall_prob: float) -> dict[str, Any]:
    """Per system, over every stored ``method`` trace under ``stored``: how many asks the fall
    screen admitted (predicted fall probability ≤ ``max_fall_prob``) and how many were asked
    over it (no candidate passed), and the share of each that fell."""
    out: dict[str, Any] = {}
    for f in sorted(stored.glob(f"*/gap*/seed*/{method}.json")):
        r = json.loads(f.read_text())
        o = out.setdefault(r["system"], {"admitted": [0, 0], "over_screen": [0, 0]})
        for i, d in enumerate(r.get("decisions", [])):
            p = d.get("max_fall_prob_asked")
            if p is None:
                continue
            k = "admitted" if p <= max_fall_prob else "over_screen"
            o[k][0] += 1
            o[k][1] += int(bool(r["failed"][i + 1]))      # decision i asks trial i + 2
    return {s: {k: {"asks": v[0], "fell": v[1], "fall_rate": v[1] / v[0] if v[0] else None}
                for k, v in o.items()} for s, o in out.items()}


def _med(rows: list[dict[str, Any]], key: str, sub: str | None = None) -> float:
    v = [r[key][sub] if sub else r[key] for r in rows]
    v = [x for x in v if x is not None]
    return float(np.median(v)) if v else math.nan


def markdown(out: dict[str, Any]) -> str:
    lines = ["| target | peer | best transfer / peer | falls 1–5 / after (transfer), peer "
             "| forced design asks | agreement | log2 side @10/20/30/40 | first trial at min side "
             "| source→peer best (rms / max) | source→transfer best | transfer→peer best "
             "| best found at trial (transfer / peer) | at the box's faces (source / transfer "
             "/ peer best) |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for row in out["targets"]:
        S = row["seeds"]
        r = list(S.values())
        sides = "/".join(f"{_med(r, 'log2_side_at', str(k)):.1f}" for k in (10, 20, 30, 40))
        forced = float(np.median([len(x["design_asks_over_fall_screen"]) for x in r]))
        d = {k: f"{_med(r, k, 'rms'):.3f} / {_med(r, k, 'max'):.2f}" for k in
             ("dist_source_to_peer_best", "dist_source_to_transfer_best",
              "dist_transfer_best_to_peer_best")}
        lines.append(
            f"| {row['system']} {row['gap']:g} | {row['peer']} | {_med(r, 'transfer_best'):.4g} / "
            f"{_med(r, 'peer_best'):.4g} | {_med(r, 'falls_1_5'):g} / {_med(r, 'falls_after_5'):g}"
            f", {_med(r, 'peer_falls'):g} | {forced:g} | {_med(r, 'agreement_median'):.2f} | "
            f"{sides} | {_med(r, 'first_trial_at_min_side'):g} | "
            f"{d['dist_source_to_peer_best']} | {d['dist_source_to_transfer_best']} | "
            f"{d['dist_transfer_best_to_peer_best']} | {_med(r, 'transfer_best_trial'):g} / "
            f"{_med(r, 'peer_best_trial'):g} | "
            + " / ".join(f"{_med(r, 'at_bounds', k):.2f}"
                         for k in ("source", "transfer_best", "peer_best")) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    from benchmarks.common import Provenance, bench_parser, out_file
    from benchmarks.transfer import parse_variant
    from latentune.critic.transfer import TRANSFER_DEFAULTS

    argv = sys.argv[1:] if argv is None else argv
    ap = bench_parser("benchmarks.transfer_diagnose", description=__doc__.splitlines()[0])
    ap.add_argument("--sources", default="runs/transfer")
    ap.add_argument("--runs", default="runs/transfer_diag")
    ap.add_argument("--ladder", default="results/transfer/ladder.json")
    ap.add_argument("--targets", nargs="+", default=["arm:1.5", "chain:1.5", "chain:2",
                                                      "hopper:1.5"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    ap.add_argument("--options", default="", help="transfer options option=value[:option=value]")
    ap.add_argument("--stored", default="results/transfer/runs",
                    help="stored ladder traces for the fall screen's calibration")
    ap.add_argument("--out", type=out_file, default="results/transfer/selection/diagnosis.json")
    a = ap.parse_args(argv)
    prov = Provenance(argv, module="benchmarks.transfer_diagnose")
    ladder = json.loads(Path(a.ladder).read_text())
    opts = parse_variant(a.options)
    name = "transfer" + (f"+{a.options}" if a.options else "")
    o = {**TRANSFER_DEFAULTS, **opts}
    out: dict[str, Any] = {"options": o, "targets": []}
    for spec in a.targets:
        system, _, g = spec.partition(":")
        try:
            gap = float(g)
            lrow = next(r for r in ladder["targets"] if r["system"] == system
                        and abs(r["gap"] - gap) < 1e-9)
        except (ValueError, StopIteration):
            error_line("benchmarks.transfer_diagnose", f"no ladder target {spec!r} in {a.ladder}")
            return 2
        peer = lrow["best_peer"]
        row: dict[str, Any] = {"system": system, "gap": gap, "peer": peer, "seeds": {}}
        for s in a.seeds:
            t = _trace(Path(a.runs), Path(a.sources), system, gap, s, "transfer", opts, name)
            p = _trace(Path(a.runs), Path(a.sources), system, gap, s, peer, None, peer)
            rec = diagnose_seed(t, p, float(o["length_min"]), float(o["max_fall_prob"]))
            if s in lrow["seeds"] and not opts:
                k = lrow["seeds"].index(s)
                rec["reproduces"] = (
                    rec["transfer_best"] == lrow["methods"]["transfer"]["best"][k]
                    and rec["peer_best"] == lrow["methods"][peer]["best"][k])
            row["seeds"][str(s)] = rec
            print(f"{system} {gap:g} seed {s}: transfer {rec['transfer_best']:.4g}, "
                  f"{peer} {rec['peer_best']:.4g}", flush=True)
        out["targets"].append(row)
    out["screen_calibration"] = screen_calibration(Path(a.stored), name, float(o["max_fall_prob"]))
    out["provenance"] = prov.finish()
    f = Path(a.out)
    f.parent.mkdir(parents=True, exist_ok=True)
    f.write_text(json.dumps(out, indent=1))
    md = markdown(out) + "\n\nThe fall screen on every stored run (" + a.stored + "):\n\n" + \
        "| system | admitted asks (fell) | asks over the screen (fell) |\n|---|---:|---:|\n" + \
        "\n".join(f"| {s} | {c['admitted']['asks']} ({c['admitted']['fell']}) | "
                  f"{c['over_screen']['asks']} ({c['over_screen']['fell']}) |"
                  for s, c in out["screen_calibration"].items())
    f.with_suffix(".md").write_text(f"`{out['provenance']['command']}`\n\nMedians over seeds "
                                    f"{a.seeds}.\n\n{md}\n")
    print(md)
    return 0


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.transfer_diagnose"))
