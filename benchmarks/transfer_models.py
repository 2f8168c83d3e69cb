"""Which model of the target ranks its next trials best? The transfer critic's cost and fall
models against the ones the issue names (a multi-task GP, a ranking-weighted ensemble) and a
target-only GP, on the stored target trials, one prequential cut at a time.

    python -m benchmarks.transfer_models --sources runs/transfer_skx \
        --runs results/transfer/rebuilt/runs --seeds 0 1 2 3 4 \
        --systems arm chain hopper springs --out results/transfer/models/models_a.json
    (and zones quadrotor vehicle cartpole into models_b.json), then
    python -m benchmarks.transfer_models --merge results/transfer/models/models_{a,b}.json

For each target (system, gap) and seed: the source run (``--sources``: ``SYSTEM/seed<s>/source``,
as ``benchmarks.transfer run`` makes it) and a stored run of 40 target trials (``--runs``; the
default's own trials, and TPE's, which no model here chose). Each model is given the source and
the target's first t trials (t = 5, 10, 20) and predicts the remaining 40 − t:

- ``transfer``: the default critic's target models (:meth:`~latentune.critic.transfer.Transfer.
  models`: the source cost model's mean, scaled, plus a residual GP on the target's rank
  scores; the fall model built the same way on the fall flags);
- ``source``: the source models alone (what the zero-shot θ trusts);
- ``target``: a Matérn-5/2 ARD GP on the target's t trials alone (the source's fitting code);
- ``mtgp``: BoTorch's ``MultiTaskGP`` (ICM over {source, target}) on every source trial and the
  t target trials, rank scores of each task;
- ``rgpe``: the ranking-weighted ensemble of the source GP and the target GP (Feurer et al.):
  each model's weight is the share of 256 posterior samples at the target's t trials (the
  target GP's leave-one-out) where its ranking loss is the lowest.

Scores per cut: Spearman's ρ of the predicted cost (mean) against the rank scores of the
remaining trials (falls ranked last), and, where both classes remain, the AUC of the predicted
fall probability for the fall flags (``transfer``, ``source``, ``target``). Printed: per model,
trial set and t, the median over targets × seeds and how often it beats ``transfer``. Bad input
is one line on stderr and exit 2."""
from __future__ import annotations

import json
import sys
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks import transfer as tr
from benchmarks.common import error_line
from benchmarks.transfer_walk import auc, load_trace

CUTS = (5, 10, 20)
MODELS = ("transfer", "source", "target", "mtgp", "rgpe")
SETS = {"default": tr.DEFAULT_METHOD, "tpe": "tpe"}
_SAMPLES = 256


def _spearman(a: np.ndarray, b: np.ndarray) -> float | None:
    from scipy.stats import spearmanr

    if len(a) < 3 or np.ptp(a) == 0 or np.ptp(b) == 0:
        return None
    return float(spearmanr(a, b).statistic)


def _mtgp_mean(Xs: np.ndarray, zs: np.ndarray, Xt: np.ndarray, vt: np.ndarray,
               Xq: np.ndarray) -> np.ndarray:
    """BoTorch ``MultiTaskGP`` (task 0 the source, 1 the target) fitted by marginal likelihood;
    its posterior mean (m,) of the target task at ``Xq`` (m, d)."""
    import torch
    from botorch.fit import fit_gpytorch_mll
    from botorch.models import MultiTaskGP
    from gpytorch.mlls import ExactMarginalLogLikelihood

    X = np.vstack([np.hstack([Xs, np.zeros((len(Xs), 1))]),
                   np.hstack([Xt, np.ones((len(Xt), 1))])])
    Y = np.concatenate([zs, vt])[:, None]
    m = MultiTaskGP(torch.as_tensor(X), torch.as_tensor(Y), task_feature=-1, output_tasks=[1])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit_gpytorch_mll(ExactMarginalLogLikelihood(m.likelihood, m))
    with torch.no_grad():
        q = torch.as_tensor(np.hstack([Xq, np.ones((len(Xq), 1))]))
        return m.posterior(q).mean.numpy().reshape(-1)


def _rgpe_weights(src: Any, tgt: Any, Xt: np.ndarray, vt: np.ndarray,
                  rng: np.random.Generator) -> tuple[float, float]:
    """(source, target) weights: the share of samples in which each model's ranking loss on
    the target's trials is the lowest (ties split); the target GP's samples leave each trial
    out."""
    from scipy.linalg import cho_solve

    n = len(vt)
    f_s = rng.normal(src.mean(Xt), np.sqrt(src.variance(Xt) + 1e-9), size=(_SAMPLES, n))
    Kinv = cho_solve((tgt.chol, True), np.eye(n))
    d = np.diag(Kinv)
    loo_mu = vt - tgt.alpha / d                     # closed-form leave-one-out (fixed hypers)
    f_t = rng.normal(loo_mu, np.sqrt(1.0 / d), size=(_SAMPLES, n))
    sign = np.sign(vt[:, None] - vt[None, :])

    def loss(f: np.ndarray) -> np.ndarray:
        return (np.sign(f[:, :, None] - f[:, None, :]) != sign[None]).sum((1, 2)) / 2

    ls, lt = loss(f_s), loss(f_t)
    w_s = float(np.mean((ls < lt) + 0.5 * (ls == lt)))
    return w_s, 1.0 - w_s


def score_cut(src_rows: tuple[np.ndarray, np.ndarray, np.ndarray], hypers: dict[str, Any],
              seed: int, X: np.ndarray, y: np.ndarray, fell: np.ndarray, t: int,
              models: tuple[str, ...] = MODELS) -> dict[str, dict[str, float | None]]:
    """Each model's scores on trials t… of the target trials (X (40, d), y, fell) given the
    source and trials …t − 1: ``{"rho": …, "auc": …}`` per model (None where undefined)."""
    from latentune.critic.transfer import Transfer
    from latentune.critic.transfer_model import fit_gp, rank_scores

    Xt, yt, ft = X[:t], y[:t], fell[:t]
    Xq, yq, fq = X[t:], y[t:], fell[t:]
    vq = rank_scores(yq, fq)
    cr = Transfer(src_rows, None, None, seed=seed)
    cr.load_state_dict({"source_hypers": hypers})
    cr.tell(Xt, yt, fell=ft)
    cost_m, fall_m = cr.models()
    sm = cr.source_model()
    vt = rank_scores(yt, ft)
    out: dict[str, dict[str, float | None]] = {}
    pred: dict[str, np.ndarray] = {}
    fallp: dict[str, np.ndarray] = {}
    pred["transfer"] = cost_m.mean_cov(Xq, with_cov=False)[0]
    fallp["transfer"] = fall_m.mean_cov(Xq, with_cov=False)[0]
    pred["source"] = sm.cost(Xq)
    fallp["source"] = sm.fall_prob(Xq)
    tgt = None
    if {"target", "rgpe"} & set(models):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            tgt, _ = fit_gp(Xt, vt, None)
            tfall, _ = fit_gp(Xt, ft.astype(float), None) if 0 < ft.sum() < t else (None, None)
        pred["target"] = tgt.mean(Xq)
        fallp["target"] = tfall.mean(Xq) if tfall is not None else np.full(len(Xq), ft.mean())
    if "mtgp" in models:
        Xs, ys, fs = cr.source_rows()
        pred["mtgp"] = _mtgp_mean(Xs, rank_scores(ys, fs), Xt, vt, Xq)
    if "rgpe" in models:
        w_s, w_t = _rgpe_weights(sm.cost_gp, tgt, Xt, vt, np.random.default_rng([seed, t]))
        pred["rgpe"] = w_s * sm.cost(Xq) + w_t * tgt.mean(Xq)
        out["rgpe_weight_source"] = {"w": w_s}
    both = 0 < fq.sum() < len(fq)
    for m in models:
        out[m] = {"rho": _spearman(pred[m], vq),
                  "auc": (auc(-fallp[m], ~fq) if both and m in fallp else None)}
    return out


def run(sources: Path, runs: Path, seeds: list[int], systems: list[str] | None,
        cuts: tuple[int, ...] = CUTS) -> list[dict[str, Any]]:
    """One row per (system, gap, seed, trial set, cut) with every model's scores."""
    from latentune.pipeline.baselines import source_trials

    rows = []
    for sysdir in sorted(p for p in runs.iterdir() if p.is_dir()):
        if systems and sysdir.name not in systems:
            continue
        for gapdir in sorted(sysdir.glob("gap*")):
            gap = float(gapdir.name[3:])
            for s in seeds:
                src = sources / sysdir.name / f"seed{s}" / "source"
                if not (src / "run.db").is_file():
                    raise ValueError(f"no source run at {src} (benchmarks.transfer run makes it)")
                rows_s = source_trials(src)
                hypers = tr.source_hypers(src, s)
                for set_name, method in SETS.items():
                    r = load_trace([runs], sysdir.name, gap, s, method)
                    if r is None or not r.get("thetas"):
                        continue
                    X = np.asarray(r["thetas"], dtype=float)
                    y, f = np.asarray(r["costs"], float), np.asarray(r["failed"], bool)
                    for t in cuts:
                        sc = score_cut(rows_s, hypers, s, X, y, f, t)
                        rows.append({"system": sysdir.name, "gap": gap, "seed": s,
                                     "set": set_name, "t": t, **sc})
                        print(f"{sysdir.name} {gap:g} s{s} {set_name} t={t}: " + ", ".join(
                            f"{m} {sc[m]['rho']:.2f}" if sc[m]["rho"] is not None else f"{m} -"
                            for m in MODELS), flush=True)
    return rows


def table(rows: list[dict[str, Any]]) -> list[str]:
    """Per trial set and cut: each model's median ρ (and AUC) over targets × seeds, and on how
    many cuts it ranks better than ``transfer`` (ρ higher) / worse, with a two-sided sign test."""
    from scipy.stats import binomtest

    out = ["| set | t | model | median ρ | better / worse than transfer (sign test p) | "
           "median fall AUC |", "|---|---:|---|---:|---|---:|"]
    for set_name in SETS:
        for t in CUTS:
            part = [r for r in rows if r["set"] == set_name and r["t"] == t]
            if not part:
                continue
            for m in MODELS:
                rho = [r[m]["rho"] for r in part if r[m]["rho"] is not None]
                au = [r[m]["auc"] for r in part if r[m]["auc"] is not None]
                pairs = [(r[m]["rho"], r["transfer"]["rho"]) for r in part
                         if r[m]["rho"] is not None and r["transfer"]["rho"] is not None]
                up, down = sum(a > b for a, b in pairs), sum(a < b for a, b in pairs)
                bw = "" if m == "transfer" or not up + down else \
                    f"{up} / {down} ({binomtest(up, up + down).pvalue:.2g})"
                out.append(f"| {set_name} | {t} | {m} | "
                           f"{np.median(rho) if rho else float('nan'):.3f} | {bw} | "
                           f"{np.median(au) if au else float('nan'):.3f} |")
    return out


def main(argv: list[str] | None = None) -> int:
    from benchmarks.common import bench_parser, out_file
    ap = bench_parser("benchmarks.transfer_models", description=__doc__.splitlines()[0])
    ap.add_argument("--sources")
    ap.add_argument("--runs")
    ap.add_argument("--merge", nargs="+", default=None, metavar="JSON",
                    help="no new cuts: the table of the rows stored in these outputs, together")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    ap.add_argument("--systems", nargs="*", default=None)
    ap.add_argument("--out", type=out_file, default=None, metavar="FILE.json")
    a = ap.parse_args(sys.argv[1:] if argv is None else argv)
    try:
        if a.merge:
            if a.sources or a.runs:
                raise ValueError("--merge reads stored rows: no --sources or --runs with it")
            rows = [r for f in a.merge for r in json.loads(Path(f).read_text())["rows"]]
        else:
            for p in (a.sources, a.runs):
                if p is None or not Path(p).is_dir():
                    raise ValueError(f"no such directory: {p} (--sources and --runs, or --merge)")
            rows = run(Path(a.sources), Path(a.runs), a.seeds, a.systems)
        if not rows:
            raise ValueError("no stored target run with its θ for those systems and seeds")
    except (OSError, ValueError, KeyError) as e:
        error_line("benchmarks.transfer_models", e)
        return 2
    emit(rows, table(rows), a.out)
    return 0


def emit(rows: list[dict[str, Any]], md: list[str], out: str | Path | None,
         with_md: bool = False) -> None:
    """Print the table ``md``; with ``out``, write ``{"rows", "table"}`` there as JSON (and,
    ``with_md``, the table beside it as ``.md``)."""
    print("\n".join(md))
    if out:
        Path(out).parent.mkdir(parents=True, exist_ok=True)
        Path(out).write_text(json.dumps({"rows": rows, "table": md}, indent=1))
        if with_md:
            Path(out).with_suffix(".md").write_text("\n".join(md) + "\n")


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.transfer_models"))
