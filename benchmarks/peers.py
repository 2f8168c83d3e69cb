"""latentune's critics against peer optimizers, side by side on one suite (issue 16).

Every (problem, method, seed) runs in this process, one thread (``OMP_NUM_THREADS=1``,
``torch.set_num_threads(1)``), on the peer suite of :func:`benchmarks.common.problems` (unit box),
with the same budget and batch size, and is written as soon as it completes to
``<dir>/runs/<problem>__<method>__s<seed>__b<budget>[__<hash>].json`` (best value, best-so-far
trace, wall and function seconds). A killed run continues where it stopped: finished runs are
skipped. Runs of latentune's critics carry a hash of the code (docstrings and comments left out)
of the critics they use (``base``, ``turbo``, ``cmaes``, ``random_search``, ``__init__`` in
``src/latentune/critic/``) in their name,
so they are redone after the critic changes and the older ones stay for comparison
(``--report --critic-hash HASH``). Every invocation is appended to ``<dir>/invocations.jsonl``
(command, date, seeds, budgets, versions, ``os.getloadavg()`` at start and end).

Methods (all minimize on [0, 1]^d; batch = ``--batch-size`` points per ask unless stated):

* ``lt_turbo``, ``lt_cma``: ``latentune.minimize(method="turbo" / "cma")`` with its defaults.
  ``--variant NAME='{"opt": value}'`` adds ``lt_turbo@NAME`` (or ``lt_cma@NAME`` with
  ``--variant-method cma``) with extra critic options.
* ``ref_turbo1``: reference TuRBO-1 (``uber-turbo``), ``n_init = 2·d``.
* ``ref_turbom``: reference TuRBO-m, ``m = 3`` regions, ``n_init = min(2·d, budget // (2·m))``
  per region (its 2·d does not fit 3 regions in 500 evaluations above 41 dimensions).
  The reference restarts can evaluate past ``max_evals``: the objective wrapper stops both at the
  budget.
* ``optuna_tpe`` (``TPESampler(multivariate=True)``), ``optuna_cma`` (``CmaEsSampler``: its
  defaults, mean at the centre, sigma0 = 1/6 of the range, population 4 + ⌊3 ln d⌋),
  ``optuna_gp`` (``GPSampler``; ``--gp-budget``, default 200, because it is slow): batches of
  ``--batch-size`` trials asked before any is told.
* ``pycma``: pycma as a user would call it: ``cma.CMAEvolutionStrategy(centre, 0.3 · range,
  {"bounds": [0, 1]})``, its default population, one generation per batch, a fresh start from
  a random mean when it stops.

Report (``--report``): per problem the median and [min, max] of the best value over seeds, the
rank of every method by median and a tied-best mark (a method is tied-best if a two-sided
Mann–Whitney U test over seeds does not separate it from the method with the best median at
p < 0.05), ``lt_turbo``'s win/tie/loss against every peer, and each method's own seconds per
suggested point (wall minus function time, divided by the evaluations). Methods with a smaller
budget (``optuna_gp``) are compared with the others' best-so-far at that budget. Written to
``<dir>/summary.md`` and ``<dir>/summary.json`` (``summary_<hash>.*`` with ``--critic-hash``;
``--baseline-hash HASH`` adds the latentune runs of an older critic as peers ``before:<method>``).

Relabel (``--relabel HASH``): after a change to the critics' code that leaves the defaults'
path alone, re-runs ``--relabel-check`` (3) of each of the ``lt_turbo``/``lt_cma`` runs of ``HASH``; if
their best-so-far traces are bit-identical, copies all of them under the current hash (with a
``relabelled`` record), so they need not be run again. Only runs made on this kind of machine
can be checked (runs that record no ``machine`` count as another machine's).

Compare (``--compare DIR``): the runs of ``--out`` against the runs of the same name in DIR
(identical traces, where they part, both medians per problem and method); every invocation
and run records the machine's CPU and vector extension (``machine``).

The TuRBO-m overhead (seconds per suggested point, thread settings, a busy machine) is
``benchmarks.turbo_overhead``.

    python -m benchmarks.peers --seeds 0 1 2 3 4 --budget 500 --batch-size 10
    python -m benchmarks.peers --report
"""
from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import datetime  # noqa: E402
import hashlib  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import traceback  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from benchmarks.common import (ROOT, Provenance, bench_parser, error_line, git_commit,  # noqa: E402
                               machine, out_dir, out_file, problems, versions, write_json)

CRITIC_DIR = ROOT / "src" / "latentune" / "critic"
CRITIC_FILES = ("__init__.py", "base.py", "cmaes.py", "random_search.py", "turbo.py")
ALL_METHODS = ["lt_turbo", "lt_cma", "pycma", "optuna_cma", "optuna_tpe", "ref_turbo1",
               "ref_turbom", "optuna_gp"]
HEAVY_ORDER = ["optuna_tpe", "ref_turbo1", "optuna_gp", "ref_turbom"]
HEAVY = set(HEAVY_ORDER)


def code_digest(source: str) -> bytes:
    """The code of a module without its docstrings and comments (its AST), as bytes."""
    import ast

    tree = ast.parse(source)
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if (isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef))
                and body and isinstance(body[0], ast.Expr)
                and isinstance(body[0].value, ast.Constant)
                and isinstance(body[0].value.value, str)):
            node.body = body[1:] or [ast.Pass()]
    return ast.dump(tree, include_attributes=False).encode()


def critic_hash(sources: dict[str, str] | None = None) -> str:
    """Hash of the code (not the docstrings) of the critics latentune's runs use."""
    h = hashlib.sha256()
    for name in sorted(CRITIC_FILES):
        src = sources[name] if sources is not None else (CRITIC_DIR / name).read_text()
        h.update(name.encode())
        h.update(code_digest(src))
    return h.hexdigest()[:12]


class BudgetReached(Exception):
    pass


class Objective:
    """Counts and times evaluations, keeps the best-so-far trace, stops at the budget."""

    def __init__(self, problem, budget: int) -> None:
        self.p, self.budget = problem, budget
        self.y: list[float] = []
        self.fun_time = 0.0

    def __call__(self, u) -> float:
        if len(self.y) >= self.budget:
            raise BudgetReached
        u = np.clip(np.asarray(u, dtype=float).reshape(-1), 0.0, 1.0)
        t = time.perf_counter()
        v = self.p(u)
        self.fun_time += time.perf_counter() - t
        self.y.append(v)
        return v

    @property
    def left(self) -> int:
        return self.budget - len(self.y)


# ------------------------------------------------------------------ methods
def variant_options(opts: dict, d: int) -> dict:
    """A variant's options on a problem of dimension ``d``: an option given as "<k>d" is k
    times the dimension (e.g. ``{"n_init": "2d"}``)."""
    return {k: int(float(v[:-1]) * d) if isinstance(v, str) and v.endswith("d") and
            v[:-1].replace(".", "", 1).isdigit() else v for k, v in opts.items()}


def check_variant(method: str, opts: dict, dims: list[int], budget: int, batch: int) -> None:
    """UsageError (a ValueError) naming the option when ``lt_<method>`` with the variant's
    ``opts`` would be refused on a problem of one of the dimensions ``dims``: an option the
    critic does not have or a value it refuses (the critic of each run, built and not run)."""
    from latentune.optimize import minimize_critic

    for d in sorted(set(dims)):
        minimize_critic(method, d, budget=budget, batch_size=batch, seed=0,
                        **variant_options(opts, d))


def run_lt(method: str, opts: dict, obj: Objective, d: int, batch: int, seed: int) -> None:
    import latentune as lt

    lt.minimize(obj, [(0.0, 1.0)] * d, method=method, budget=obj.budget, batch_size=batch,
                seed=seed, **variant_options(opts, d))


def run_pycma(obj: Objective, d: int, batch: int, seed: int) -> None:
    import cma

    restart = 0
    x0 = np.full(d, 0.5)
    while obj.left > 0:
        es = cma.CMAEvolutionStrategy(x0.tolist(), 0.3, {"bounds": [0.0, 1.0], "verbose": -9,
                                                         "seed": 1 + seed + 1000 * restart})
        while not es.stop() and obj.left > 0:
            X = es.ask()
            if len(X) > obj.left:
                for x in X[: obj.left]:
                    obj(x)
                return
            es.tell(X, [obj(x) for x in X])
        restart += 1
        x0 = np.random.default_rng([seed, restart]).random(d)


def run_optuna(kind: str, obj: Objective, d: int, batch: int, seed: int) -> None:
    import optuna

    optuna.logging.set_verbosity(optuna.logging.ERROR)
    if kind == "tpe":
        sampler = optuna.samplers.TPESampler(multivariate=True, seed=seed)
    elif kind == "cma":
        sampler = optuna.samplers.CmaEsSampler(seed=seed)
    elif kind == "gp":
        sampler = optuna.samplers.GPSampler(seed=seed)
    else:
        raise ValueError(kind)
    import warnings

    warnings.filterwarnings("ignore", module="optuna")
    study = optuna.create_study(sampler=sampler)
    dists = {f"x{i:03d}": optuna.distributions.FloatDistribution(0.0, 1.0) for i in range(d)}
    while obj.left > 0:
        k = min(batch, obj.left)
        trials = [study.ask(dists) for _ in range(k)]   # the whole batch before any tell
        ys = [obj(np.array([tr.params[f"x{i:03d}"] for i in range(d)])) for tr in trials]
        for tr, v in zip(trials, ys):
            study.tell(tr, v)


def run_ref(kind: str, obj: Objective, d: int, batch: int, seed: int) -> None:
    import torch
    from turbo import Turbo1, TurboM

    np.random.seed(seed)          # the reference draws from the global generators
    torch.manual_seed(seed)

    def f(x):
        return obj(x)

    lb, ub = np.zeros(d), np.ones(d)
    if kind == "turbo1":
        opt = Turbo1(f=f, lb=lb, ub=ub, n_init=2 * d, max_evals=obj.budget, batch_size=batch,
                     verbose=False)
    else:
        m = 3
        n_init = min(2 * d, obj.budget // (2 * m))
        opt = TurboM(f=f, lb=lb, ub=ub, n_init=n_init, max_evals=obj.budget, batch_size=batch,
                     n_trust_regions=m, verbose=False)
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        opt.optimize()               # restarts inside; the wrapper stops it at the budget


def run_method(method: str, pname: str, seed: int, budget: int, batch: int,
               variants: dict) -> dict:
    prob = problems()[pname]
    d = prob.dim
    obj = Objective(prob, budget)
    t0 = time.perf_counter()
    try:
        if method == "lt_turbo" or method == "lt_cma":
            run_lt(method[3:], {}, obj, d, batch, seed)
        elif method.startswith("lt_") and "@" in method:
            base, name = method.split("@", 1)
            run_lt(base[3:], variants[name][1], obj, d, batch, seed)
        elif method == "pycma":
            run_pycma(obj, d, batch, seed)
        elif method.startswith("optuna_"):
            run_optuna(method[7:], obj, d, batch, seed)
        elif method.startswith("ref_"):
            run_ref(method[4:], obj, d, batch, seed)
        else:
            raise ValueError(f"unknown method {method}")
    except BudgetReached:
        pass
    wall = time.perf_counter() - t0
    y = np.array(obj.y)
    yf = np.where(np.isfinite(y), y, np.inf)
    trace = np.minimum.accumulate(yf).tolist()
    return dict(problem=pname, method=method, seed=seed, budget=budget, batch=batch,
                n=len(obj.y), best=float(yf.min()) if len(yf) else float("inf"),
                trace=trace, wall=wall, fun_time=obj.fun_time,
                overhead_per_point=(wall - obj.fun_time) / max(len(obj.y), 1))


def run_path(out: Path, pname: str, method: str, seed: int, budget: int, chash: str) -> Path:
    safe = method.replace("@", "-at-")
    tail = f"__{chash}" if method.startswith("lt_") else ""
    return out / "runs" / f"{pname}__{safe}__s{seed}__b{budget}{tail}.json"


def method_budget(method: str, budget: int, gp_budget: int) -> int:
    return min(budget, gp_budget) if method == "optuna_gp" else budget


def bench(a) -> int:
    """Run every (problem, method, seed) not written yet; 0, or 1 when a run raised (its
    traceback printed as it happened, the failed runs named in one line on stderr at the end,
    nothing written for them)."""
    import torch

    torch.set_num_threads(1)
    out = Path(a.dir)
    (out / "runs").mkdir(parents=True, exist_ok=True)
    variants = {}
    for v in a.variant or []:
        name, js = v.split("=", 1)
        variants[name] = (a.variant_method, json.loads(js))
    methods = list(a.methods) + [f"lt_{m}@{n}" for n, (m, _) in variants.items()]
    chash = critic_hash()
    inv = dict(command=" ".join([sys.executable] + sys.argv), cwd=os.getcwd(),
               date=datetime.datetime.now(datetime.timezone.utc).isoformat(),
               problems=a.problems, methods=methods, seeds=a.seeds, budget=a.budget,
               gp_budget=a.gp_budget, batch=a.batch_size, critic_hash=chash,
               variants={k: v[1] for k, v in variants.items()},
               versions=versions(("uber-turbo", "cmaes")), commit=git_commit(),
               machine=machine(), loadavg_start=os.getloadavg(), threads=dict(torch=torch.get_num_threads(),
                                                           omp=os.environ.get("OMP_NUM_THREADS")))
    with open(out / "invocations.jsonl", "a") as fh:
        fh.write(json.dumps(dict(inv, event="start")) + "\n")
    # cheap methods for every seed first, then the slow ones: for the first three seeds one
    # method after the other (HEAVY_ORDER), then for the other seeds
    work = []
    cheap = [m for m in methods if m not in HEAVY]
    heavy = [m for m in methods if m in HEAVY]
    for s in a.seeds:
        for p in a.problems:
            for m in cheap:
                work.append((p, m, s))
    groups = [a.seeds[:3], a.seeds[3:]]
    for group in groups:
        for m in sorted(heavy, key=HEAVY_ORDER.index):
            for s in group:
                for p in a.problems:
                    work.append((p, m, s))
    n_done, failed = 0, []
    for p, m, s in work:
        b = method_budget(m, a.budget, a.gp_budget)
        path = run_path(out, p, m, s, b, chash)
        if path.exists():
            continue
        try:
            r = run_method(m, p, s, b, a.batch_size, variants)
        except Exception:
            print(f"FAILED {p} {m} {s}:\n{traceback.format_exc()}", flush=True)
            failed.append(f"{p} {m} s{s}")
            continue
        r["critic_hash"] = chash if m.startswith("lt_") else None
        if m.startswith("lt_") and "@" in m:
            r["options"] = variants[m.split("@", 1)[1]][1]
        r["loadavg"] = os.getloadavg()
        r["machine"] = inv["machine"]
        r["date"] = datetime.datetime.now(datetime.timezone.utc).isoformat()
        tmp = path.with_suffix(".tmp")
        tmp.write_text(json.dumps(r))
        tmp.replace(path)
        n_done += 1
        print(f"{p:14s} {m:22s} s{s} best {r['best']:.5g}  n={r['n']}  wall {r['wall']:.1f}s  "
              f"own {r['overhead_per_point'] * 1e3:.1f} ms/pt  load {r['loadavg'][0]:.2f}",
              flush=True)
    inv["loadavg_end"] = os.getloadavg()
    inv["runs_done"] = n_done
    inv["runs_failed"] = failed
    with open(out / "invocations.jsonl", "a") as fh:
        fh.write(json.dumps(dict(inv, event="end")) + "\n")
    if failed:
        error_line("benchmarks.peers", f"{len(failed)} of {len(work)} runs failed (their "
                   f"tracebacks above; not written, a re-run tries them again): "
                   f"{', '.join(failed)}")
    return 1 if failed else 0


# ------------------------------------------------------------------ report
def _mwu(a, b) -> float:
    from scipy.stats import mannwhitneyu

    if len(a) < 2 or len(b) < 2:
        return 1.0
    if np.allclose(np.concatenate([a, b]), a[0]):
        return 1.0
    return float(mannwhitneyu(a, b, alternative="two-sided").pvalue)


def load_runs(out: Path) -> list[dict]:
    return [json.loads(p.read_text()) for p in sorted((out / "runs").glob("*.json"))]


def report(a) -> None:
    out = Path(a.dir)
    runs = load_runs(out)
    chash = a.critic_hash or critic_hash()
    # keep latentune runs of the current critic only (older ones are stale), and those of
    # --baseline-hash as the peers "before:<method>"
    kept = []
    for r in runs:
        if not r["method"].startswith("lt_") or r.get("critic_hash") == chash:
            kept.append(r)
        elif a.baseline_hash and r.get("critic_hash") == a.baseline_hash:
            kept.append(dict(r, method="before:" + r["method"]))
    runs = kept
    budget = a.budget
    probs = [p for p in a.problems if any(r["problem"] == p for r in runs)]
    methods = [m for m in ALL_METHODS if any(r["method"] == m for r in runs)]
    methods += sorted({r["method"] for r in runs if r["method"] not in ALL_METHODS})
    summary: dict = {"budget": budget, "gp_budget": a.gp_budget, "problems": {},
                     "critic_hash": chash}
    lines = [f"# latentune's critics against peers (budget {budget}, batch {a.batch_size})", "",
             "Best value found: median [min, max] over seeds (n = seeds); lower is better. "
             "`*` = tied-best (two-sided Mann–Whitney U against the best median, p >= 0.05); "
             f"ranks by median. `optuna_gp` ran {a.gp_budget} evaluations and is compared with "
             f"every method's best-so-far at {a.gp_budget} (second table). With fewer than 4 "
             "seeds on either side the test cannot reach p < 0.05, so such a method is always "
             "'tied'.", ""]

    def vals(p, m, at=None):
        out_ = []
        for r in runs:
            if r["problem"] == p and r["method"] == m and r["seed"] in a.seeds:
                if at is None:
                    if r["budget"] != budget:
                        continue
                    out_.append(r["best"])
                else:
                    if len(r["trace"]) >= at:
                        out_.append(r["trace"][at - 1])
        return np.array(out_)

    def table(at, meths, title):
        lines.append(f"## {title}")
        lines.append("")
        lines.append("| problem | " + " | ".join(meths) + " |")
        lines.append("|---|" + "---|" * len(meths))
        res = {}
        for p in probs:
            v = {m: vals(p, m, at) for m in meths}
            v = {m: x for m, x in v.items() if len(x)}
            if not v:
                continue
            med = {m: float(np.median(x)) for m, x in v.items()}
            best_m = min(med, key=med.get)
            order = sorted(med, key=med.get)
            cells = []
            res[p] = {}
            for m in meths:
                if m not in v:
                    cells.append("–")
                    continue
                pval = 1.0 if m == best_m else _mwu(v[m], v[best_m])
                tied = pval >= 0.05
                rank = order.index(m) + 1
                cells.append(f"{'**' if tied else ''}{med[m]:.4g}{'**' if tied else ''} "
                             f"[{v[m].min():.3g}, {v[m].max():.3g}] n{len(v[m])} "
                             f"r{rank}{'*' if tied else ''}")
                res[p][m] = dict(median=med[m], min=float(v[m].min()), max=float(v[m].max()),
                                 q25=float(np.percentile(v[m], 25)),
                                 q75=float(np.percentile(v[m], 75)), n=int(len(v[m])),
                                 rank=rank, tied_best=bool(tied), p_vs_best=pval,
                                 values=v[m].tolist())
            lines.append(f"| {p} | " + " | ".join(cells) + " |")
        lines.append("")
        return res

    main_m = [m for m in methods if m != "optuna_gp"]
    summary["problems"] = table(None, main_m, f"All methods at {budget} evaluations")
    if "optuna_gp" in methods:
        summary["at_gp_budget"] = table(a.gp_budget, methods,
                                        f"Best-so-far at {a.gp_budget} evaluations")
    # latentune's methods against each peer
    peers = [m for m in methods if not m.startswith("lt_")]
    for ours in [m for m in methods if m.startswith("lt_")]:
        lines.append(f"## {ours} against each peer (win / tie / loss over problems, "
                     "Mann–Whitney U p < 0.05)")
        lines.append("")
        lines.append("| peer | win | tie | loss | problems lost |")
        lines.append("|---|---|---|---|---|")
        summary.setdefault("versus", {})[ours] = {}
        for peer in peers:
            at = a.gp_budget if peer == "optuna_gp" else None
            w = t = l_ = 0
            lost = []
            for p in probs:
                x, y = vals(p, ours, at), vals(p, peer, at)
                if len(x) == 0 or len(y) == 0:
                    continue
                pv = _mwu(x, y)
                if pv < 0.05 and np.median(x) < np.median(y):
                    w += 1
                elif pv < 0.05:
                    l_ += 1
                    lost.append(p)
                else:
                    t += 1
            summary["versus"][ours][peer] = dict(win=w, tie=t, loss=l_, lost=lost)
            lines.append(f"| {peer} | {w} | {t} | {l_} | {', '.join(lost)} |")
        lines.append("")
    # overhead
    lines.append("## Optimizer's own seconds per suggested point (wall − function time) / n")
    lines.append("")
    lines.append("| method | median ms/pt | max ms/pt | runs |")
    lines.append("|---|---|---|---|")
    summary["overhead_ms_per_point"] = {}
    for m in methods:
        o = np.array([r["overhead_per_point"] for r in runs if r["method"] == m]) * 1e3
        if len(o):
            summary["overhead_ms_per_point"][m] = dict(median=float(np.median(o)),
                                                       max=float(o.max()), runs=int(len(o)))
            lines.append(f"| {m} | {np.median(o):.2f} | {o.max():.2f} | {len(o)} |")
    lines.append("")
    inv = [json.loads(x) for x in (out / "invocations.jsonl").read_text().splitlines()] \
        if (out / "invocations.jsonl").exists() else []
    lines.append("## Invocations")
    lines.append("")
    for i in inv:
        if i.get("event") == "start":
            lines.append(f"- started {i['date']}: `{i['command']}` (load "
                         f"{i['loadavg_start'][0]:.2f})")
        else:
            lines.append(f"- ended (started {i['date']}): `{i['command']}` (load "
                         f"{i['loadavg_start'][0]:.2f} → {i['loadavg_end'][0]:.2f}, "
                         f"{i.get('runs_done')} runs)")
    lines.append("")
    lines.append(f"Report: `python -m benchmarks.peers --report` (critic hash {chash}).")
    stem = "summary" if a.critic_hash is None else f"summary_{a.critic_hash}"
    (out / f"{stem}.md").write_text("\n".join(lines) + "\n")
    (out / f"{stem}.json").write_text(json.dumps(summary, indent=1))
    print("\n".join(lines))
    if a.out is not None:
        write_json(a.out, summary, a.provenance)


# ------------------------------------------------------------------ compare
def compare(a) -> int:
    """The runs of ``a.dir`` against the runs of the same name in ``a.compare`` (e.g. the same
    seeded runs made on another machine): per run whether the best-so-far traces are identical
    and the first evaluation where they differ by more than 1e-6 relatively; per (problem,
    method) both medians and the Mann–Whitney U p between the two sets of seeds. Written to
    ``<dir>/compare_<name of the other directory's parent>.json`` and printed."""
    out, other = Path(a.dir), Path(a.compare)
    rows, groups = [], {}
    for f in sorted((out / "runs").glob("*.json")):
        g = other / "runs" / f.name
        if not g.exists():
            continue
        r, o = json.loads(f.read_text()), json.loads(g.read_text())
        x, y = np.asarray(r["trace"], float), np.asarray(o["trace"], float)
        n = min(len(x), len(y))
        rel = np.abs(x[:n] - y[:n]) / np.maximum(np.abs(y[:n]), 1e-300)
        apart = np.flatnonzero(rel > 1e-6)
        rows.append(dict(run=f.name, identical=bool(n == len(x) == len(y) and
                                                    np.array_equal(x, y)),
                         first_apart=int(apart[0]) if apart.size else None,
                         best=r["best"], best_other=o["best"], machine=r.get("machine"),
                         machine_other=o.get("machine")))
        here_best, there_best = groups.setdefault((r["problem"], r["method"]), ([], []))
        here_best.append(r["best"])
        there_best.append(o["best"])
    if not rows:
        error_line("benchmarks.peers", f"no run of {out / 'runs'} is also in {other / 'runs'}")
        return 1
    lines = [f"# {out} against {other}", "",
             f"{sum(r['identical'] for r in rows)} of {len(rows)} runs have identical traces; "
             "first evaluation apart by > 1e-6 (relative): "
             + ", ".join(str(r["first_apart"]) for r in rows), "",
             "| problem | method | seeds | median here | median there | p |", "|---|---|---|---|---|---|"]
    summ = []
    for (pn, m), (b1, b2) in sorted(groups.items()):
        pv = _mwu(np.asarray(b1), np.asarray(b2))
        summ.append(dict(problem=pn, method=m, seeds=len(b1), median=float(np.median(b1)),
                         median_other=float(np.median(b2)), p=pv))
        lines.append(f"| {pn} | {m} | {len(b1)} | {np.median(b1):.4g} | {np.median(b2):.4g} | "
                     f"{pv:.2f} |")
    name = other.resolve().name
    (out / f"compare_{name}.json").write_text(json.dumps(dict(
        here=str(out), there=str(other), runs=rows, groups=summ), indent=1))
    print("\n".join(lines))
    return 0


# ------------------------------------------------------------------ relabel
def relabel(a) -> int:
    """Carry the ``lt_turbo`` / ``lt_cma`` runs of critic hash ``a.relabel`` over to the current
    hash when the code change does not touch their path: ``a.relabel_check`` of them (spread over
    methods, problems and seeds) are re-run with the current code and must give bit-identical
    best-so-far traces; then every run is copied under the current hash with a ``relabelled``
    record (old hash, the runs checked, date; a list, oldest first, after several relabels). ``a.relabel_check`` runs of each method are
    checked. Returns 1 (nothing written) if a trace differs."""
    import torch

    torch.set_num_threads(1)
    out, new = Path(a.dir), critic_hash()
    old = {f: json.loads(f.read_text())
           for f in sorted((out / "runs").glob(f"*__b*__{a.relabel}.json"))}
    old = {f: o for f, o in old.items() if o["method"] in ("lt_turbo", "lt_cma")}
    if not old or new == a.relabel:
        print(f"nothing to relabel: {len(old)} runs of {a.relabel}, current hash {new}")
        return 1
    here = machine()
    elsewhere = {json.dumps(o.get("machine")) for o in old.values()} - {json.dumps(here)}
    if elsewhere:      # a seeded trajectory is reproducible on one kind of CPU only (--compare)
        error_line("benchmarks.peers", f"runs of {a.relabel} were made on another machine "
                   f"({', '.join(sorted(elsewhere))}; here {json.dumps(here)}): their traces "
                   "cannot be checked here; re-run them")
        return 1
    picks = []
    for m in ("lt_turbo", "lt_cma"):      # --relabel-check runs of each, spread over the list
        runs = [f for f in old if f"__{m}__" in f.name]
        picks += runs[:: max(1, len(runs) // max(a.relabel_check, 1))][: a.relabel_check]
    checked = []
    for f in picks:
        o = old[f]
        r = run_method(o["method"], o["problem"], o["seed"], o["budget"], o["batch"], {})
        same = r["trace"] == o["trace"]
        print(f"{o['problem']:14s} {o['method']:9s} s{o['seed']}: "
              f"{'identical' if same else 'DIFFERENT'} (best {r['best']:.6g} vs {o['best']:.6g})",
              flush=True)
        if not same:
            return 1
        checked.append(f.name)
    stamp = datetime.datetime.now(datetime.timezone.utc).isoformat()
    n = 0
    for o in old.values():
        path = run_path(out, o["problem"], o["method"], o["seed"], o["budget"], new)
        if path.exists():
            continue
        prev = o.get("relabelled", [])
        prev = [prev] if isinstance(prev, dict) else prev       # earlier relabels, oldest first
        o["relabelled"] = prev + [{"from": a.relabel, "to": new, "checked": checked,
                                   "date": stamp}]
        o["critic_hash"] = new
        path.write_text(json.dumps(o))
        n += 1
    print(f"relabelled {n} runs {a.relabel} -> {new} ({len(checked)} re-run bit-identical)")
    return 0


def main(argv=None) -> int:
    prov = Provenance(argv, "benchmarks.peers")
    p = bench_parser("benchmarks.peers", description=__doc__,
                     formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--problems", nargs="+", default=list(problems()), choices=list(problems()))
    p.add_argument("--methods", nargs="*", default=ALL_METHODS, choices=ALL_METHODS)
    p.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2, 3, 4])
    p.add_argument("--budget", type=int, default=500)
    p.add_argument("--gp-budget", type=int, default=200)
    p.add_argument("--batch-size", type=int, default=10)
    p.add_argument("--dir", type=out_dir, default=str(ROOT / "results" / "peers"),
                   help="the runs directory (runs/, invocations.jsonl, summaries)")
    p.add_argument("--out", type=out_file, default=None, metavar="FILE.json",
                   help="--report: also write the summary and its provenance to this JSON file")
    p.add_argument("--variant", action="append",
                   help="NAME=JSON: extra latentune run lt_<method>@NAME with these options")
    p.add_argument("--variant-method", default="turbo", choices=["turbo", "cma"])
    p.add_argument("--report", action="store_true")
    p.add_argument("--baseline-hash", default=None,
                   help="also report latentune runs of this critic hash, as 'before:<method>'")
    p.add_argument("--critic-hash", default=None,
                   help="report latentune runs of this critic hash (default: the current code)")
    p.add_argument("--relabel", default=None, metavar="HASH",
                   help="carry lt_turbo/lt_cma runs of this critic hash over to the current one "
                        "after re-running --relabel-check of them bit-identically")
    p.add_argument("--relabel-check", type=int, default=3)
    p.add_argument("--compare", default=None, metavar="DIR",
                   help="compare the runs of --out with the runs of the same name in DIR")
    a = p.parse_args(argv)
    for v in a.variant or []:       # refused here, not a traceback after the runs began
        name, eq, js = v.partition("=")
        try:
            opts = json.loads(js) if eq and name else None
        except json.JSONDecodeError as e:
            p.error(f"--variant {v!r}: the options are not JSON ({e})")
        if not isinstance(opts, dict):
            p.error(f"--variant {v!r}: expected NAME='{{\"option\": value}}'")
        if not (a.report or a.compare or a.relabel):     # the runs' critics take them
            try:
                check_variant(a.variant_method, opts, [problems()[q].dim for q in a.problems],
                              a.budget, a.batch_size)
            except (ValueError, TypeError) as e:    # one line, as benchmarks.transfer's
                error_line("benchmarks.peers", f"--variant {v!r}: {e}")
                return 2
    if a.compare:
        return compare(a)
    if a.relabel:
        return relabel(a)
    a.provenance = prov
    if a.report:
        report(a)
        return 0
    return bench(a)


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.peers"))
