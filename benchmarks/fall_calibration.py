"""How well the fall classifier predicts the target's falls: replayed on finished reality-gap runs.

For every run store given (direct searches on θ made by ``benchmarks.reality_gap``, without
the fall-aware option, so their points were not screened), the trials are replayed batch by
batch: before batch ``b`` a :class:`~latentune.critic.fall_model.GPFallModel` is fitted on the
trials before it (the manual θ's trial, phase 0, and batches ``< b``) and, for the variants that use it, on the
source run's phase-1 trials as its prior; it then predicts the fall probability of each trial of
batch ``b``. The pooled predictions against what happened say whether any threshold could have
avoided the falls, and at what price in trials that would not have fallen.

Variants (``--variants``):

* ``prior``: the source's phase-1 trials as prior (FallAware's classifier in a direct search);
* ``target``: no prior, the target's trials only.

Per variant: the number of predicted trials (batches after the first one whose training data
hold both classes), falls among them, the ROC AUC of the predicted probability, and for each
threshold ``P`` the share of falls that ``p > P`` would have screened out (``caught``) and the
share of non-falls screened with them (``lost``).

    python -m benchmarks.fall_calibration --source results/a1/a1-jump \
        --runs /work/runs/rg_a1_jump/hard_direct_s* [--out FILE.json]
"""
from __future__ import annotations

import sys
from pathlib import Path

from latentune.threads import one_thread_env

one_thread_env()

import numpy as np  # noqa: E402

from latentune.critic.fall_model import GPFallModel  # noqa: E402
from latentune.constants import Phase  # noqa: E402
from latentune.pipeline.store import RunStore  # noqa: E402

from benchmarks.common import Provenance, add_out_arg, bench_parser, cli_main, finish  # noqa: E402

THRESHOLDS = (0.1, 0.2, 0.3, 0.5)
VARIANTS = ("prior", "target")


def trials(run: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """(θ (n, d), fell (n,), batch index (n,), batch size) of a direct run: the manual θ's trial
    (phase 0, batch -1) and the tuning phase's trials in order."""
    with RunStore(run, create=False) as st:
        cfg = st.meta().get("config", {})
        start = st.rows(Phase.MANUAL)
        rows = st.rows(Phase.PHASE1) or st.rows(Phase.PHASE3)
    bs = int((cfg.get("phase1") or cfg.get("phase3") or {}).get("batch_size", 4))
    X = np.array([r.theta for r in start + rows])
    fell = np.array([r.fell for r in start + rows], dtype=bool)
    batch = np.concatenate([np.full(len(start), -1), np.arange(len(rows)) // bs])
    return X, fell, batch, bs


def auc(p: np.ndarray, y: np.ndarray) -> float:
    """ROC AUC of scores ``p`` for labels ``y`` (ties count one half); NaN with one class."""
    pos, neg = p[y], p[~y]
    if not len(pos) or not len(neg):
        return float("nan")
    gt = (pos[:, None] > neg[None, :]).sum() + 0.5 * (pos[:, None] == neg[None, :]).sum()
    return float(gt / (len(pos) * len(neg)))


def replay(X: np.ndarray, fell: np.ndarray, batch: np.ndarray, variant: str,
           prior: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """(p, fell) of every trial predicted before its batch by ``variant``."""
    ps, ys = [], []
    for b in range(int(batch.max()) + 1):
        train, test = batch < b, batch == b
        clf = GPFallModel(X.shape[1])
        if variant != "target":
            clf.set_prior(*prior)
        if not clf.fit(X[train], fell[train]):
            continue
        ps.append(clf.p_fall(X[test]))
        ys.append(fell[test])
    if not ps:
        return np.zeros(0), np.zeros(0, dtype=bool)
    return np.concatenate(ps), np.concatenate(ys)


def main(argv: list[str] | None = None) -> int:
    prov = Provenance(argv, "benchmarks.fall_calibration")
    ap = bench_parser("benchmarks.fall_calibration", description=__doc__.splitlines()[0])
    ap.add_argument("--source", required=True, help="the source run (its phase 1 is the prior)")
    ap.add_argument("--runs", nargs="+", required=True, help="run directories of direct searches")
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=VARIANTS)
    add_out_arg(ap)
    a = ap.parse_args(argv)
    with RunStore(Path(a.source), create=False) as st:
        src = st.rows(Phase.PHASE1)
    prior = (np.array([r.theta for r in src]), np.array([r.fell for r in src], dtype=bool))
    res = {"source": a.source, "runs": a.runs,
           "prior": {"trials": int(len(prior[1])), "falls": int(prior[1].sum())},
           "variants": {}}
    data = [trials(Path(r)) for r in a.runs]
    for v in a.variants:
        P, Y = [], []
        for X, fell, batch, _ in data:
            p, y = replay(X, fell, batch, v, prior)
            P.append(p)
            Y.append(y)
        p, y = np.concatenate(P), np.concatenate(Y)
        row = {"predicted": int(len(y)), "falls": int(y.sum()), "auc": auc(p, y),
               "p_median_falls": float(np.median(p[y])) if y.any() else None,
               "p_median_stable": float(np.median(p[~y])) if (~y).any() else None,
               "thresholds": {str(t): {"caught": float((p[y] > t).mean()) if y.any() else None,
                                       "lost": float((p[~y] > t).mean()) if (~y).any() else None}
                              for t in THRESHOLDS}}
        res["variants"][v] = row
    rows = [{"variant": v, "predicted": r["predicted"], "falls": r["falls"], "AUC": r["auc"],
             "median p (falls)": r["p_median_falls"], "median p (stable)": r["p_median_stable"],
             **{f"P={t} caught / lost": "–" if r["thresholds"][str(t)]["caught"] is None else
                f"{r['thresholds'][str(t)]['caught']:.2f} / {r['thresholds'][str(t)]['lost'] or 0:.2f}"
                for t in THRESHOLDS}}
            for v, r in res["variants"].items()]
    finish(a.out, prov, res, rows, title=f"fall classifier replayed on {len(a.runs)} runs")
    return 0


if __name__ == "__main__":
    sys.exit(cli_main(main, "benchmarks.fall_calibration"))
