"""Why the transfer phase 3 falls: every fallen trial of stored transfer studies against the ones
that did not fall, from the stores alone (no rollouts).

    python -m benchmarks.transfer_falls [stores] [--root results/paper10k/a1]
        [--target a1-jump-flat-default] [--plain a1-jump-flat] [--source a1-jump]
        [--seeds 0 1 2 3 4] [--counterfactual OPTION=VALUE[:OPTION=VALUE] ...]
        [--out FILE.json] [--md FILE.md]

The study of seed 0 is ``ROOT/TARGET``, of seed s > 0 ``ROOT/TARGET-sS`` (the paper runner's
naming); ``--plain`` names the paper's plain phase 3 the same way (its seed 0 is the phase 3 of
``--source``). Every store is copied first with SQLite's backup API from a read-only connection
(a live run may be writing it), with the study's latent space, into a temporary directory.

Per seed the target study's transfer critic is rebuilt as the phase loop builds it
(:func:`latentune.pipeline.loop.transfer_critic`: the source's trials, the stored latent space,
the manual θ, the zero-shot trial; the stored source hyperparameters, so nothing is refitted),
told the stored phase-3 rows one ask at a time and asked again before each: ``reproduced``
counts the asks that give the stored θ and tags in some order (the critic is deterministic; a
batch's rows are stored in the order its trials finished). For each trial the
JSON keeps the ask's decision (generation, pool, trust-region side ``L``, cost agreement ``a``,
candidates admitted by the fall screen) and, at the asked θ, the screen's fall probability (the
target fall model's upper bound, as the ask saw it), its mean and standard deviation, the source
fall model's probability, the RMS distance (unit box, ``‖Δ‖ / √d``) and largest coordinate step
from the ask's centre (the best θ so far that did not fall) and the number of coordinates moved.
The summaries compare fallen and standing trials (medians), the screen's discrimination (AUC of
its probability for the falls) and calibration (mean probability against the fall rate), and
the fall rate by trust-region side and by distance from the centre.

The source: how many of its falls each source model was fitted on (the cost model's subset and
the fall model's balanced subset of ``max_points``), the source fall model's AUC on all source
trials, and the source's own fall rate by RMS distance from its best θ.

``--counterfactual``: at every replayed ask a copy of the critic with those Transfer options
asks too (told the same stored history), and the fall model's mean probability at its θ is kept
beside the stored asks' — what the option would have asked, predicted by the model, no rollouts.

    python -m benchmarks.transfer_falls ladder [--root runs/transfer] [--systems chain hopper]
        [--seeds 0 1 2] [--methods transfer transfer+VARIANT ...] [--after 8] [--out FILE.json]

``ladder``: for traces of :mod:`benchmarks.transfer` (``run --variants``), per (system, gap,
method) the median over the seeds of the best cost, of the falls and of the falls from trial
``--after`` on (the search's falls, after the first trials the screen knows little about); the
asks and falls by band of the fall screen's probability (``screen_bands``: how calibrated the
screen was), and with ``fall_calibrate`` the median of the runs' last calibration map
``(a, b)`` (``b`` well below 1: the screen's score tells little of which θ fall there); and
the trust-region asks and their falls by band of the step from the centre (``region_steps``).

    python -m benchmarks.transfer_falls kinds --root results/transfer/rebuilt/runs
        --methods transfer+VARIANT@avx512 ... [--systems ...] [--seeds ...] [--out FILE.json]

``kinds``: per method, the asks and falls by kind of ask (the design, a region ask's pool, an
explore ask's pool; explore asks whose own GP chose warped values marked so), summed over every
stored trace.
"""
from __future__ import annotations

import json
import math
import shutil
import sqlite3
import sys
import tempfile
from pathlib import Path
from typing import Any

from latentune.threads import one_thread_env

one_thread_env()

import numpy as np  # noqa: E402

from latentune.pipeline.store import read_uri  # noqa: E402

RADII = (0.01, 0.02, 0.05, 0.1, 0.2)
"""RMS distances (unit box) at which fall rates around a centre are counted."""
PF_EDGES = (0.0, 0.1, 0.2, 0.3, 1.0)
"""Bins of the screen's fall probability for its calibration table."""
STEP_EDGES = (0.0, 0.05, 0.2, 1.0)
"""Bins of a trust-region ask's largest coordinate step from its centre (``ladder``)."""


def study_name(prefix: str, seed: int) -> str:
    """The paper runner's study directory name for ``seed``."""
    return prefix if seed == 0 else f"{prefix}-s{seed}"


def snapshot(study: Path, dst: Path) -> Path:
    """A consistent copy of ``study`` (run.db through SQLite's backup API from a read-only
    connection, the other files as they are, no WAL/lock files) at ``dst``; returns ``dst``."""
    if not (study / "run.db").is_file():
        raise FileNotFoundError(f"no run store at {study}")
    dst.mkdir(parents=True, exist_ok=True)
    for f in study.iterdir():
        if f.is_file() and not f.name.startswith("run."):
            shutil.copy2(f, dst / f.name)
    src = sqlite3.connect(read_uri(study / 'run.db'), uri=True)
    out = sqlite3.connect(dst / "run.db")
    try:
        src.backup(out)
    finally:
        src.close()
        out.close()
    return dst


def auc(score: np.ndarray, pos: np.ndarray) -> float | None:
    """Area under the ROC curve of ``score`` (n,) for the positives ``pos`` (n,) (ties: half),
    None without both classes."""
    from scipy.stats import rankdata

    pos = np.asarray(pos, bool)
    n1, n0 = int(pos.sum()), int((~pos).sum())
    if n1 == 0 or n0 == 0:
        return None
    r = rankdata(score)
    return float((r[pos].sum() - n1 * (n1 + 1) / 2) / (n1 * n0))


def _rms(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    d = np.atleast_2d(a) - np.atleast_2d(b)
    return np.linalg.norm(d, axis=1) / math.sqrt(d.shape[1])


def rates_by_distance(X: np.ndarray, fell: np.ndarray, centre: np.ndarray) -> list[dict]:
    """Trials and fall rate within each of :data:`RADII` (RMS) of ``centre``."""
    r = _rms(X, centre)
    out = []
    for rad in RADII:
        m = r <= rad
        out.append({"rms_within": rad, "trials": int(m.sum()), "falls": int(fell[m].sum()),
                    "fall_rate": float(fell[m].mean()) if m.any() else None})
    return out


def source_report(critic: Any) -> dict[str, Any]:
    """What the source models of ``critic`` (a Transfer) were fitted on, and how the source's
    falls lie (module docstring)."""
    X, y, f = critic.source
    sm = critic.source_model()

    def falls_in(S: np.ndarray) -> tuple[int, int]:
        idx = [int(np.flatnonzero(np.all(X == s, axis=1))[0]) for s in S]
        return len(idx), int(f[idx].sum())

    n_c, f_c = falls_in(sm.cost_gp.S)
    n_f, f_f = falls_in(sm.fall_gp.S) if sm.fall_gp is not None else (0, 0)
    ok = np.where(f, np.inf, y)
    best = X[int(np.argmin(ok))]
    ps = sm.fall_prob(X)
    return {"trials": int(len(y)), "falls": int(f.sum()), "fall_rate": float(f.mean()),
            "cost_model_points": n_c, "cost_model_falls": f_c,
            "fall_model_points": n_f, "fall_model_falls": f_f,
            "fall_model_constant": None if sm.fall_gp is None else sm.fall_gp.constant,
            "fall_model_auc_all_source": auc(ps, f),
            "fall_model_mean_at_falls": float(ps[f].mean()) if f.any() else None,
            "fall_model_mean_at_standing": float(ps[~f].mean()),
            "fall_model_at_source_best": float(sm.fall_prob(best[None, :])[0]),
            "falls_near_source_best": rates_by_distance(X, f, best),
            "cost_lengthscales": sm.lengthscales.tolist(),
            "fall_lengthscales": sm.fall_lengthscales.tolist()}


def same_points(U: np.ndarray, T: np.ndarray, X: np.ndarray, tags: np.ndarray) -> bool:
    """True when the asked points ``U`` (n, d) with tags ``T`` (n,) are the stored ``X`` (n, d)
    with ``tags`` (n,) in some order (rows are stored in the order their trials finished)."""
    a = np.column_stack([T, U])
    b = np.column_stack([tags, X])
    return a.shape == b.shape and np.array_equal(a[np.lexsort(a.T[::-1])],
                                                 b[np.lexsort(b.T[::-1])])


def _build(target: Path, source: Path) -> tuple[Any, list[Any]]:
    """The target study's transfer critic as the phase loop builds it, and its phase-3 rows."""
    from latentune.constants import Phase
    from latentune.pipeline.loop import study_latent, transfer_critic
    from latentune.pipeline.phases import state_key
    from latentune.pipeline.rundir import RunDir
    from latentune.pipeline.store import RunStore
    from latentune.space import ParameterSpace

    run = RunDir(target)
    latent = study_latent(run)
    with RunStore(target) as st:
        cfg = st.get_meta("config")
        state = st.get_meta(state_key(Phase.PHASE3))
        rows = st.rows(Phase.PHASE3)
    run.close()
    pc = cfg["phase3"]
    if pc.get("strategy") != "transfer":
        raise ValueError(f"{target} is not a transfer phase 3 (strategy {pc.get('strategy')})")
    critic = transfer_critic(pc, ParameterSpace.from_dict(cfg["space"]), target, source, latent)
    critic.load_state_dict({"source_hypers": state["source_hypers"],
                            "options": state["options"]})
    return critic, rows


def replay_seed(target: Path, source: Path, variants: dict[str, dict[str, Any]] | None = None
                ) -> dict[str, Any]:
    """Per-trial records of one transfer study (module docstring) and its source report; with
    ``variants`` (name -> Transfer options), each record also holds, per variant, the fall
    model's mean probability at the θ a copy of the critic with those options asks in the same
    state (``pf_mean_option``; no rollouts)."""
    import copy

    critic, rows = _build(target, source)
    src = source_report(critic)
    k = critic.k
    trials: list[dict[str, Any]] = []
    reproduced = asks = 0
    i = 0
    while i < len(rows):
        g = rows[i].tag // 4
        j = i
        while j < len(rows) and rows[j].tag // 4 == g:
            j += 1
        batch = rows[i:j]
        centre = critic._centre().copy()
        best_cost = float(critic.best_y) if critic.n_told else math.nan
        twins = {}
        for name, opts in (variants or {}).items():
            twin = copy.deepcopy(critic)
            twin.opts.update(opts)
            twins[name] = twin.ask(len(batch))
        U = critic.ask(len(batch))
        T = critic.last_tags.copy()
        dec = critic.decisions[-1]
        Xb = np.array([r.theta for r in batch])
        asks += 1
        reproduced += int(same_points(U, T, Xb, np.array([r.tag for r in batch])))
        _, fall_m = critic.models()
        pf = critic._fall_prob(Xb, fall_m)
        if fall_m is None:
            mean, sd = pf, np.zeros(len(Xb))
            fa = None
        else:
            mean = fall_m.mean_cov(Xb, False)[0]
            sd = np.sqrt(fall_m.variance(Xb))
            fa = float(fall_m.coefficients()[0][0])
        ps = critic.source_model().fall_prob(Xb)
        p_opt = {name: np.clip(fall_m.mean_cov(Uo, False)[0], 0, 1) if fall_m is not None
                 else np.full(len(Uo), np.nan) for name, Uo in twins.items()}
        step = np.abs(Xb - centre)
        for q, r in enumerate(batch):
            trials.append({
                "idx": int(r.idx), "tag": int(r.tag), "generation": int(g),
                "pool": ["elite", "full", "latent", "global"][int(r.tag) % 4],
                "fell": bool(r.fell), "cost": float(r.cost), "fall_step": r.fall_step,
                "design": bool(dec.get("design")), "L": dec.get("length"),
                "agreement": dec.get("agreement"), "fall_agreement": fa,
                "n_admissible": dec.get("n_admissible"), "n_candidates": dec.get("n_candidates"),
                "pf_screen": float(pf[q]), "pf_mean": float(mean[q]), "pf_sd": float(sd[q]),
                "p_source": float(ps[q]), "rms_from_centre": float(_rms(Xb[q], centre)[0]),
                "max_step": float(step[q].max()), "coords_moved": int((step[q] > 1e-12).sum()),
                "best_before": best_cost,
                "pf_mean_option": {k: float(v[q]) for k, v in p_opt.items()}})
        Z = np.array([r.z if r.z is not None and len(r.z) == k else np.full(k, np.nan)
                      for r in batch]) if k else None
        critic.tell(Xb, np.array([r.cost for r in batch]), np.array([r.tag for r in batch]),
                    fell=np.array([r.fell for r in batch], dtype=bool), z=Z)
        i = j
    X_all = np.array([r.theta for r in rows])
    f_all = np.array([bool(r.fell) for r in rows])
    c = critic._centre()
    at = np.flatnonzero(np.all(X_all == c, axis=1))
    Xs, ys, fs = critic.source
    s_best = Xs[int(np.argmin(np.where(fs, np.inf, ys)))]
    return {"asks": asks, "reproduced": reproduced, "trials": trials, "source": src,
            "final_centre_falls": rates_by_distance(X_all, f_all, c),
            "final_centre_trial": int(at[0]) if at.size else None,
            "final_centre_rms_to_source_best": float(_rms(c, s_best)[0]),
            "source_falls_near_final_centre": rates_by_distance(Xs, fs, c)}


def _median(v: list[Any]) -> float | None:
    v = [x for x in v if x is not None and np.isfinite(x)]
    return float(np.median(v)) if v else None


def seed_summary(rep: dict[str, Any], max_fall_prob: float) -> dict[str, Any]:
    """Fallen against standing trials of one seed (medians), screen AUC and calibration, fall
    rate by trust-region side and distance."""
    t = [r for r in rep["trials"]]
    fell = np.array([r["fell"] for r in t])
    keys = ("L", "agreement", "fall_agreement", "pf_screen", "pf_mean", "pf_sd", "p_source",
            "rms_from_centre", "max_step", "coords_moved", "n_admissible")
    cmp_ = {k: {"fell": _median([r[k] for r, f in zip(t, fell) if f]),
                "stood": _median([r[k] for r, f in zip(t, fell) if not f])} for k in keys}
    pools: dict[str, list[int]] = {}
    for r in t:
        p = pools.setdefault(r["pool"], [0, 0])
        p[0] += 1
        p[1] += int(r["fell"])
    byL: dict[str, list[int]] = {}
    for r in t:
        if r["L"] is None:
            continue
        b = byL.setdefault(f"{math.log2(r['L']):.0f}", [0, 0])
        b[0] += 1
        b[1] += int(r["fell"])
    rms = np.array([r["rms_from_centre"] for r in t])
    edges = (0.0, 0.005, 0.01, 0.02, 0.05, 0.1, 1.0)
    by_d = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        m = (rms > lo) & (rms <= hi) if lo > 0 else rms <= hi
        by_d.append({"rms": f"({lo:g}, {hi:g}]", "trials": int(m.sum()),
                     "falls": int(fell[m].sum())})
    pf = np.array([r["pf_screen"] for r in t])
    pm = np.array([r["pf_mean"] for r in t])
    Ls = np.array([math.inf if r["L"] is None else r["L"] for r in t])
    at_min = np.flatnonzero(Ls <= min(Ls) * (1 + 1e-9))
    k0 = int(at_min[0]) if at_min.size else len(t)
    costs = np.array([math.inf if r["fell"] else r["cost"] for r in t])
    after = np.array([not r["design"] for r in t])
    return {"trials": len(t), "falls": int(fell.sum()),
            "falls_per_100": 100.0 * float(fell.mean()),
            "fallen_vs_stood": cmp_,
            "pools": {k: {"trials": v[0], "falls": v[1]} for k, v in pools.items()},
            "by_log2_L": {k: {"trials": v[0], "falls": v[1]} for k, v in byL.items()},
            "by_rms_from_centre": by_d,
            "screen_auc": auc(pf[after], fell[after]),
            "screen_mean_auc": auc(pm[after], fell[after]),
            "source_p_auc": auc(np.array([r["p_source"] for r in t])[after], fell[after]),
            "screen_mean_prob": float(pf[after].mean()),
            "screen_mean_of_mean": float(pm[after].mean()),
            "option_mean_of_mean": {k: float(np.mean([r["pf_mean_option"][k]
                                                      for r, a in zip(t, after) if a]))
                                    for k in t[-1]["pf_mean_option"]},
            "fall_rate_after_design": float(fell[after].mean()),
            "by_screen_prob": [{"pf_screen": f"({lo:g}, {hi:g}]", "trials": int(m.sum()),
                                "falls": int(fell[m].sum())}
                               for lo, hi in zip(PF_EDGES[:-1], PF_EDGES[1:])
                               for m in [after & (pf > lo) & (pf <= hi)]],
            "asked_over_screen": int((pf > max_fall_prob).sum()),
            "first_fall_idx": int(np.flatnonzero(fell)[0]) if fell.any() else None,
            "best_before_first_ask": t[0]["best_before"],
            "first_trial_at_min_L": k0, "trials_at_min_L": int(len(t) - k0),
            "falls_from_min_L": int(fell[k0:].sum()),
            "best_before_min_L": float(min(t[0]["best_before"], costs[:k0].min(initial=math.inf))),
            "best_final": float(min(t[0]["best_before"], costs.min())),
            "falls_by_quarter": [int(fell[q * len(t) // 4:(q + 1) * len(t) // 4].sum())
                                 for q in range(4)]}


def plain_falls(root: Path, plain: str, source: str, seeds: list[int]) -> list[dict]:
    """Falls of the plain phase 3 per seed (seed 0: the source study's phase 3)."""
    out = []
    for s in seeds:
        d = root / (source if s == 0 else study_name(plain, s))
        if not (d / "run.db").is_file():
            out.append({"seed": s, "study": d.name, "trials": None, "falls": None})
            continue
        con = sqlite3.connect(read_uri(d / 'run.db'), uri=True)
        try:
            n, f = con.execute("select count(*), coalesce(sum(fell), 0) from evaluations "
                               "where phase = 3").fetchone()
        finally:
            con.close()
        out.append({"seed": s, "study": d.name, "trials": int(n), "falls": int(f)})
    return out


def _fmt(v: Any) -> str:
    if v is None:
        return "–"
    if isinstance(v, float):
        return f"{v:.3g}"
    return str(v)


def _section(title: str, cols: list[str], rows: list[list[Any]]) -> list[str]:
    """Markdown lines of a titled table (cells through :func:`_fmt`)."""
    return ["", f"## {title}", "", "| " + " | ".join(cols) + " |", "|" + "---|" * len(cols),
            *("| " + " | ".join(_fmt(c) for c in r) + " |" for r in rows)]


def _rate_table(title: str, head: str, key: str, rows: list[dict[str, Any]]) -> list[str]:
    """Markdown lines of a table of trials, falls and fall rate per bin ``row[key]``."""
    return _section(title, [head, "trials", "falls", "rate"],
                    [[v[key], v["trials"], v["falls"],
                      v["falls"] / v["trials"] if v["trials"] else None] for v in rows])


def markdown(res: dict[str, Any]) -> str:
    """The Markdown report of :func:`run`'s result."""
    S = res["seeds"]
    L = [f"# Falls of the transfer phase 3: {res['target']} (source {res['source']})", "",
         f"Command: `{res['command']}`", "",
         "## Per seed", "",
         "| seed | asks reproduced | trials | falls | falls/100 | plain falls | pools (trials/falls)"
         " | falls by quarter | first fall | screen AUC (UCB / mean / source p) "
         "| mean screen p / fall rate after design |",
         "|---|---|---|---|---|---|---|---|---|---|---|"]
    for s in S:
        m = s["summary"]
        pools = ", ".join(f"{k} {v['trials']}/{v['falls']}" for k, v in sorted(m["pools"].items()))
        L.append(f"| {s['seed']} | {s['reproduced']}/{s['asks']} | {m['trials']} | {m['falls']} "
                 f"| {m['falls_per_100']:.1f} | {_fmt(s['plain_falls'])} | {pools} "
                 f"| {m['falls_by_quarter']} | {_fmt(m['first_fall_idx'])} "
                 f"| {_fmt(m['screen_auc'])} / {_fmt(m['screen_mean_auc'])} / "
                 f"{_fmt(m['source_p_auc'])} | {_fmt(m['screen_mean_prob'])} / "
                 f"{_fmt(m['fall_rate_after_design'])} |")
    cf = res.get("counterfactual") or []
    if cf:
        L += ["", "## Counterfactual (no rollouts): the same states asked with other options", "",
              "Mean over the asks after the design of the fall model's posterior mean at the "
              "asked θ; for the stored asks compare it with their fall rate after the design "
              "(per-seed table).", "",
              "| seed | stored asks | " + " | ".join(cf) + " |",
              "|---|---|" + "---|" * len(cf)]
        for s in S:
            m = s["summary"]
            L.append(f"| {s['seed']} | {_fmt(m['screen_mean_of_mean'])} | "
                     + " | ".join(_fmt(m["option_mean_of_mean"][k]) for k in cf) + " |")
        L.append("| median | " + _fmt(_median([s["summary"]["screen_mean_of_mean"] for s in S]))
                 + " | " + " | ".join(_fmt(_median([s["summary"]["option_mean_of_mean"][k]
                                                   for s in S])) for k in cf) + " |")
    L += _section("What the trials at the smallest trust region bought",
                  ["seed", "best before the first ask (zero-shot)",
                   "first trial at the smallest side", "trials / falls from it", "best before it",
                   "final best"],
                  [[s["seed"], f"{m['best_before_first_ask']:.4f}", m["first_trial_at_min_L"],
                    f"{m['trials_at_min_L']} / {m['falls_from_min_L']}",
                    f"{m['best_before_min_L']:.4f}", f"{m['best_final']:.4f}"]
                   for s in S for m in [s["summary"]]])
    L += ["", "## Fallen against standing trials (median over seeds of the per-seed medians)", "",
          "| quantity at the ask | fell | stood |", "|---|---|---|"]
    for k, v in res["fallen_vs_stood"].items():
        L.append(f"| {k} | {_fmt(v['fell'])} | {_fmt(v['stood'])} |")
    L += ["", "## Fall rate by trust-region side (all seeds pooled)", "",
          "| log2 L | trials | falls | rate |", "|---|---|---|---|"]
    for k, v in sorted(res["by_log2_L"].items(), key=lambda kv: -float(kv[0])):
        L.append(f"| {k} | {v['trials']} | {v['falls']} | {v['falls'] / v['trials']:.3f} |")
    L += _rate_table("Fall rate by RMS distance from the ask's centre (all seeds pooled)",
                     "RMS from centre", "rms", res["by_rms_from_centre"])
    L += _rate_table("The screen's calibration: fall rate by its probability at the asked θ "
                     "(asks after the design, all seeds pooled)", "screen probability",
                     "pf_screen", res["by_screen_prob"])
    L += _section("The final centre (the best θ that did not fall, after the last trial)",
                  ["seed", "found at trial", "RMS to the source's best",
                   "target trials / falls within RMS 0.01 of it",
                   "source trials / falls within RMS 0.02 of it"],
                  [[s["seed"], s["final_centre_trial"], s["final_centre_rms_to_source_best"],
                    f"{a['trials']} / {a['falls']}", f"{b['trials']} / {b['falls']}"]
                   for s in S for a, b in [(s["final_centre_falls"][0],
                                            s["source_falls_near_final_centre"][1])]])
    L += _section("The source models (per seed: the fitted subsets depend on the seed)",
                  ["seed", "source trials / falls", "cost-model points / falls",
                   "fall-model points / falls", "fall-model constant",
                   "fall-model AUC on the source", "p at falls / standing", "p at source best"],
                  [[s["seed"], f"{r['trials']} / {r['falls']}",
                    f"{r['cost_model_points']} / {r['cost_model_falls']}",
                    f"{r['fall_model_points']} / {r['fall_model_falls']}",
                    r["fall_model_constant"], r["fall_model_auc_all_source"],
                    f"{_fmt(r['fall_model_mean_at_falls'])} / "
                    f"{_fmt(r['fall_model_mean_at_standing'])}", r["fall_model_at_source_best"]]
                   for s in S for r in [s["source"]]])
    L += ["", "## Falls around the source's best θ (source trials) and around the target's final "
          "centre (target trials, seed 0)", "",
          "| RMS within | source trials | source falls | target trials | target falls |",
          "|---|---|---|---|---|"]
    s0 = S[0]
    for a, b in zip(s0["source"]["falls_near_source_best"], s0["final_centre_falls"]):
        L.append(f"| {a['rms_within']} | {a['trials']} | {a['falls']} | {b['trials']} "
                 f"| {b['falls']} |")
    return "\n".join(L) + "\n"


def run(root: Path, target: str, plain: str, source: str, seeds: list[int],
        command: str, variants: dict[str, dict[str, Any]] | None = None) -> dict[str, Any]:
    """Replay and summarize every seed (module docstring)."""
    plain_rows = {p["seed"]: p for p in plain_falls(root, plain, source, seeds)}
    out: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="transfer_falls_") as tmp:
        src = snapshot(root / source, Path(tmp) / source)
        for s in seeds:
            name = study_name(target, s)
            tgt = snapshot(root / name, Path(tmp) / name)
            rep = replay_seed(tgt, src, variants)
            from latentune.critic.transfer import TRANSFER_DEFAULTS

            summ = seed_summary(rep, float(TRANSFER_DEFAULTS["max_fall_prob"]))
            out.append({"seed": s, "study": name, **{k: rep[k] for k in
                                                     ("asks", "reproduced", "source",
                                                      "final_centre_falls", "final_centre_trial",
                                                      "final_centre_rms_to_source_best",
                                                      "source_falls_near_final_centre",
                                                      "trials")},
                        "summary": summ, "plain_falls": plain_rows[s]["falls"]})
            print(f"seed {s}: {summ['falls']} falls / {summ['trials']}, "
                  f"{rep['reproduced']}/{rep['asks']} asks reproduced", file=sys.stderr)
    fvs: dict[str, dict[str, float | None]] = {}
    for k in out[0]["summary"]["fallen_vs_stood"]:
        fvs[k] = {w: _median([o["summary"]["fallen_vs_stood"][k][w] for o in out])
                  for w in ("fell", "stood")}
    byL: dict[str, dict[str, int]] = {}
    by_d: dict[str, dict[str, Any]] = {}
    by_p: dict[str, dict[str, Any]] = {}
    for o in out:
        for v in o["summary"]["by_screen_prob"]:
            b = by_p.setdefault(v["pf_screen"], {"pf_screen": v["pf_screen"], "trials": 0,
                                                 "falls": 0})
            b["trials"] += v["trials"]
            b["falls"] += v["falls"]
        for k, v in o["summary"]["by_log2_L"].items():
            b = byL.setdefault(k, {"trials": 0, "falls": 0})
            b["trials"] += v["trials"]
            b["falls"] += v["falls"]
        for v in o["summary"]["by_rms_from_centre"]:
            b = by_d.setdefault(v["rms"], {"rms": v["rms"], "trials": 0, "falls": 0})
            b["trials"] += v["trials"]
            b["falls"] += v["falls"]
    return {"target": target, "source": source, "plain": plain, "seeds": out,
            "command": command, "counterfactual": sorted(variants or {}),
            "median_falls_per_100": _median([o["summary"]["falls_per_100"] for o in out]),
            "fallen_vs_stood": fvs, "by_log2_L": byL, "by_rms_from_centre": list(by_d.values()),
            "by_screen_prob": list(by_p.values())}


def ladder(root: Path, systems: list[str], seeds: list[int], methods: list[str], after: int
           ) -> list[dict[str, Any]]:
    """Per (system, gap, method) of the transfer ladder's traces under ``root``
    (``ROOT/<system>/gap<g>/seed<s>/<method>.json``): the median over ``seeds`` of the best cost
    of the trials that did not fall, of the falls, and of the falls from trial ``after`` + 1 on
    (once the target models have data), with the seeds found."""
    rows = []
    for system in systems:
        for g in sorted((root / system).glob("gap*"), key=lambda p: float(p.name[3:])):
            for m in methods:
                best, falls, late, calib = [], [], [], []
                bands = np.zeros((len(PF_EDGES) - 1, 2), dtype=int)
                steps = np.zeros((len(STEP_EDGES) - 1, 2), dtype=int)
                for s in seeds:
                    f = g / f"seed{s}" / f"{m}.json"
                    if not f.is_file():
                        continue
                    r = json.loads(f.read_text())
                    c, fl = np.asarray(r["costs"], float), np.asarray(r["failed"], bool)
                    best.append(float(np.min(c[~fl])) if (~fl).any() else math.inf)
                    falls.append(int(fl.sum()))
                    late.append(int(fl[after:].sum()))
                    bands += screen_bands(r)
                    steps += region_steps(r)
                    if r.get("decisions") and "fall_calibration" in r["decisions"][-1]:
                        calib.append(r["decisions"][-1]["fall_calibration"])
                rows.append({"system": system, "gap": g.name[3:], "method": m,
                             "seeds": len(best), "median_best": _median(best),
                             "median_falls": _median(falls), f"median_falls_after_{after}":
                             _median(late), "falls_total": int(sum(falls)),
                             f"falls_after_{after}_total": int(sum(late)),
                             "screen_bands": {f"{lo}-{hi}": [int(n), int(k)] for (lo, hi), (n, k)
                                              in zip(zip(PF_EDGES, PF_EDGES[1:]), bands)},
                             "region_steps": {f"{lo}-{hi}": [int(n), int(k)] for (lo, hi), (n, k)
                                              in zip(zip(STEP_EDGES, STEP_EDGES[1:]), steps)},
                             **({"calibration_median": np.median(calib, 0).round(3).tolist()}
                                if calib else {})})
    return rows


def ask_kind(d: dict[str, Any]) -> str:
    """The kind of ask of one decision record: ``design``, ``explore <pool>`` (``latent`` for
    records made before the explore pool was recorded), or the region ask's pool."""
    if d.get("design"):
        return "design"
    if d.get("explore"):
        return f"explore {d.get('explore_pool', 'latent')}"
    return (d.get("pools") or ["?"])[0]


def kind_of(d: dict[str, Any]) -> str:
    """The kind of ask of one decision record (:func:`ask_kind`), an explore ask whose own GP
    fitted warped values (``explore_scores="auto"`` chose them) marked ``(warped)``."""
    warped = (d.get("auto_scores") or {}).get("explore", [None])[0] == "warped"
    return ask_kind(d) + (" (warped)" if warped else "")


def kinds(root: Path, methods: list[str], systems: list[str] | None = None,
          seeds: list[int] | None = None) -> list[dict[str, Any]]:
    """Asks and falls by kind of ask (:func:`kind_of`; decision ``i`` asked trial ``i + 1``,
    trial 0 is the zero-shot θ) of every stored trace of each of ``methods`` under ``root``
    (``ROOT/<system>/gap<g>/seed<s>/<method>.json``; only ``systems`` and ``seeds`` when given),
    summed over the traces: one row per (method, kind), and one ``all`` row per method."""
    rows = []
    for m in methods:
        acc: dict[str, list[int]] = {}
        runs = 0
        for f in sorted(root.glob(f"*/gap*/seed*/{m}.json")):
            system, seed = f.parts[-4], int(f.parts[-2][4:])
            if (systems is not None and system not in systems) or \
                    (seeds is not None and seed not in seeds):
                continue
            r = json.loads(f.read_text())
            runs += 1
            for i, d in enumerate((r.get("decisions") or [])[:len(r["failed"]) - 1]):
                a = acc.setdefault(kind_of(d), [0, 0])
                a[0] += 1
                a[1] += bool(r["failed"][i + 1])
        if not runs:
            raise ValueError(f"no trace of {m} under {root}")
        total = [sum(v[0] for v in acc.values()), sum(v[1] for v in acc.values())]
        for k, (n, fell) in [*sorted(acc.items()), ("all", total)]:
            rows.append({"method": m, "runs": runs, "kind": k, "asks": n, "falls": fell,
                         "fall_rate": round(fell / n, 4) if n else None})
    return rows


def region_steps(trace: dict[str, Any]) -> np.ndarray:
    """(len(STEP_EDGES) − 1, 2) asks and falls of one :mod:`benchmarks.transfer` trace's
    trust-region asks (neither design nor explore; batch 1) by band of their step from the centre:
    the largest coordinate difference (unit box) between the θ asked and the best θ that did not
    fall among the trials before it. Asks before any trial stood are not counted."""
    fl = np.asarray(trace["failed"], bool)
    c = np.asarray(trace["costs"], float)
    X = np.asarray(trace["thetas"], float)
    dec = trace.get("decisions") or []
    out = np.zeros((len(STEP_EDGES) - 1, 2), dtype=int)
    for i, d in enumerate(dec, start=len(fl) - len(dec)):
        ok = ~fl[:i]
        if d.get("design") or d.get("explore") or len(d.get("pools", [])) != 1 or not ok.any():
            continue
        centre = X[:i][ok][np.argmin(c[:i][ok])]
        out[band(STEP_EDGES, float(np.abs(X[i] - centre).max()))] += (1, int(fl[i]))
    return out


def band(edges: tuple[float, ...], v: float) -> int:
    """The index of the band of ``edges`` (closed below) holding ``v``; the last band holds its
    upper edge and everything above it."""
    return min(int(np.searchsorted(edges, v, side="right")) - 1, len(edges) - 2)


def screen_bands(trace: dict[str, Any]) -> np.ndarray:
    """(len(PF_EDGES) − 1, 2) asks and falls of one :mod:`benchmarks.transfer` trace by band of
    the fall screen's probability of the θ asked (each decision's ``max_fall_prob_asked``, the
    batch's largest; batch 1 in the ladder). A trace's decisions are its last trials' (the
    zero-shot trial before them has none); asks without the probability (the manual θ after
    falls) are not counted."""
    fl = np.asarray(trace["failed"], bool)
    dec = trace.get("decisions") or []
    out = np.zeros((len(PF_EDGES) - 1, 2), dtype=int)
    for i, d in enumerate(dec, start=len(fl) - len(dec)):
        p = d.get("max_fall_prob_asked")
        if p is None or len(d.get("pools", [])) != 1:
            continue
        out[band(PF_EDGES, p)] += (1, int(fl[i]))
    return out


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["ladder"]:
        return main_ladder(argv[1:])
    if argv[:1] == ["kinds"]:
        return main_kinds(argv[1:])
    if argv[:1] == ["stores"]:
        argv = argv[1:]
    from benchmarks.common import Provenance, bench_parser, out_file, write_json, write_text

    ap = bench_parser("benchmarks.transfer_falls", description=__doc__.splitlines()[0],
                      epilog="This is its 'stores' command (the default). The others: "
                             "'ladder' (the traces of benchmarks.transfer run: falls by screen "
                             "band and by trust-region step, region_steps) and 'kinds' (asks "
                             "and falls by kind of ask); each has its own --help.")
    ap.add_argument("--root", type=Path, default=Path("results/paper10k/a1"),
                    help="directory holding the studies")
    ap.add_argument("--target", default="a1-jump-flat-default",
                    help="the transfer studies' name (seed s > 0: NAME-sS)")
    ap.add_argument("--plain", default="a1-jump-flat",
                    help="the plain phase 3's studies' name (seed 0: the source's phase 3)")
    ap.add_argument("--source", default="a1-jump", help="the source study")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    ap.add_argument("--counterfactual", nargs="+", default=[],
                    metavar="OPTION=VALUE[:OPTION=VALUE]",
                    help="also ask a copy of the critic with these Transfer options at every "
                         "replayed ask and report the fall model's mean probability at its θ")
    ap.add_argument("--out", type=out_file, default=None, metavar="FILE.json",
                    help="write the results (every trial's record) and provenance here")
    ap.add_argument("--md", type=out_file, default=None, metavar="FILE.md",
                    help="write the Markdown report here (it is printed on stdout too)")
    a = ap.parse_args(argv)
    prov = Provenance(["stores", *argv], module="benchmarks.transfer_falls")
    from benchmarks.transfer import parse_variant

    variants = {v: parse_variant(v) for v in a.counterfactual}
    res = run(a.root, a.target, a.plain, a.source, a.seeds, prov.command, variants)
    md = markdown(res)
    print(md)
    if a.md is not None:
        write_text(a.md, md)
    if a.out is not None:
        write_json(a.out, res, prov)
    return 0


def main_ladder(argv: list[str]) -> int:
    """``ladder``: falls and best costs of transfer variants on the transfer ladder's traces; a
    --methods name with no trace under --root for these systems and seeds is refused (exit 2)."""
    from benchmarks.common import Provenance, add_out_arg, bench_parser, error_line, finish

    ap = bench_parser("benchmarks.transfer_falls ladder", description=main_ladder.__doc__)
    ap.add_argument("--root", type=Path, default=Path("runs/transfer"))
    ap.add_argument("--systems", nargs="+", default=["chain", "hopper"])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--methods", nargs="+", default=["transfer"],
                    help="trace names, e.g. transfer transfer+fall_cost=true")
    ap.add_argument("--after", type=int, default=8,
                    help="also count the falls from this trial on (0-based index)")
    add_out_arg(ap)
    a = ap.parse_args(argv)
    prov = Provenance(["ladder", *argv], module="benchmarks.transfer_falls")
    rows = ladder(a.root, a.systems, a.seeds, a.methods, a.after)
    missing = [m for m in a.methods if not any(r["method"] == m and r["seeds"] for r in rows)]
    if missing:             # an empty table (or the others' rows alone) and exit 0 misled
        error_line("benchmarks.transfer_falls ladder",
                   f"no trace of {' '.join(missing)} under {a.root} (systems "
                   f"{' '.join(a.systems)}, seeds {' '.join(map(str, a.seeds))})")
        return 2
    finish(a.out, prov, {"root": str(a.root), "seeds": a.seeds, "after": a.after}, rows,
           title=f"Transfer variants on the ladder (median over seeds {a.seeds})")
    return 0


def main_kinds(argv: list[str]) -> int:
    """``kinds``: asks and falls by kind of ask of transfer variants' traces (their decisions)."""
    from benchmarks.common import Provenance, bench_parser, error_line, finish, out_file

    ap = bench_parser("benchmarks.transfer_falls kinds", description=main_kinds.__doc__)
    ap.add_argument("--root", type=Path, default=Path("runs/transfer"))
    ap.add_argument("--methods", nargs="+", required=True,
                    help="trace names, e.g. transfer+VARIANT@avx512")
    ap.add_argument("--systems", nargs="+", default=None)
    ap.add_argument("--seeds", type=int, nargs="+", default=None)
    ap.add_argument("--out", type=out_file, default=None, metavar="FILE.json")
    a = ap.parse_args(argv)
    prov = Provenance(["kinds", *argv], module="benchmarks.transfer_falls")
    try:
        rows = kinds(a.root, a.methods, a.systems, a.seeds)
    except ValueError as e:
        error_line("benchmarks.transfer_falls kinds", e)
        return 2
    finish(a.out, prov, {"root": str(a.root), "systems": a.systems, "seeds": a.seeds}, rows,
           title="Asks and falls by kind of ask, summed over the traces")
    return 0


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.transfer_falls"))
