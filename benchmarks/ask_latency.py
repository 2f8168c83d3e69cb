"""Wall time of ``latentune ask`` and ``latentune tell``, each a new process as the person at the
robot runs them, on a study with many told trials.

    python -m benchmarks.ask_latency [--told 1000] [--dim 25] [--repeats 8] [--phase {1,3}]
        [--strategy {transfer,plain}] [--max-fall-prob P] [--out FILE.json]

Builds an ask/tell study on a shifted sphere in ``--dim`` dimensions through the Python API
(``Study.ask``/``tell`` in batches of 50 until ``--told`` trials are told; phase 3: the
``--strategy``, by default transfer, from a 300-trial phase-1 source on the same sphere), then
runs ``latentune
ask DIR --json`` followed by ``latentune tell DIR ID --cost C`` ``--repeats`` times, timing each:

* ``prepared``: as the person runs them. An ask leases a queued suggestion or the batch the
  tell before it prepared (:mod:`latentune.pipeline.asktell`); the tell that ends a batch asks
  the critic for the next one.
* ``cold``: before each timed ask, the open suggestions are told through the API and the
  prepared batch is deleted, so every timed ask builds the critic from the stored rows and its
  saved state (what an ask costs when the prepared batch is stale, or was never made).

Also times ``python -c "import latentune.cli"`` and ``python -c "import latentune.critic.turbo,
botorch"`` (the import floor of building the critic), and records the load average around the
timed calls.

The fall model's overhead (``--max-fall-prob P``): the cost has falls (:func:`outcome`: a trial
with ``θ₀ + θ₁ >`` :data:`FALL_SUM` on the unit box fails, cost :data:`FALL_COST`; told with
``--failed``), and two studies of the same seed are built in the same run, ``plain`` and ``fall
model`` (``max_fall_prob=P``; phase 3: both from one source run on the same cost, the fall
model's prior its trials; ``--strategy plain`` only: the transfer strategy always screens with
a fall model of its own), each to ``--told`` trials of its own. Their timed calls are
interleaved (each repeat times both, in alternating order), and the output adds the ratio fall
model / plain of each median (and of the longest tell: the one that ends a batch and asks the
critic).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from latentune.threads import one_thread_env, thread_env

one_thread_env()

import numpy as np  # noqa: E402

import latentune as lt  # noqa: E402
from latentune.pipeline.asktell import NEXT_KEY  # noqa: E402

from benchmarks.common import Provenance, add_out_arg, bench_parser, finish  # noqa: E402

ENV = dict(os.environ, **thread_env())
FALL_SUM = 1.1
"""A trial of the cost with falls fails when ``θ₀ + θ₁`` exceeds this (unit box; the sphere's
minimum, 0.3 in every entry, is stable)."""
FALL_COST = 100.0
"""The cost told with a failed trial (above every stable cost of the sphere on the unit box)."""
STUDIES = ("plain", "fall model")


def cost(theta: np.ndarray) -> float:
    return float(np.sum((np.asarray(theta) - 0.3) ** 2))


def outcome(theta: np.ndarray, falls: bool) -> tuple[float, bool]:
    """(cost, failed) of ``theta``: the sphere, or with ``falls`` :data:`FALL_COST` and failed
    where ``θ₀ + θ₁ >`` :data:`FALL_SUM`."""
    theta = np.asarray(theta, dtype=float)
    if falls and theta[0] + theta[1] > FALL_SUM:
        return FALL_COST, True
    return cost(theta), False


def falling_cost(theta: np.ndarray) -> tuple[float, bool]:
    """:func:`outcome` with falls, as a FunctionSystem's function (the phase-3 source)."""
    return outcome(theta, True)


def cli_seconds(*args: str) -> tuple[float, str]:
    """(wall seconds, stdout) of ``latentune ARGS`` in a new process."""
    t = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "latentune.cli", *args], check=True,
                       capture_output=True, text=True, env=ENV)
    return time.perf_counter() - t, r.stdout


def python_seconds(code: str) -> float:
    t = time.perf_counter()
    subprocess.run([sys.executable, "-c", code], check=True, env=ENV)
    return time.perf_counter() - t


def stats(secs: list[float]) -> dict:
    return {"s": secs, "median_s": float(np.median(secs)), "max_s": float(np.max(secs))}


def build(d: Path, a: argparse.Namespace, kw: dict, falls: bool) -> dict:
    """Ask and tell the study ``d`` through the API to ``a.told`` trials (batches of 50);
    return its build time and how many of its trials failed."""
    t0 = time.perf_counter()
    study = lt.Study(d, seed=0)
    told = 0
    while told < a.told:
        for s in study.ask(min(50, a.told - told), **kw):
            c, fell = outcome(s.theta, falls)
            study.tell(s.id, c, failed=fell)
        told = study.store.count(a.phase)
    n_fell = int(study.store.fell(a.phase).sum())
    study.close()
    return {"build_s": time.perf_counter() - t0, "n_fell": n_fell}


def time_pair(d: Path, mode: str, falls: bool) -> tuple[float, float]:
    """Seconds of one ``latentune ask DIR --json`` and of the ``tell`` of its suggestion (see
    the module docstring for ``mode``)."""
    if mode == "cold":
        with lt.Study(d) as st:
            n_open = len(st.store.trials("queued")) + len(st.store.trials("pending"))
            for sugg in st.ask(n_open) if n_open else []:
                c, fell = outcome(sugg.theta, falls)
                st.tell(sugg.id, c, failed=fell)
            st.store.delete_meta(NEXT_KEY)
    ask_s, text = cli_seconds("ask", str(d), "--json")
    (sugg,) = json.loads(text)
    c, fell = outcome(np.array(sugg["theta"]), falls)
    tell_s, _ = cli_seconds("tell", str(d), str(sugg["id"]), "--cost", repr(c),
                            *(["--failed"] if fell else []))
    return ask_s, tell_s


def main(argv: list[str] | None = None) -> int:
    prov = Provenance(argv, "benchmarks.ask_latency")
    ap = bench_parser("benchmarks.ask_latency", description=__doc__.splitlines()[0])
    ap.add_argument("--told", type=int, default=1000)
    ap.add_argument("--dim", type=int, default=25)
    ap.add_argument("--repeats", type=int, default=8, help="ask/tell pairs timed per mode")
    ap.add_argument("--phase", type=int, choices=(1, 3), default=1,
                    help="3: phase 3 with the default (transfer) strategy, from a 300-trial "
                         "phase-1 source on the same sphere")
    ap.add_argument("--strategy", choices=("transfer", "plain"), default="transfer",
                    help="phase 3's strategy")
    ap.add_argument("--max-fall-prob", type=float, default=None, metavar="P",
                    help="compare a study with the fall model (this max_fall_prob) and one "
                         "without it, on a cost with falls")
    add_out_arg(ap)
    a = ap.parse_args(argv)
    falls = a.max_fall_prob is not None
    if falls and a.phase == 3 and a.strategy == "transfer":
        ap.error("the transfer strategy screens with its own fall model in every study: "
                 "compare with --strategy plain")
    root = Path(tempfile.mkdtemp(prefix="lt_asklat_"))
    space = lt.ParameterSpace([f"k{i}" for i in range(a.dim)], [0.0] * a.dim, [1.0] * a.dim)
    kw: dict = {"space": space, "budget": a.told + 8 * a.repeats}     # room for the timed asks
    t0 = time.perf_counter()
    if a.phase == 3:
        with lt.Study(root / "source", seed=0) as src:
            src.phase1(lt.FunctionSystem(space, falling_cost if falls else cost), 300)
            src.train_latent()
        kw.update(phase=3, latent=root / "source", strategy=a.strategy)
    source_s = time.perf_counter() - t0
    runs = {name: root / name.replace(" ", "_") for name in (STUDIES if falls else ("study",))}
    built = {name: build(d, a, {**kw, **({"max_fall_prob": a.max_fall_prob}
                                         if name == "fall model" else {})}, falls)
             for name, d in runs.items()}
    out: dict = {"told": a.told, "dim": a.dim, "phase": a.phase,
                 **({"strategy": a.strategy} if a.phase == 3 else {}),
                 "cli_import_s": python_seconds("import latentune.cli"),
                 "critic_import_s": python_seconds("import latentune.critic.turbo, botorch")}
    if falls:
        out.update(max_fall_prob=a.max_fall_prob,
                   falls=f"θ0 + θ1 > {FALL_SUM} on the unit box fails, cost {FALL_COST}",
                   source_s=source_s)
    else:
        out["build_s"] = source_s + built["study"]["build_s"]
    out["load_before"] = os.getloadavg()
    secs = {name: {mode: {"ask": [], "tell": []} for mode in ("prepared", "cold")}
            for name in runs}
    for mode in ("prepared", "cold"):
        for r in range(a.repeats):
            for name in (list(runs) if r % 2 == 0 else list(runs)[::-1]):
                ask_s, tell_s = time_pair(runs[name], mode, falls)
                secs[name][mode]["ask"].append(ask_s)
                secs[name][mode]["tell"].append(tell_s)
    out["load_after"] = os.getloadavg()
    timed = {name: {mode: {k: stats(v) for k, v in secs[name][mode].items()}
                    for mode in ("prepared", "cold")} for name in runs}
    rows = [{**({"study": name} if falls else {}), "mode": mode,
             "ask median s": t[mode]["ask"]["median_s"], "ask max s": t[mode]["ask"]["max_s"],
             "tell median s": t[mode]["tell"]["median_s"],
             "tell max s": t[mode]["tell"]["max_s"],
             "ask s (per repeat)": [round(v, 2) for v in t[mode]["ask"]["s"]],
             "tell s (per repeat)": [round(v, 2) for v in t[mode]["tell"]["s"]]}
            for name, t in timed.items() for mode in ("prepared", "cold")]
    head = (f"`latentune ask` / `tell` on a phase-{a.phase} study "
            + (f"({a.strategy}) " if a.phase == 3 else "") + f"with {a.told} told "
            f"trials, d = {a.dim} (import floors: latentune.cli {out['cli_import_s']:.2f} s, "
            f"the critic {out['critic_import_s']:.2f} s; load {out['load_before'][0]:.1f} "
            f"to {out['load_after'][0]:.1f})")
    if not falls:
        out.update(timed["study"])
        finish(a.out, prov, out, rows, title=head)
        return 0
    out["studies"] = {name: {**built[name], **timed[name]} for name in runs}
    f, p = timed["fall model"], timed["plain"]
    out["ratio_fall_model_over_plain"] = {
        f"{mode} {k} {stat}": f[mode][k][f"{stat}_s"] / p[mode][k][f"{stat}_s"]
        for mode in ("prepared", "cold") for k in ("ask", "tell") for stat in ("median", "max")}
    rows.append({"study": "ratio fall model / plain", "mode": "prepared",
                 "ask median s": out["ratio_fall_model_over_plain"]["prepared ask median"],
                 "tell median s": out["ratio_fall_model_over_plain"]["prepared tell median"],
                 "tell max s": out["ratio_fall_model_over_plain"]["prepared tell max"]})
    rows.append({"study": "ratio fall model / plain", "mode": "cold",
                 "ask median s": out["ratio_fall_model_over_plain"]["cold ask median"],
                 "tell median s": out["ratio_fall_model_over_plain"]["cold tell median"],
                 "tell max s": out["ratio_fall_model_over_plain"]["cold tell max"]})
    finish(a.out, prov, out, rows,
           title=f"{head}; with and without the fall model (max_fall_prob "
                 f"{a.max_fall_prob:g}), failed trials: "
                 + ", ".join(f"{n} {built[n]['n_fell']}" for n in runs))
    return 0

if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.ask_latency"))
