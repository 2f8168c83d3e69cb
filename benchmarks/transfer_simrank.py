"""Does the source *system* itself rank the target's trials? An upper bound for every model
that trusts the source, measured on the stored target trials of ``benchmarks.transfer_models``.

Session 47 found every target model near chance (median Spearman ρ −0.10 to 0.23) at ranking
the default's own later trials, the source model alone included. The source model is a GP on
a few hundred source trials: near the target's incumbent it may simply not know the source. So
here each stored target θ is run on the model system (the source; cheap here, and the
simulator beside a real robot), and that *exact* source cost, with its fall flag, ranks the
trials after each cut t = 5, 10, 20 as the models did (rank scores, falls last; Spearman ρ and
the fall AUC). Any model of the form ``a·source + b`` ranks as the exact source does, so this
is what such a model could reach with a perfect source model; a residual fitted on t target
trials is not included. Beside it, ``local``: a GP (the source model's fitting code, its own
hyperparameters) on the ``LOCAL`` source trials nearest the target's incumbent at the cut (its
best standing trial, else its first): what the source run already holds near where the
target searches, without a new source evaluation.

    python -m benchmarks.transfer_simrank --runs results/transfer/rebuilt/runs \
        --sources runs/transfer_skx \
        --models results/transfer/models/models.json \
        --out results/transfer/models/simrank.json

Pairs every row of ``--models`` (system, gap, seed, trial set, cut) with the exact source's
scores; the table gives, per trial set and cut, the median ρ of the exact source beside the
transfer model's and the source model's, how often the exact source ranks better than the
transfer model (sign test), and the fall AUCs. Bad input is one line on stderr and exit 2."""
from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks import transfer as tr
from benchmarks.common import error_line
from benchmarks.transfer_models import CUTS, SETS, _spearman, emit
from benchmarks.transfer_walk import auc, load_trace


LOCAL = 100


def local_source_rho(src: tuple[np.ndarray, np.ndarray, np.ndarray], X: np.ndarray,
                     y: np.ndarray, f: np.ndarray, t: int) -> float | None:
    """ρ of the local source GP (module docstring) on the target trials t… (rank scores)."""
    import warnings

    from latentune.critic.transfer_model import fit_gp, rank_scores

    Xs, ys, fs = src
    ok = np.flatnonzero(~f[:t])
    inc = X[ok[np.argmin(y[:t][ok])]] if ok.size else X[0]
    near = np.argsort(((Xs - inc) ** 2).sum(1), kind="stable")[:LOCAL]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        gp, _ = fit_gp(Xs[near], rank_scores(ys[near], fs[near]), None)
    return _spearman(gp.mean(X[t:]), rank_scores(y[t:], f[t:]))


def source_outcomes(system: str, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(cost (n,), fell (n,)) of the unit θ ``X`` (n, d) on the model system of ``system``."""
    from latentune.system import evaluate

    model = tr.SYSTEMS[system]["model"]()
    outs = [evaluate(model, x) for x in X]
    return (np.array([float(o.cost) for o in outs]), np.array([bool(o.failed) for o in outs]))


def score(rows: list[dict[str, Any]], runs: Path, sources: Path) -> list[dict[str, Any]]:
    """Each row of transfer_models with ``exact``: the exact source's ρ and AUC at its cut,
    and ``local``: the local source GP's ρ."""
    from latentune.pipeline.baselines import source_trials
    from latentune.critic.transfer_model import rank_scores

    srcs: dict[tuple[str, int], tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
    cache: dict[tuple[str, float, int, str], tuple[np.ndarray, ...]] = {}
    out = []
    for r in rows:
        key = (r["system"], float(r["gap"]), int(r["seed"]), r["set"])
        if key not in cache:
            tr_ = load_trace([runs], key[0], key[1], key[2], SETS[key[3]])
            if tr_ is None or not tr_.get("thetas"):
                raise ValueError(f"no stored trace with θ for {key}")
            X = np.asarray(tr_["thetas"], dtype=float)
            cs, fs = source_outcomes(key[0], X)
            cache[key] = (np.asarray(tr_["costs"], float), np.asarray(tr_["failed"], bool),
                          cs, fs)
            print(f"{key[0]} {key[1]:g} s{key[2]} {key[3]}: source falls {int(fs.sum())}, "
                  f"target falls {int(np.sum(tr_['failed']))}", flush=True)
        y, f, cs, fs = cache[key]
        t = int(r["t"])
        vq, sq = rank_scores(y[t:], f[t:]), rank_scores(cs[t:], fs[t:])
        both = 0 < f[t:].sum() < len(f) - t
        sk = (key[0], key[2])
        if sk not in srcs:
            d = sources / key[0] / f"seed{key[2]}" / "source"
            if not (d / "run.db").is_file():
                raise ValueError(f"no source run at {d}")
            srcs[sk] = source_trials(d)
        X = np.asarray(load_trace([runs], key[0], key[1], key[2], SETS[key[3]])["thetas"], float)
        out.append({**r, "exact": {"rho": _spearman(sq, vq),
                                   "auc": auc(-fs[t:].astype(float), ~f[t:]) if both else None},
                    "local": {"rho": local_source_rho(srcs[sk], X, y, f, t), "auc": None}})
    return out


def table(rows: list[dict[str, Any]]) -> list[str]:
    from scipy.stats import binomtest

    md = ["| set | t | median ρ: exact source | local source GP | transfer model | source model "
          "| exact better / worse than transfer (sign p) | local better / worse than transfer "
          "(sign p) | fall AUC: exact | transfer |",
          "|---|---:|---:|---:|---:|---:|---|---|---:|---:|"]
    for s in SETS:
        for t in CUTS:
            part = [r for r in rows if r["set"] == s and r["t"] == t]
            if not part:
                continue

            def med(m: str, k: str = "rho") -> float:
                v = [r[m][k] for r in part if r[m][k] is not None]
                return float(np.median(v)) if v else float("nan")
            def against(m: str) -> str:
                pairs = [(r[m]["rho"], r["transfer"]["rho"]) for r in part
                         if r[m]["rho"] is not None and r["transfer"]["rho"] is not None]
                up, down = sum(a > b for a, b in pairs), sum(a < b for a, b in pairs)
                p = binomtest(up, up + down).pvalue if up + down else 1.0
                return f"{up} / {down} ({p:.2g})"
            md.append(f"| {s} | {t} | {med('exact'):.3f} | {med('local'):.3f} | "
                      f"{med('transfer'):.3f} | {med('source'):.3f} | {against('exact')} | "
                      f"{against('local')} | {med('exact', 'auc'):.3f} | "
                      f"{med('transfer', 'auc'):.3f} |")
    return md


def main(argv: list[str] | None = None) -> int:
    from benchmarks.common import bench_parser, out_file
    ap = bench_parser("benchmarks.transfer_simrank", description=__doc__.splitlines()[0])
    ap.add_argument("--runs", required=True)
    ap.add_argument("--sources", required=True, help="SYSTEM/seed<s>/source run directories")
    ap.add_argument("--models", required=True, help="transfer_models' output (its rows)")
    ap.add_argument("--systems", nargs="*", default=None)
    ap.add_argument("--out", type=out_file, default=None, metavar="FILE.json")
    a = ap.parse_args(sys.argv[1:] if argv is None else argv)
    try:
        if not Path(a.runs).is_dir():
            raise ValueError(f"no such directory: {a.runs}")
        rows = json.loads(Path(a.models).read_text())["rows"]
        if a.systems:
            unknown = set(a.systems) - set(tr.SYSTEMS)
            if unknown:
                raise ValueError(f"unknown system(s) {sorted(unknown)}")
            rows = [r for r in rows if r["system"] in a.systems]
        if not rows:
            raise ValueError("no rows for those systems in --models")
        rows = score(rows, Path(a.runs), Path(a.sources))
    except (OSError, ValueError, KeyError, json.JSONDecodeError) as e:
        error_line("benchmarks.transfer_simrank", e)
        return 2
    emit(rows, table(rows), a.out, with_md=True)
    return 0


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.transfer_simrank"))
