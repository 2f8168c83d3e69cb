"""Wall time of ``latentune ask`` and ``latentune tell``, each a new process as the person at the
robot runs them, on a study with many told trials.

    python -m benchmarks.ask_latency [--told 1000] [--dim 25] [--repeats 8] [--phase {1,3}]
        [--out FILE.json]

Builds an ask/tell study on a shifted sphere in ``--dim`` dimensions through the Python API
(``Study.ask``/``tell`` in batches of 50 until ``--told`` trials are told; phase 3: the default
strategy, transfer, from a 300-trial phase-1 source on the same sphere), then runs ``latentune
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

from benchmarks.common import Provenance, add_out_arg, finish  # noqa: E402

ENV = dict(os.environ, **thread_env())


def cost(theta: np.ndarray) -> float:
    return float(np.sum((np.asarray(theta) - 0.3) ** 2))


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


def main(argv: list[str] | None = None) -> int:
    prov = Provenance(argv, "benchmarks.ask_latency")
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--told", type=int, default=1000)
    ap.add_argument("--dim", type=int, default=25)
    ap.add_argument("--repeats", type=int, default=8, help="ask/tell pairs timed per mode")
    ap.add_argument("--phase", type=int, choices=(1, 3), default=1,
                    help="3: phase 3 with the default (transfer) strategy, from a 300-trial "
                         "phase-1 source on the same sphere")
    add_out_arg(ap)
    a = ap.parse_args(argv)
    t0 = time.perf_counter()
    root = Path(tempfile.mkdtemp(prefix="lt_asklat_"))
    d = root / "study"
    space = lt.ParameterSpace([f"k{i}" for i in range(a.dim)], [0.0] * a.dim, [1.0] * a.dim)
    kw: dict = {"space": space, "budget": a.told + 8 * a.repeats}     # room for the timed asks
    if a.phase == 3:
        with lt.Study(root / "source", seed=0) as src:
            src.phase1(lt.FunctionSystem(space, cost), 300)
            src.train_latent()
        kw.update(phase=3, latent=root / "source")
    study = lt.Study(d, seed=0)
    told = 0
    while told < a.told:
        for s in study.ask(min(50, a.told - told), **kw):
            study.tell(s.id, cost(s.theta))
        told = study.store.count(a.phase)
    study.close()
    build_s = time.perf_counter() - t0
    out: dict = {"told": a.told, "dim": a.dim, "phase": a.phase, "build_s": build_s,
                 "cli_import_s": python_seconds("import latentune.cli"),
                 "critic_import_s": python_seconds("import latentune.critic.turbo, botorch")}
    out["load_before"] = os.getloadavg()
    for mode in ("prepared", "cold"):
        asks, tells = [], []
        for _ in range(a.repeats):
            if mode == "cold":
                with lt.Study(d) as st:
                    n_open = len(st.store.trials("queued")) + len(st.store.trials("pending"))
                    for sugg in st.ask(n_open) if n_open else []:
                        st.tell(sugg.id, cost(sugg.theta))
                    st.store.delete_meta(NEXT_KEY)
            s, text = cli_seconds("ask", str(d), "--json")
            asks.append(s)
            (sugg,) = json.loads(text)
            s, _ = cli_seconds("tell", str(d), str(sugg["id"]), "--cost",
                               repr(cost(sugg["theta"])))
            tells.append(s)
        out[mode] = {"ask": stats(asks), "tell": stats(tells)}
    out["load_after"] = os.getloadavg()
    rows = [{"mode": mode, "ask median s": out[mode]["ask"]["median_s"],
             "ask max s": out[mode]["ask"]["max_s"],
             "tell median s": out[mode]["tell"]["median_s"],
             "tell max s": out[mode]["tell"]["max_s"],
             "ask s (per repeat)": [round(v, 2) for v in out[mode]["ask"]["s"]],
             "tell s (per repeat)": [round(v, 2) for v in out[mode]["tell"]["s"]]}
            for mode in ("prepared", "cold")]
    finish(a.out, prov, out, rows,
           title=f"`latentune ask` / `tell` on a phase-{a.phase} study with {a.told} told "
                 f"trials, d = {a.dim} (import floors: latentune.cli {out['cli_import_s']:.2f} s, "
                 f"the critic {out['critic_import_s']:.2f} s; load {out['load_before'][0]:.1f} "
                 f"to {out['load_after'][0]:.1f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
