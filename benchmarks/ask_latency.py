"""Wall time of one ``latentune ask`` (a new process: imports, store, critic rebuilt from the
store) on a study with many told trials, with and without the stored critic state.

    python -m benchmarks.ask_latency [--told 1000] [--dim 25] [--repeats 3] [--phase {1,3}]
        [--out FILE.json]

Builds an ask/tell study on a shifted sphere in ``--dim`` dimensions through the Python API
(``Study.ask``/``tell`` in batches of 50 until ``--told`` trials are told), then times
``latentune ask DIR --n 1`` followed by ``tell`` ``--repeats`` times: as it is (the store holds
TuRBO-m's last GP fits, :meth:`Critic.state_dict`) and after deleting that state before each ask
(every ask refits the GPs from scratch). Also times a bare
``python -c "import latentune.critic.turbo"`` (the import floor of any ask).
"""
from __future__ import annotations

import argparse
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
from latentune.pipeline.phases import state_key  # noqa: E402
from latentune.pipeline.store import RunStore  # noqa: E402

from benchmarks.common import Provenance, add_out_arg, finish  # noqa: E402

ENV = dict(os.environ, **thread_env())


def cost(theta: np.ndarray) -> float:
    return float(np.sum((theta - 0.3) ** 2))


def cli_seconds(*args: str) -> float:
    t = time.perf_counter()
    subprocess.run([sys.executable, "-m", "latentune.cli", *args], check=True,
                   capture_output=True, env=ENV)
    return time.perf_counter() - t


def main(argv: list[str] | None = None) -> int:
    prov = Provenance(argv, "benchmarks.ask_latency")
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--told", type=int, default=1000)
    ap.add_argument("--dim", type=int, default=25)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--phase", type=int, choices=(1, 3), default=1,
                    help="3: phase 3 with the default (transfer) strategy, from a 300-trial "
                         "phase-1 source on the same sphere")
    add_out_arg(ap)
    a = ap.parse_args(argv)
    t0 = time.perf_counter()
    root = Path(tempfile.mkdtemp(prefix="lt_asklat_"))
    d = root / "study"
    space = lt.ParameterSpace([f"k{i}" for i in range(a.dim)], [0.0] * a.dim, [1.0] * a.dim)
    kw: dict = {"space": space, "budget": a.told + 4 * a.repeats}     # room for the timed asks
    if a.phase == 3:
        with lt.Study(root / "source", seed=0) as src:
            src.phase1(lt.FunctionSystem(space, cost), 300)
            src.train_latent()
        kw.update(phase=3, latent=root / "source")
    study = lt.Study(d, seed=0)
    told = 0
    while told < a.told:
        for s in study.ask(min(50, a.told - told), **kw):
            study.tell(s.id, cost(np.asarray(s.theta)))
        told = study.store.count(a.phase)
    study.close()
    build_s = time.perf_counter() - t0
    t = time.perf_counter()
    subprocess.run([sys.executable, "-c", "import latentune.critic.turbo, botorch"], check=True,
                   env=ENV)
    import_s = time.perf_counter() - t
    out: dict = {"told": a.told, "dim": a.dim, "phase": a.phase, "build_s": build_s,
                 "import_s": import_s}
    for mode in ("with_state", "without_state"):
        secs = []
        for _ in range(a.repeats):
            if mode == "without_state":
                with RunStore(d) as st:
                    st.set_meta(state_key(a.phase), {})
            secs.append(cli_seconds("ask", str(d), "--json"))
            with RunStore(d) as st:
                tid = st.trials("pending")[0].id
                theta = st.trials_by_id(tid).theta
            cli_seconds("tell", str(d), str(tid), "--cost", repr(cost(theta)))
        out[mode] = {"ask_s": secs, "median_s": float(np.median(secs))}
    rows = [{"stored critic state": mode == "with_state", "ask wall s (per repeat)":
             [round(v, 2) for v in out[mode]["ask_s"]], "median s": out[mode]["median_s"],
             "import floor s": import_s} for mode in ("with_state", "without_state")]
    out["ratio"] = out["without_state"]["median_s"] / out["with_state"]["median_s"]
    finish(a.out, prov, out, rows,
           title=f"`latentune ask` on a phase-{a.phase} study with {a.told} told trials, "
                 f"d = {a.dim}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
