"""``escape_falls`` on targets where the source's stable region falls: bowl-shaped user systems
of 2, 4 and 8 weights (the bar: ``results/transfer/escape/bar.md``).

    python -m benchmarks.transfer_escape run [--root runs/escape] [--dims 2 4 8]
        [--seeds 0 1 2 3 4] [--kinds anti moved narrow] [--budget 30] [--k 8]
    python -m benchmarks.transfer_escape summary [--root runs/escape] [--k 8] --out F.json
    python -m benchmarks.transfer_escape blind [--root runs/transfer] [--out runs/escape_blind]
        [--seeds 0 ... 9] [--budget 40] [--k 8]

The source (the model) costs ``q(θ) = Σ (θ_i − 0.3)²`` on the unit box and fails where
``q > r`` (``r = 0.35 d / 4``): it stands in a ball around 0.3. Each target keeps the cost and
moves where it fails:

* ``anti``: it fails where the source stands (``q ≤ r``) and stands everywhere else;
* ``moved``: it stands in a ball of the source's radius around 0.8 (its cost there is
  ``Σ (θ_i − 0.8)²``), so the source's stable region falls but for the overlap;
* ``narrow``: it stands where ``q ≤ r / 10`` (a control: the source is right, its region
  smaller).

A failed trial has no cost (the loop's fall convention gives it one), as a user system that
only says "it fell" does. Each seed has its own source run (phase 1 of 150 trials, batch 4,
and the latent space) under ``ROOT/d<d>/seed<s>/source``; the methods on each target are the
default transfer phase 3, the same with ``escape_falls=k``, and two peers a user would pick
(TuRBO-m from the manual θ, Optuna's GPSampler), ``budget`` trials each, the zero-shot trial
included for the transfer phase 3. Runs are stored as JSON under
``ROOT/d<d>/seed<s>/<kind>/<method>.json`` and skipped when present (the run resumes).
``summary`` gives per (kind, d) the median best (a run where every trial fell: inf), the median
falls, how many runs found a standing trial, and the bar's verdicts. ``blind`` runs the default
and ``escape_falls=k`` on the ladder's harshest targets with their falls reported blind
(:class:`Blind`), on the ladder's sources; ``benchmarks.transfer compare --root OUT`` pairs
them.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

import latentune as lt
from benchmarks.common import error_line

SOURCE_EVALS = 150
CENTRE, MOVED = 0.3, 0.8
KINDS = ("anti", "moved", "narrow")


def _radius(d: int) -> float:
    return 0.35 * d / 4


class Bowl:
    """The bowl of ``d`` weights (module docstring): ``kind`` ``"source"`` or a target kind."""

    def __init__(self, d: int = 4, kind: str = "source") -> None:
        if kind not in ("source",) + KINDS:
            raise ValueError(f"kind must be source or one of {KINDS}, got {kind!r}")
        self.d, self.kind = int(d), kind
        self.space = lt.ParameterSpace([f"k{i}" for i in range(self.d)], [0.0] * self.d,
                                       [1.0] * self.d, manual=[0.5] * self.d)

    def config(self) -> dict[str, Any]:
        return {"kind": "escape_bowl", "d": self.d, "target": self.kind}

    def evaluate(self, theta: np.ndarray) -> lt.Outcome:
        u = self.space.validate_unit(theta)
        r = _radius(self.d)
        q = float(((u - CENTRE) ** 2).sum())
        if self.kind == "source":
            stands = q <= r
        elif self.kind == "anti":
            stands = q > r
        elif self.kind == "narrow":
            stands = q <= r / 10
        else:
            q = float(((u - MOVED) ** 2).sum())
            stands = q <= r
        return lt.Outcome(q, False) if stands else lt.Outcome(None, True)


class Blind:
    """A target whose falls are reported without a step or a cost (``Outcome(None, True)``):
    the loop's convention gives each the same cost, so nothing ranks them."""

    def __init__(self, target: Any) -> None:
        self.target, self.space = target, target.space

    def config(self) -> dict[str, Any]:
        return {**self.target.config(), "blind_falls": True}

    def evaluate(self, theta: np.ndarray) -> lt.Outcome:
        from latentune.system import evaluate

        out = evaluate(self.target, theta)
        return lt.Outcome(None, True) if out.failed else out


BLIND_TARGETS = (("servo", 1.0), ("vehicle", 2.5), ("quadrotor", 2.5))
"""The targets ``escape_falls=8`` changed (the default ran 8 or more falls first there)."""


def run_blind(root: Path, out: Path, seeds: list[int], budget: int, k: int) -> None:
    """The default and ``escape_falls=k`` on :class:`Blind` versions of
    :data:`BLIND_TARGETS`, on the ladder's sources under ``root`` (made when missing), stored
    as ``out/<system>/gap<g>/seed<s>/<method>.json`` (skipped when present)."""
    from benchmarks.transfer import SYSTEMS, run_method, source_run

    for system, gap in BLIND_TARGETS:
        for s in seeds:
            src = source_run(root, system, s, 300)
            for name, opts in (("transfer", None), escape_variant(k)):
                f = out / system / f"gap{gap:g}" / f"seed{s}" / f"{name}.json"
                if f.is_file():
                    continue
                res = run_method("transfer", Blind(SYSTEMS[system]["target"](gap)), src,
                                 budget, s, opts)
                f.parent.mkdir(parents=True, exist_ok=True)
                f.write_text(json.dumps({"costs": res["costs"], "failed": res["failed"],
                                         "system": system, "gap": gap, "seed": s,
                                         "method": name, "budget": budget}))
                fl = np.asarray(res["failed"], bool)
                print(f"blind {system} gap {gap:g} seed {s} {name}: falls {int(fl.sum())}",
                      flush=True)


def source_dir(root: Path, d: int, seed: int) -> Path:
    """Phase 1 + the latent space on the source bowl (resumes); its directory."""
    src = root / f"d{d}" / f"seed{seed}" / "source"
    with lt.Study(src, seed=seed, batch_size=4) as st:
        st.phase1(Bowl(d), SOURCE_EVALS)
        st.train_latent()
    return src


def escape_variant(k: int) -> tuple[str, dict[str, Any]]:
    """The stored name and the transfer options of ``escape_falls=k``."""
    return f"transfer+escape_falls={k}", {"escape_falls": k}


def methods(k: int) -> dict[str, tuple[str, dict[str, Any] | None]]:
    """name -> (benchmarks.transfer method, transfer options)."""
    name, opts = escape_variant(k)
    return {"transfer": ("transfer", None), name: ("transfer", opts),
            "turbo_manual": ("turbo_manual", None), "gp": ("gp", None)}


def run(root: Path, dims: list[int], seeds: list[int], kinds: list[str], budget: int,
        k: int) -> None:
    from benchmarks.transfer import run_method

    for d in dims:
        for s in seeds:
            src = source_dir(root, d, s)
            for kind in kinds:
                for name, (m, opts) in methods(k).items():
                    out = root / f"d{d}" / f"seed{s}" / kind / f"{name}.json"
                    if out.is_file():
                        continue
                    res = run_method(m, Bowl(d, kind), src, budget, s, opts)
                    out.parent.mkdir(parents=True, exist_ok=True)
                    out.write_text(json.dumps({k2: res[k2] for k2 in ("costs", "failed")}))
                    f = np.asarray(res["failed"], bool)
                    print(f"d{d} seed{s} {kind} {name}: falls {int(f.sum())}/{len(f)}",
                          flush=True)


def summary(root: Path, k: int) -> dict[str, Any]:
    rows = []
    for kind in KINDS:
        for dd in sorted(root.glob("d*"), key=lambda p: int(p.name[1:])):
            per: dict[str, dict[str, list]] = {}
            for name in methods(k):
                for f in sorted(dd.glob(f"seed*/{kind}/{name}.json")):
                    r = json.loads(f.read_text())
                    c, fl = np.asarray(r["costs"], float), np.asarray(r["failed"], bool)
                    best = float(c[~fl].min()) if (~fl).any() else float("inf")
                    e = per.setdefault(name, {"best": [], "falls": [], "stood": []})
                    e["best"].append(best)
                    e["falls"].append(int(fl.sum()))
                    e["stood"].append(bool((~fl).any()))
            if not per:
                continue
            row = {"kind": kind, "d": int(dd.name[1:]), "methods": {
                n: {"seeds": len(v["best"]), "median_best": float(np.median(v["best"])),
                    "median_falls": float(np.median(v["falls"])),
                    "runs_standing": int(sum(v["stood"]))} for n, v in per.items()}}
            rows.append(row)
    esc = escape_variant(k)[0]
    verdict: dict[str, Any] = {}
    trapped = [r for r in rows if r["kind"] in ("anti", "moved")]
    if trapped and all(esc in r["methods"] and "transfer" in r["methods"] for r in trapped):
        fall_ok = all(r["methods"][esc]["median_falls"] <= 0.5 * r["methods"]["transfer"]
                      ["median_falls"] for r in trapped)
        stood = sum(r["methods"][esc]["runs_standing"] for r in trapped)
        n = sum(r["methods"][esc]["seeds"] for r in trapped)
        verdict["anti_moved_falls_halved"] = fall_ok
        verdict["anti_moved_runs_standing"] = [stood, n]
        verdict["anti_moved_standing_ok"] = stood >= 0.8 * n
    ctrl = [r for r in rows if r["kind"] == "narrow"]
    if ctrl and all(esc in r["methods"] for r in ctrl):
        ratios = [r["methods"][esc]["median_best"] / r["methods"]["transfer"]["median_best"]
                  for r in ctrl]
        verdict["narrow_ratios"] = ratios
        verdict["narrow_ok"] = all(x <= 1.02 for x in ratios)
    return {"rows": rows, "verdict": verdict}


def _table(res: dict[str, Any]) -> str:
    lines = ["| target | d | method | median best | median falls | runs with a standing trial |",
             "|---|---:|---|---:|---:|---:|"]
    for r in res["rows"]:
        for n, m in r["methods"].items():
            lines.append(f"| {r['kind']} | {r['d']} | {n} | {m['median_best']:.4g} | "
                         f"{m['median_falls']:g} | {m['runs_standing']} of {m['seeds']} |")
    lines.append("")
    lines.append("verdict: " + json.dumps(res["verdict"]))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    from benchmarks.common import bench_parser, out_dir, out_file
    ap = bench_parser("benchmarks.transfer_escape", description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run")
    r.add_argument("--root", type=Path, default=Path("runs/escape"))
    r.add_argument("--dims", nargs="+", type=int, default=[2, 4, 8])
    r.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2, 3, 4])
    r.add_argument("--kinds", nargs="+", choices=KINDS, default=list(KINDS))
    r.add_argument("--budget", type=int, default=30)
    r.add_argument("--k", type=int, default=8)
    b = sub.add_parser("blind", help="the default and escape_falls on blind-fall targets")
    b.add_argument("--root", type=Path, default=Path("runs/transfer"),
                   help="the ladder's sources (benchmarks.transfer)")
    b.add_argument("--out", type=out_dir, default="runs/escape_blind")
    b.add_argument("--seeds", nargs="+", type=int, default=list(range(10)))
    b.add_argument("--budget", type=int, default=40)
    b.add_argument("--k", type=int, default=8)
    s = sub.add_parser("summary")
    s.add_argument("--root", type=Path, default=Path("runs/escape"))
    s.add_argument("--k", type=int, default=8)
    s.add_argument("--out", type=out_file, default=None)
    a = ap.parse_args(argv)
    if a.cmd == "run":
        run(a.root, a.dims, a.seeds, a.kinds, a.budget, a.k)
        return 0
    if a.cmd == "blind":
        run_blind(a.root, a.out, a.seeds, a.budget, a.k)
        return 0
    from benchmarks.common import Provenance, write_json

    prov = Provenance(argv, "benchmarks.transfer_escape")
    res = summary(a.root, a.k)
    if not res["rows"]:         # an empty table and exit 0 read as "nothing went wrong"
        error_line("benchmarks.transfer_escape summary",
                   f"no run of {', '.join(methods(a.k))} under {a.root}/d*/seed*/KIND")
        return 2
    text = _table(res)
    print(text)
    if a.out is not None:
        write_json(a.out, res, prov)
        a.out.with_suffix(".md").write_text(f"`python -m benchmarks.transfer_escape "
                                            f"{' '.join(argv or sys.argv[1:])}`\n\n{text}\n")
    return 0


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.transfer_escape"))
