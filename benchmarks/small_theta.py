"""The default phase 3 on small θ: the VAE's current hidden widths against Table I's, on thermal
zones of 1 to 4 rooms (4 to 16 gains, :mod:`examples.thermal_zones`).

    python -m benchmarks.small_theta --root runs/small_theta [--rooms 1 2 3 4] [--gaps 1 2]
        [--seeds 0 .. 9] [--phase1 300] [--budget 40] [--rules current table1]
        [--options OPTION=VALUE[:...]] [--against EARLIER.json] [--out F.json]

Per (rooms, seed): phase 1 on the model (gap 0; ``--phase1`` trials, TuRBO-m, batch 4, the
seed) once, in ``ROOT/r<rooms>/seed<s>/phase1``; it is copied to two sources, and each gets a
latent space trained by ``Study.train_latent`` with one rule of hidden widths: ``current``
(:func:`latentune.latent.vae.hidden_widths`) and ``table1`` (max(⌊d/2⌋, 1), max(⌊d/4⌋, 1),
the rule before session 31, reproduced by replacing ``hidden_widths`` while that source
trains). Per gap and rule, the default phase 3 (``Study.phase3``, strategy transfer) runs
``--budget`` trials on the target from that source, with the seed. Everything resumes.

Output rows per (rooms, gap, rule): the median over seeds of the best cost within the budget
and of the falls, and per (rooms, gap) the pairs ``current`` against ``table1`` (lower best,
tie, higher); ``overall`` pools every pair (:func:`overall`). ``runs`` holds every run's costs and failed flags per trial and each source's
``decoded_variance_ratio`` and whether its codes all decode to one θ, and the trials and falls
of each of the critic's pools (``pool_falls``: falls / trials summed over the seeds).
``explore_pool`` records the default phase 3's explore pool of the run
(``TRANSFER_DEFAULTS``).

``--rules`` runs only those rules. ``--options`` runs the default phase 3 with these options of
the transfer critic changed (``"explore_fall_prob=0.15"``, as ``benchmarks.transfer``'s
variants; passed as ``Study.phase3(transfer_options=...)``, ``max_fall_prob`` as its own
argument; recorded as ``options``); its target runs are stored beside the default's, in
``<rule>+<options>``, so both resume. ``--against`` pairs this run's ``current`` runs with those of
an earlier output of this benchmark, made with another default phase 3 (``against``: this run
lower / tie / higher, sign test, geometric mean of the best-cost ratios, falls of each). The
sources must be the same: every pair's first trial (the zero-shot θ) must cost the same to
1e-9 relative, else the pairing is refused.
"""
from __future__ import annotations

import contextlib
import shutil
import sys
from pathlib import Path
from typing import Any, Iterator

from latentune.threads import one_thread_env

one_thread_env()

import numpy as np  # noqa: E402

from benchmarks.common import (Provenance, add_out_arg, bench_parser, error_line,  # noqa: E402
                               finish)

RULES = ("current", "table1")
POOLS = ("elite", "full", "latent", "global")
"""The transfer critic's pools by ``tag % 4`` (:mod:`latentune.critic.transfer`, "Tags")."""


@contextlib.contextmanager
def widths_rule(rule: str) -> Iterator[None]:
    """Train latent spaces with ``rule``'s widths inside the block."""
    import latentune.latent.vae as vae

    if rule == "current":
        yield
        return
    kept = vae.hidden_widths
    vae.hidden_widths = lambda d: (max(d // 2, 1), max(d // 4, 1))      # type: ignore
    try:
        yield
    finally:
        vae.hidden_widths = kept                                         # type: ignore


def phase3_options(options: dict[str, Any]) -> dict[str, Any]:
    """The arguments of ``Study.phase3`` for the transfer ``options`` (``--options`` parsed):
    ``max_fall_prob`` (its own argument) and ``transfer_options`` (the others); checked
    (UsageError naming the option)."""
    from latentune.pipeline import manifest as mf

    opts = dict(options)
    mfp = mf.fall_options(opts.pop("max_fall_prob", None), None)["max_fall_prob"]
    return {"max_fall_prob": mfp, **mf.transfer_option(opts, "transfer", mfp)}


def source(root: Path, rooms: int, seed: int, phase1: int, rule: str) -> tuple[Path, dict]:
    """The source of (rooms, seed, rule) (module docstring) and its latent space's record."""
    import latentune as lt
    from examples.thermal_zones import make_system
    from latentune.errors import LatentError

    base = root / f"r{rooms}" / f"seed{seed}"
    with lt.Study(base / "phase1", seed=seed, batch_size=4) as st:
        st.phase1(make_system(0.0, rooms=rooms), phase1)
    d = base / f"src_{rule}"
    if not (d / "vae.json").is_file():
        shutil.rmtree(d, ignore_errors=True)
        shutil.copytree(base / "phase1", d, ignore=shutil.ignore_patterns("run.lock"))
        with widths_rule(rule), lt.Study(d) as st:
            st.train_latent()
    with lt.Study(d) as st:
        ls = st.latent()
    try:
        ls.require_spread()
        one = False
    except LatentError:
        one = True
    return d, {"hidden": ls.meta.get("hidden"), "spread": ls.meta.get("decoded_variance_ratio"),
               "decodes_to_one_theta": one}


def target_run(root: Path, rooms: int, seed: int, gap: float, rule: str, src: Path,
               budget: int, options: str = "", phase3_kw: dict[str, Any] | None = None
               ) -> dict[str, Any]:
    """The default phase 3 of --budget trials on the target with the arguments ``phase3_kw``
    (:func:`phase3_options` of the transfer options; none: the defaults), stored in the
    directory ``options`` (their ``"option=value[:...]"`` text) names; its costs and failed
    flags."""
    import latentune as lt
    from examples.thermal_zones import make_system
    from latentune.constants import Phase

    d = root / f"r{rooms}" / f"seed{seed}" / f"gap{gap:g}" / (f"{rule}+{options}" if options
                                                               else rule)
    with lt.Study(d, seed=seed) as st:
        st.phase3(make_system(gap, rooms=rooms), budget, latent=src, **(phase3_kw or {}))
        rows = st.store.rows(Phase.PHASE3)
    costs = [float(r.cost) for r in rows][:budget]
    failed = [bool(r.fell) for r in rows][:budget]
    pools: dict[str, list[int]] = {}                # pool of each trial's ask: [trials, falls]
    for r in rows[:budget]:
        p = POOLS[r.tag % 4] if r.tag is not None else "zero-shot"
        pools.setdefault(p, [0, 0])
        pools[p][0] += 1
        pools[p][1] += bool(r.fell)
    return {"costs": costs, "failed": failed, "best": min(costs), "falls": sum(failed),
            "pools": pools}


def paired(pairs: list[tuple[float, float]]) -> dict[str, Any]:
    """Pairs ``(a, b)`` of best costs: ``a`` lower / tie / higher, the two-sided sign test's p
    over the untied pairs, the geometric mean of the ratios a / b."""
    from scipy.stats import binomtest

    lo, hi = sum(a < b for a, b in pairs), sum(a > b for a, b in pairs)
    return {"pairs": len(pairs), "lower": lo, "tie": len(pairs) - lo - hi, "higher": hi,
            "sign_p": float(binomtest(lo, lo + hi).pvalue) if lo + hi else None,
            "geomean_ratio": float(np.exp(np.mean([np.log(a / b) for a, b in pairs])))
            if pairs else None}


def counts(pairs: list[tuple[float, float]]) -> str:
    """``"lower / tie / higher"`` of pairs ``(a, b)``, as :func:`paired` counts them."""
    p = paired(pairs)
    return f"{p['lower']} / {p['tie']} / {p['higher']}"


def overall(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """Every (rooms, gap, seed) pair: ``current`` lower / tie / higher best than ``table1``, the
    two-sided sign test's p over the untied pairs, the geometric mean of the best-cost ratios
    current / table1, and each rule's falls."""
    key = {(x["rooms"], x["gap"], x["seed"], x["rule"]): x for x in runs}
    p = paired([(key[k[:3] + ("current",)]["best"], x["best"]) for k, x in key.items()
                if k[3] == "table1" and k[:3] + ("current",) in key])
    return {"pairs": p["pairs"], "current_lower": p["lower"], "tie": p["tie"],
            "current_higher": p["higher"], "sign_p": p["sign_p"],
            "geomean_ratio": p["geomean_ratio"],
            "falls": {r: sum(x["falls"] for x in runs if x["rule"] == r) for r in RULES}}


def pool_falls(runs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per (rooms, gap, rule): trials and falls of each pool, summed over the seeds."""
    out: dict[tuple, dict[str, list[int]]] = {}
    for x in runs:
        acc = out.setdefault((x["rooms"], x["gap"], x["rule"]), {})
        for p, (n, f) in x.get("pools", {}).items():
            acc.setdefault(p, [0, 0])
            acc[p][0] += n
            acc[p][1] += f
    return [{"rooms": k[0], "gap": k[1], "rule": k[2],
             **{p: f"{v[1]} / {v[0]}" for p, v in sorted(acc.items())}}
            for k, acc in out.items()]


def against(runs: list[dict[str, Any]], earlier: dict[str, Any]) -> dict[str, Any]:
    """This run's ``current`` runs paired by (rooms, gap, seed) with ``earlier``'s (an output of
    this benchmark): this run lower / tie / higher, the two-sided sign test's p, the geometric
    mean of the best-cost ratios (this / earlier) (:func:`paired`) and each side's falls.
    ``ValueError`` when a pair's first trial costs differ (not the same source) or no pair
    exists."""
    old = {(x["rooms"], x["gap"], x["seed"]): x for x in earlier["runs"]
           if x["rule"] == "current"}
    pairs = [(x, old[k]) for x in runs if x["rule"] == "current"
             and (k := (x["rooms"], x["gap"], x["seed"])) in old]
    if not pairs:
        raise ValueError("no (rooms, gap, seed) of this run is in the earlier output")
    for x, o in pairs:
        if not np.isclose(x["costs"][0], o["costs"][0], rtol=1e-9, atol=0.0):
            raise ValueError(f"rooms {x['rooms']} gap {x['gap']:g} seed {x['seed']}: the first "
                             f"trial costs {x['costs'][0]!r} here and {o['costs'][0]!r} in the "
                             "earlier output: not the same source")
    return {**paired([(x["best"], o["best"]) for x, o in pairs]),
            "falls": sum(x["falls"] for x, _ in pairs),
            "falls_earlier": sum(o["falls"] for _, o in pairs),
            "earlier_explore_pool": earlier.get("explore_pool", "latent"),
            "by_rooms_gap": [
                {"rooms": r, "gap": g,
                 "lower / tie / higher": counts([(x["best"], o["best"]) for x, o in pp]),
                 "median best": float(np.median([x["best"] for x, _ in pp])),
                 "median best earlier": float(np.median([o["best"] for _, o in pp])),
                 "falls": sum(x["falls"] for x, _ in pp),
                 "falls earlier": sum(o["falls"] for _, o in pp)}
                for r, g in sorted({(x["rooms"], x["gap"]) for x, _ in pairs})
                if (pp := [(x, o) for x, o in pairs if (x["rooms"], x["gap"]) == (r, g)])]}


def main(argv: list[str] | None = None) -> int:
    prov = Provenance(argv, "benchmarks.small_theta")
    ap = bench_parser("benchmarks.small_theta", description=__doc__.splitlines()[0])
    ap.add_argument("--root", type=Path, required=True)
    ap.add_argument("--rooms", type=int, nargs="+", default=[1, 2, 3, 4])
    ap.add_argument("--gaps", type=float, nargs="+", default=[1.0, 2.0])
    ap.add_argument("--seeds", type=int, nargs="+", default=list(range(10)))
    ap.add_argument("--phase1", type=int, default=300)
    ap.add_argument("--budget", type=int, default=40)
    ap.add_argument("--rules", nargs="+", choices=RULES, default=list(RULES))
    ap.add_argument("--options", default="", metavar="OPTION=VALUE[:...]")
    ap.add_argument("--against", type=Path, default=None, metavar="EARLIER.json")
    add_out_arg(ap)
    a = ap.parse_args(argv)
    earlier = None
    from benchmarks.transfer import parse_variant
    from latentune.critic.transfer import TRANSFER_DEFAULTS
    from latentune.errors import UsageError

    options = parse_variant(a.options)
    try:            # the critic's own checks, before any trial
        phase3_kw = phase3_options(options)
    except UsageError as e:
        error_line("benchmarks.small_theta", f"--options: {e}")
        return 2
    if a.against is not None and "current" not in a.rules:
        error_line("benchmarks.small_theta",
                   "--against pairs the current rule's runs: give --rules "
                   "current")
        return 2
    if a.against is not None:
        import json

        try:
            earlier = json.loads(a.against.read_text())
            assert isinstance(earlier, dict) and isinstance(earlier.get("runs"), list)
        except (OSError, ValueError, AssertionError) as e:
            error_line("benchmarks.small_theta",
                       f"--against {a.against}: not an output of this benchmark "
                       f"({e.__class__.__name__})")
            return 2
    if not all(1 <= r <= 4 for r in a.rooms) or a.phase1 < 8 or a.budget < 2 or \
            min(a.gaps) <= 0:
        error_line("benchmarks.small_theta",
                   "--rooms in [1, 4] (θ below 20 gains), --phase1 >= 8, "
                   "--budget >= 2, --gaps > 0")
        return 2
    runs, rows = [], []
    for rooms in a.rooms:
        for s in a.seeds:
            srcs = {rule: source(a.root, rooms, s, a.phase1, rule) for rule in a.rules}
            for g in a.gaps:
                for rule in a.rules:
                    r = target_run(a.root, rooms, s, g, rule, srcs[rule][0], a.budget,
                                   a.options, phase3_kw)
                    runs.append({"rooms": rooms, "seed": s, "gap": g, "rule": rule,
                                 "source": srcs[rule][1], **r})
                    print(f"rooms {rooms} seed {s} gap {g:g} {rule}: best {r['best']:.4f}, "
                          f"falls {r['falls']}", flush=True)
    for rooms in a.rooms:
        for g in a.gaps:
            by = {rule: {x["seed"]: x for x in runs if (x["rooms"], x["gap"], x["rule"]) ==
                         (rooms, g, rule)} for rule in a.rules}
            pairs = [(by["current"][s]["best"], by["table1"][s]["best"]) for s in a.seeds] \
                if len(by) == 2 else []
            for rule in a.rules:
                rr = list(by[rule].values())
                rows.append({"rooms": rooms, "d": 4 * rooms, "gap": g, "rule": rule,
                             "median best": float(np.median([x["best"] for x in rr])),
                             "median falls": float(np.median([x["falls"] for x in rr])),
                             "falls": sum(x["falls"] for x in rr),
                             "sources decoding to one θ":
                                 sum(x["source"]["decodes_to_one_theta"] for x in rr),
                             "current lower / tie / higher": "" if rule == "table1" or
                             not pairs else counts(pairs)})
    extra: dict[str, Any] = {}
    if earlier is not None:
        try:
            extra["against"] = {"file": str(a.against), **against(runs, earlier)}
        except ValueError as e:
            error_line("benchmarks.small_theta", f"--against: {e}")
            return 2
        print(f"against {a.against}: {extra['against']}", flush=True)
    finish(a.out, prov, {"root": str(a.root), "rooms": a.rooms, "gaps": a.gaps,
                         "seeds": a.seeds, "phase1": a.phase1, "budget": a.budget,
                         "rules": a.rules, "options": options,
                         "explore_pool": options.get("explore_pool",
                                                     TRANSFER_DEFAULTS["explore_pool"]),
                         "overall": overall(runs), "pool_falls": pool_falls(runs),
                         "runs": runs, **extra}, rows,
           title="the default phase 3 on small θ: current widths against Table I's")
    return 0


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.small_theta"))
