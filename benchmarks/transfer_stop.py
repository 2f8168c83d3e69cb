"""Can a stopping rule the run sets from its own trials meet criterion (3) and keep (1)?
Two families judged on the stored runs, chosen on the ladder, tested on what the choice did
not see (the bar: ``results/transfer/early_budget/bar.md``).

    python -m benchmarks.transfer_stop \
        --runs results/transfer/rebuilt/runs \
        --heldout-runs results/transfer/rebuilt/heldout_gaps/runs \
        --fresh-runs results/transfer/rebuilt/fresh_gaps/runs \
        --robot-summary results/robot_transfer/ladder10220/summary_allowance.json \
        --robot-traces results/robot_transfer/ladder10220/traces \
        --out results/transfer/early_budget/stop.json

A rule stops a run after some trial; the run then holds its best standing θ for the rest of
its budget B (:func:`benchmarks.transfer.cut_at`). The critic asks nothing different before
the stop, so the default's stored run cut there is the run the rule would have made (as
``fall_budget`` = q, session 43, whose cut runs equalled actual runs trial for trial).

- **early** (a, b, counts): after n_e = ⌈B/4⌉ trials the fall budget is
  k = max(1, ⌈a·E⌉ + b), E = the falls among those n_e trials; the run stops once the falls
  ``counts`` counts (every fall, or those after the first standing trial) reach k and a trial
  stands (:func:`early_end`).
- **stall** (m, w): a fall is unpaid when the best standing cost has not improved since the
  count last restarted (it restarts at each improvement); the run stops at the m-th unpaid
  fall in a row of no improvement, once ⌈w·B⌉ trials ran (:func:`stall_end`).

Sets: the ladder (arm, chain, hopper, springs, zones in ``--runs``) chooses; the held-out
systems (quadrotor, car, cart-pole in ``--runs``), the held-out gaps (``--heldout-runs``) and
the robots (``--robot-summary``: the peers' best costs and falls per seed; the default's
runs from ``--robot-traces``) test; ``--fresh-runs`` (the default's runs only, no peers) give
the paired cost alone. Per set: criteria (1), (3) and both, per target as ``benchmarks.transfer
summary`` states them; the falls; the paired cost (geometric mean over runs of the cut run's
best over the uncut run's). Bad input is one line on stderr and exit 2."""
from __future__ import annotations

import itertools
import json
import math
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks import transfer as tr
from benchmarks.common import error_line
from benchmarks.transfer_walk import load_trace, runs_by_seed
from latentune.critic.transfer import FALL_BUDGET_COUNTS, counted_falls

LADDER = ("arm", "chain", "hopper", "springs", "zones")
HELDOUT = ("quadrotor", "vehicle", "cartpole")
EARLY_GRID = {"a": (1.0, 1.5, 2.0, 3.0), "b": (0, 1, 2), "counts": FALL_BUDGET_COUNTS}
STALL_GRID = {"m": (1, 2, 3, 4, 6), "w": (0.0, 0.25, 0.5)}

Ends = Callable[[list[float], list[bool]], int]
"""A stopping rule: (costs, failed) of a run of B trials → the trials it keeps (B: no stop)."""


def early_end(costs: list[float], failed: list[bool], a: float, b: int,
              counts: str = "all") -> int:
    """Trials kept under the early rule (a, b, counts): see the module's docstring."""
    B = len(failed)
    n_e = math.ceil(B / 4)
    f = np.asarray(failed, dtype=bool)
    k = max(1, math.ceil(a * int(f[:n_e].sum()) - 1e-9) + int(b))
    for i in range(n_e, B + 1):
        if not f[:i].all() and counted_falls(f[:i], counts) >= k:
            return i
    return B


def stall_end(costs: list[float], failed: list[bool], m: int, w: float) -> int:
    """Trials kept under the stall rule (m, w): see the module's docstring."""
    B = len(failed)
    best, unpaid = math.inf, 0
    for i, (c, fell) in enumerate(zip(costs, failed)):
        if fell:
            unpaid += best < math.inf
        elif c < best:
            best, unpaid = c, 0
        if i + 1 >= math.ceil(w * B) and best < math.inf and unpaid >= m:
            return i + 1
    return B


Case = tuple[str, dict[str, Any], list[dict[str, Any]]]
"""(target, its summary row, the default's runs in the row's seed order)."""


def cheap_cases(root: Path, systems: tuple[str, ...] | None, default: str) -> list[Case]:
    """One case per target under ``root`` with peers (``benchmarks.transfer.summarize``, the
    ``@avx512`` runs read in place of the stored ones)."""
    s = tr.summarize(root, default=default, machine="avx512",
                     methods=[*tr.PEERS, "transfer"], systems=list(systems) if systems else None)
    out = []
    for row in s["targets"]:
        runs = [load_trace([root], row["system"], row["gap"], sd, default) for sd in row["seeds"]]
        if None in runs:
            raise ValueError(f"no stored default run for {row['system']} gap {row['gap']:g}")
        out.append((f"{row['system']} {row['gap']:g}", row, runs))
    return out


def robot_cases(summary: Path, traces: Path, default: str) -> list[Case]:
    """One case per rung of a robot summary, the default's runs from the exported traces."""
    s = json.loads(summary.read_text())
    out = []
    for row in s["targets"]:
        d = json.loads((traces / f"{row['target']}.json").read_text())
        by_seed = runs_by_seed(d["runs"], default)
        if not set(row["seeds"]) <= set(by_seed):
            raise ValueError(f"the traces of {row['target']} lack the default's seeds "
                             f"{sorted(set(row['seeds']) - set(by_seed))}")
        out.append((row["target"], row, [by_seed[sd] for sd in row["seeds"]]))
    return out


def _cut(run: dict[str, Any], end: Ends) -> dict[str, Any]:
    """``run`` stopped where the rule ``end`` says (:func:`benchmarks.transfer.cut_at`)."""
    return tr.cut_at(run, end(list(run["costs"]), [bool(x) for x in run["failed"]]))


def judge(cases: list[Case], end: Ends | None) -> dict[str, Any]:
    """Criteria (1), (3) and both over ``cases`` with the default's runs cut by ``end`` (None:
    as stored), the falls, the paired cost and the targets that fail."""
    from scipy.stats import gmean

    n1 = n3 = n13 = falls = 0
    ratios: list[float] = []
    fails = []
    for key, row, runs in cases:
        peer = row["methods"][row["best_peer"]]
        cut = [_cut(r, end) if end else r for r in runs]
        best = [min(r["costs"]) for r in cut]
        fl = [int(sum(r["failed"])) for r in cut]
        ok1 = tr._no_worse(best, peer["best"])[0]
        ok3 = float(np.median(fl)) <= (1 if peer["falls_median"] <= 4
                                       else peer["falls_median"] / 4)
        n1, n3, n13, falls = n1 + ok1, n3 + ok3, n13 + (ok1 and ok3), falls + sum(fl)
        ratios += [b / min(r["costs"]) for b, r in zip(best, runs) if min(r["costs"]) > 0]
        if not (ok1 and ok3):
            fails.append(key + ("" if ok1 else " (1)") + ("" if ok3 else " (3)"))
    return {"targets": len(cases), "c1": n1, "c3": n3, "c1_and_c3": n13, "falls": falls,
            "paired_cost": float(gmean(ratios)) if ratios else 1.0, "fails": fails}


def paired_only(runs: list[dict[str, Any]], end: Ends) -> dict[str, Any]:
    """Falls and paired cost of ``runs`` cut by ``end`` (a set without peers)."""
    from scipy.stats import gmean

    cut = [_cut(r, end) for r in runs]
    ratio = [min(c["costs"]) / min(r["costs"]) for c, r in zip(cut, runs)]
    return {"runs": len(runs), "falls": int(sum(sum(c["failed"]) for c in cut)),
            "falls_uncut": int(sum(sum(r["failed"]) for r in runs)),
            "paired_cost": float(gmean(ratio)), "worst": float(max(ratio))}


def rules() -> list[tuple[str, dict[str, Any], Ends]]:
    """Every rule of both families' grids: (family, parameters, ends)."""
    out: list[tuple[str, dict[str, Any], Ends]] = []
    for a, b, c in itertools.product(*EARLY_GRID.values()):
        out.append(("early", {"a": a, "b": b, "counts": c},
                    lambda y, f, a=a, b=b, c=c: early_end(y, f, a, b, c)))
    for m, w in itertools.product(*STALL_GRID.values()):
        out.append(("stall", {"m": m, "w": w}, lambda y, f, m=m, w=w: stall_end(y, f, m, w)))
    return out


def choose(ladder: list[dict[str, Any]], base: dict[str, Any]) -> dict[str, Any]:
    """The bar's choice among one family's ladder results: (1) on as many targets as the
    default, then the most targets with (1) and (3), then the lower paired cost, then the
    grid's later entry (each grid runs from tighter budgets to looser ones)."""
    keep = [r for r in ladder if r["ladder"]["c1"] >= base["c1"]]
    if not keep:
        raise ValueError("no rule keeps criterion (1) on the ladder")
    top = max(r["ladder"]["c1_and_c3"] for r in keep)
    return min((r for r in keep if r["ladder"]["c1_and_c3"] == top),
               key=lambda r: (round(r["ladder"]["paired_cost"], 6), -ladder.index(r)))


def parse_rule(text: str, grid: list[dict[str, Any]]) -> dict[str, Any]:
    """The grid's entry named ``FAMILY:K=V,...`` (e.g. ``early:a=1,b=1,counts=all``);
    ValueError naming the grids for any other."""
    fam, _, kv = text.partition(":")
    want = dict(x.partition("=")[::2] for x in kv.split(",") if x)

    def same(v: Any, given: str) -> bool:
        try:
            return type(v)(given) == v
        except ValueError:
            return False

    for g in grid:
        if g["family"] == fam and set(want) == set(g["params"]) and \
                all(same(g["params"][k], want[k]) for k in want):
            return g
    raise ValueError(f"--also {text!r} is no rule of the grids (early:a=A,b=B,counts=C with "
                     f"{EARLY_GRID}; stall:m=M,w=W with {STALL_GRID})")


def main(argv: list[str] | None = None) -> int:
    from benchmarks.common import bench_parser, out_file, write_text
    ap = bench_parser("benchmarks.transfer_stop", description=__doc__.splitlines()[0])
    ap.add_argument("--runs", required=True)
    ap.add_argument("--heldout-runs", required=True)
    ap.add_argument("--fresh-runs", default=None)
    ap.add_argument("--robot-summary", default=None)
    ap.add_argument("--robot-traces", default=None)
    ap.add_argument("--default", default=tr.DEFAULT_METHOD)
    ap.add_argument("--also", nargs="*", default=[], metavar="FAMILY:K=V,...",
                    help="rules judged on every set beside the chosen ones (not a choice: a "
                         "look), e.g. early:a=1,b=1,counts=all or stall:m=2,w=0.25")
    ap.add_argument("--out", type=out_file, default=None, metavar="FILE.json")
    a = ap.parse_args(sys.argv[1:] if argv is None else argv)
    try:
        if (a.robot_summary is None) != (a.robot_traces is None):
            raise ValueError("--robot-summary and --robot-traces go together")
        for p in (a.runs, a.heldout_runs, a.fresh_runs):
            if p is not None and not Path(p).is_dir():
                raise ValueError(f"no such directory: {p}")
        sets = {"ladder": cheap_cases(Path(a.runs), LADDER, a.default),
                "heldout_systems": cheap_cases(Path(a.runs), HELDOUT, a.default),
                "heldout_gaps": cheap_cases(Path(a.heldout_runs), None, a.default)}
        if a.robot_summary:
            sets["robots"] = robot_cases(Path(a.robot_summary), Path(a.robot_traces), a.default)
        fresh = ([json.loads(f.read_text()) for f in
                  sorted(Path(a.fresh_runs).glob(f"*/gap*/seed*/{a.default}.json"))]
                 if a.fresh_runs else [])
        if a.fresh_runs and not fresh:
            raise ValueError(f"no run of {a.default} under {a.fresh_runs}")
        base = {k: judge(v, None) for k, v in sets.items()}
        grid = []
        for fam, params, end in rules():
            grid.append({"family": fam, "params": params,
                         "ladder": judge(sets["ladder"], end), "_end": end})
        chosen = {}
        picks = [(f"chosen {fam}", choose([g for g in grid if g["family"] == fam],
                                          base["ladder"])) for fam in ("early", "stall")]
        picks += [(f"also {r}", parse_rule(r, grid)) for r in a.also]
        for name, c in picks:
            chosen[name] = {"family": c["family"], "params": c["params"],
                            **{k: judge(v, c["_end"]) for k, v in sets.items()}}
            if fresh:
                chosen[name]["fresh"] = paired_only(fresh, c["_end"])
    except (OSError, ValueError, KeyError) as e:
        error_line("benchmarks.transfer_stop", e)
        return 2
    for g in grid:
        del g["_end"]
    res = {"default": base, "grid": grid, "chosen": chosen}
    line = ("{:34s} (1) {c1:2d}  (3) {c3:2d}  both {c1_and_c3:2d} of {targets:2d}  "
            "falls {falls:4d}  paired {paired_cost:.4f}")
    print("ladder grid:")
    for g in grid:
        p = " ".join(f"{k}={v}" for k, v in g["params"].items())
        print(line.format(f"{g['family']} {p}", **g["ladder"]))
    for name, c in chosen.items():
        print(f"{name}: {c['params']}")
        for k in sets:
            print("  " + line.format(f"{k}, default", **base[k]))
            print("  " + line.format(f"{k}, {c['family']}", **c[k]),
                  "| fails:", "; ".join(c[k]["fails"]))
        if "fresh" in c:
            f = c["fresh"]
            print(f"  fresh gaps ({f['runs']} runs): falls {f['falls']} of {f['falls_uncut']}, "
                  f"paired {f['paired_cost']:.4f}, worst {f['worst']:.3f}")
    if a.out:
        write_text(a.out, json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.transfer_stop"))
