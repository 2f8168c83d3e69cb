"""Tests of the fall-aware critic (latentune.critic.fall_aware) and its fall model
(latentune.critic.fall_model): fewer falls at equal budget, determinism, resume (stored runs of
the hand-written classifier included), prior data, the screening hooks of the critic protocol,
the tag protocol and argument checks; `benchmarks.ask_latency --max-fall-prob` (the fall model's
cost in an ask) at a tiny size."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from latentune.constants import C1
from latentune.critic import X0_TAG, make_critic
from latentune.critic.fall_aware import FallAware
from latentune.critic.fall_model import FallModel, GPFallModel
from latentune.critic.turbo import KIND_DESIGN, KIND_THOMPSON, decode_tag

torch.set_num_threads(1)

XSTAR = np.array([0.6, 0.5, 0.35])          # x0 + x1 = 1.1: just inside the stable side
FAST_TURBO = dict(n_regions=1, n_candidates=300)


def problem(X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cost ``1 + |x − x*|²`` (d = 3); fell if ``x0 + x1 > 1.2`` (cost ``C1 + …``)."""
    X = np.atleast_2d(X)
    fell = X[:, 0] + X[:, 1] > 1.2
    y = 1.0 + ((X - XSTAR[: X.shape[1]]) ** 2).sum(1)
    return np.where(fell, C1 + 10.0 * y, y), fell


def critic(method: str, seed: int, fall_aware: bool, batch: int = 5, **fa_kw):
    kw = dict(batch_size=batch, seed=seed, **(FAST_TURBO if method == "turbo" else {}))
    c = make_critic(method, 3, **kw)
    return FallAware(c, **fa_kw) if fall_aware else c


def run(c, budget: int, pass_fell: bool = True) -> tuple[int, float]:
    falls = 0
    while c.n_told < budget:
        X = c.ask(min(c.batch_size, budget - c.n_told))
        y, f = problem(X)
        falls += int(f.sum())
        if isinstance(c, FallAware) and pass_fell:
            c.tell(X, y, c.last_tags, fell=f)
        elif isinstance(c, FallAware):               # no flags: a fall's cost is non-finite
            c.tell(X, np.where(f, np.inf, y), c.last_tags)
        else:
            c.tell(X, y, c.last_tags)
    return falls, c.best_y


# ----------------------------------------------------------------------------- effect
def _medians(runs):
    return np.median([r[0] for r in runs]), np.median([r[1] for r in runs])


def test_random_far_fewer_falls_same_best():
    kw = dict(batch=10)                   # 8 asks of 10 per run: a fall-model fit per ask
    f_plain, b_plain = _medians([run(critic("random", s, False, **kw), 80) for s in range(3)])
    f_aware, b_aware = _medians([run(critic("random", s, True, **kw), 80, pass_fell=bool(s % 2))
                                 for s in range(3)])
    assert f_plain >= 15
    assert f_aware <= 0.5 * f_plain, (f_plain, f_aware)
    assert b_aware <= 1.05 * b_plain, (b_plain, b_aware)


def test_turbo_fewer_falls_same_best():
    """TuRBO-m: with prior data (a source run's θ and fell flags, here the same problem) the
    falls drop by half; without, the first falls cannot be predicted and the drop is smaller,
    but there are no more falls than without the wrapper and the best cost is kept."""
    rng = np.random.default_rng(7)
    P = rng.random((100, 3))
    pf = problem(P)[1]
    kw = dict(batch=10)                   # 6 asks of 10 per run
    f_plain, b_plain = _medians([run(critic("turbo", s, False, **kw), 60) for s in range(3)])
    f_aware, b_aware = _medians([run(critic("turbo", s, True, **kw), 60) for s in range(3)])
    f_prior, b_prior = _medians([run(critic("turbo", s, True, prior_X=P, prior_fell=pf, **kw), 60)
                                 for s in range(3)])
    assert f_plain >= 4
    assert f_prior <= 0.5 * f_plain, (f_plain, f_prior)
    assert f_aware <= f_plain, (f_plain, f_aware)
    assert max(b_aware, b_prior) <= 1.05 * b_plain, (b_plain, b_aware, b_prior)


def test_cma_generations_complete_and_fewer_falls():
    """CMA-ES in penalise mode: its generations are completed (screened members told with a
    penalty), so pycma keeps updating; falls do not increase."""
    budget = 60
    plain = [run(critic("cma", s, False, batch=4), budget)[0] for s in range(3)]
    fas = [critic("cma", s, True, batch=4) for s in range(3)]
    aware = [run(c, budget)[0] for c in fas]
    assert np.median(aware) <= np.median(plain)
    for c in fas:
        assert c.inner.n_told == c.n_told == budget
        assert c.inner.n_generations_told >= budget // c.inner.popsize
        assert c.inner.sigma != pytest.approx(1.0 / 6.0)
    assert sum(c.n_screened for c in fas) > 0
    assert all(c.stats()["mode"] == "penalise" for c in fas)


def test_dropping_points_would_stall_cma():
    """Why CMA-ES is not run in drop mode: told only part of each generation, pycma never
    updates (the generation stays pending)."""
    c = make_critic("cma", 3, batch_size=4, seed=0)
    for _ in range(10):
        X = c.ask(20)
        y, _ = problem(X)
        c.tell(X[:4], y[:4], c.last_tags[:4])
    assert c.sigma == pytest.approx(1.0 / 6.0)


# ----------------------------------------------------------------------------- protocol
@pytest.mark.parametrize("method", ["random", "sobol", "cma", "turbo"])
def test_passes_through_until_both_classes(method):
    """Before any fall (and without a prior) a FallAware asks exactly what its inner asks."""
    a = critic(method, 1, False, batch=5)
    b = critic(method, 1, True, batch=5)
    for _ in range(3):
        Xa, Xb = a.ask(), b.ask()
        np.testing.assert_array_equal(Xa, Xb)
        np.testing.assert_array_equal(a.last_tags, b.last_tags)
        assert np.isnan(b.last_fall_prob).all()
        y = np.ones(len(Xa))                         # nothing falls
        a.tell(Xa, y, a.last_tags)
        b.tell(Xb, y, b.last_tags)


@pytest.mark.parametrize("method", ["random", "sobol", "cma", "turbo"])
def test_shapes_tags_and_screening(method):
    c = critic(method, 2, True, batch=4)
    run(c, 40)
    for n in (1, 3, 7):
        X = c.ask(n)
        assert X.shape == (n, 3) and X.dtype == np.float64
        assert X.min() >= 0.0 and X.max() <= 1.0
        assert c.last_tags.shape == (n,) and c.last_tags.dtype == np.int64
        assert c.last_fall_prob.shape == (n,)
        if method == "turbo":
            assert all(decode_tag(t)[1] in (KIND_DESIGN, KIND_THOMPSON) for t in c.last_tags)
        over = c.last_fall_prob > c.max_fall_prob
        assert int(over.sum()) <= c.last_n_over
        y, f = problem(X)
        c.tell(X, y, c.last_tags, fell=f)
    assert c.fell.shape == (c.n_told,)
    assert c.n_told == c.inner.n_told


@pytest.mark.parametrize("method", ["random", "cma", "turbo"])
def test_deterministic(method):
    seqs = []
    for _ in range(2):
        c = critic(method, 4, True)
        run(c, 30)
        seqs.append((c.X, c.tags, c.ask(), c.last_tags))
    for u, v in zip(*seqs):
        np.testing.assert_array_equal(u, v)


@pytest.mark.parametrize("method,opts", [("random", {}), ("sobol", {}), ("cma", {}),
                                         ("turbo", {"warm_start": False})])
def test_resume_asks_the_same_batch(method, opts):
    """A fresh FallAware (fresh inner) told the stored history -- in completion order inside
    each batch, in one call or batch by batch -- asks the original's next batch."""
    def fresh():
        kw = dict(batch_size=4, seed=5, **opts, **(FAST_TURBO if method == "turbo" else {}))
        return FallAware(make_critic(method, 3, **kw), max_fall_prob=0.3)

    c = fresh()
    rng = np.random.default_rng(0)
    batches = []
    while c.n_told < 48:
        X = c.ask()
        T = c.last_tags
        y, f = problem(X)
        p = rng.permutation(len(y))            # the store keeps completion order
        batches.append((X[p], y[p], T[p], f[p]))
        c.tell(X[p], y[p], T[p], fell=f[p])
    assert c.fell.any() and c.n_screened + c.n_over > 0
    want, want_tags = c.ask(), c.last_tags.copy()
    one = fresh()
    one.tell(*(np.concatenate(v) for v in zip(*batches[:-1])))
    one.tell(*batches[-1])
    got = one.ask()
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(one.last_tags, want_tags)


def test_points_asked_and_not_told_are_dropped_or_served_again():
    c = critic("random", 0, True)
    run(c, 30)
    X = c.ask(5)
    y, f = problem(X)
    c.tell(X[:2], y[:2], c.last_tags[:2], fell=f[:2])   # three never told
    assert c.inner.n_told == c.n_told == 32
    c.ask(5)
    # CMA-ES: a run stopped with members of a generation asked and not told asks them first
    # when resumed (its generations must be completed)
    m = critic("cma", 0, True, batch=4)
    run(m, 40)
    X = m.ask(4)
    T = m.last_tags.copy()
    y, f = problem(X)
    m.tell(X[:1], y[:1], T[:1], fell=f[:1])
    resumed = critic("cma", 0, True, batch=4)
    resumed.tell(m.X, m.y, m.tags, fell=m.fell)
    X2 = resumed.ask(3)
    np.testing.assert_array_equal(X2, X[1:])
    np.testing.assert_array_equal(resumed.last_tags, T[1:])


def test_second_ask_without_tell_gives_new_points():
    c = critic("random", 0, True)
    run(c, 30)
    X1, X2 = c.ask(5), c.ask(5)
    assert not np.any(np.all(X1[:, None] == X2[None], axis=2))


# ----------------------------------------------------------------------------- prior data
def test_prior_data_screens_from_the_first_ask():
    rng = np.random.default_rng(1)
    P = rng.random((150, 3))
    pf = problem(P)[1]
    plain_falls = run(critic("random", 0, False), 30)[0]
    c = critic("random", 0, True, prior_X=P, prior_fell=pf)
    assert c.fall_prob(np.array([[0.95, 0.95, 0.5], [0.1, 0.1, 0.5]])) is not None
    p = c.fall_prob(np.array([[0.95, 0.95, 0.5], [0.1, 0.1, 0.5]]))
    assert p[0] > 0.7 and p[1] < 0.1
    X = c.ask()
    assert np.all(c.last_fall_prob <= c.max_fall_prob)
    assert c.last_n_screened > 0
    c.tell(X, problem(X)[0], c.last_tags)
    assert run(c, 30)[0] <= max(1, plain_falls // 4)


def test_turbo_design_points_are_replaced_not_dropped():
    """With a prior that says the upper half of x0 falls, TuRBO-m's design points there are
    replaced (same design tag) and its region still completes its design."""
    rng = np.random.default_rng(2)
    P = rng.random((200, 3))
    pf = P[:, 0] > 0.5
    c = FallAware(make_critic("turbo", 3, batch_size=4, seed=0, n_regions=1, n_init=8,
                              n_candidates=300), prior_X=P, prior_fell=pf)
    seen_design = 0
    for _ in range(4):
        X = c.ask()
        kinds = [decode_tag(t)[1] for t in c.last_tags]
        seen_design += kinds.count(KIND_DESIGN)
        assert np.all(X[np.array(kinds) == KIND_DESIGN, 0] <= 0.5 + 1e-9)
        y = 1.0 + ((X - 0.3) ** 2).sum(1)
        c.tell(X, y, c.last_tags, fell=X[:, 0] > 0.5)
    assert seen_design == 8
    assert c.inner.regions[0].n_points == 16 and c.n_screened > 0
    assert all(decode_tag(t)[1] == KIND_THOMPSON for t in c.tags[8:])


def test_warm_start_is_never_screened():
    rng = np.random.default_rng(3)
    P = rng.random((100, 3))
    x0 = np.array([0.9, 0.9, 0.5])                    # inside the fall region
    for method in ("random", "turbo", "cma"):
        kw = dict(batch_size=4, seed=0, x0=x0, **(FAST_TURBO if method == "turbo" else {}))
        c = FallAware(make_critic(method, 3, **kw), prior_X=P, prior_fell=problem(P)[1])
        X = c.ask()
        np.testing.assert_array_equal(X[0], x0)
        if method != "cma":
            assert c.last_tags[0] == X0_TAG or method == "turbo"


# ----------------------------------------------------------------------------- classifier
def test_classifier_learns_a_region_and_its_cost():
    rng = np.random.default_rng(0)
    X = rng.random((1000, 10))
    fell = X[:, 0] + X[:, 1] > 1.2
    clf = GPFallModel(10)
    assert not clf.fit(X[:50], np.zeros(50, dtype=bool))      # one class only: inactive
    with pytest.raises(RuntimeError):
        clf.p_fall(X[:3])
    assert clf.fit(X, fell)
    T = rng.random((2000, 10))
    p = clf.p_fall(T)
    truth = T[:, 0] + T[:, 1] > 1.2
    far = np.abs(T[:, 0] + T[:, 1] - 1.2) > 0.15
    assert np.mean((p > 0.5)[far] == truth[far]) > 0.97
    assert np.all((p >= 0) & (p <= 1))


# ----------------------------------------------------------------------------- arguments
@pytest.mark.parametrize("kw", [dict(max_fall_prob=0.0), dict(max_fall_prob=1.5),
                                dict(max_fall_prob=float("nan")), dict(max_fall_prob=True),
                                dict(oversample=0), dict(oversample=2.5),
                                dict(prior_X=np.zeros((3, 3))),
                                dict(prior_X=np.zeros((3, 3)), prior_fell=np.zeros(2, bool)),
                                dict(prior_X=np.full((3, 3), 2.0), prior_fell=np.zeros(3, bool)),
                                dict(prior_X=np.zeros((3, 2)), prior_fell=np.zeros(3, bool)),
                                dict(prior_X=np.zeros((3, 3)), prior_fell=np.array([0, 2, 1])),
                                dict(max_points=2), dict(threads=0)])
def test_bad_arguments(kw):
    with pytest.raises(ValueError):
        FallAware(make_critic("random", 3), **kw)


def test_bad_inner_and_bad_tell():
    with pytest.raises(ValueError):
        FallAware("turbo")
    used = make_critic("random", 3)
    used.tell(np.full((1, 3), 0.5), np.ones(1))
    with pytest.raises(ValueError):
        FallAware(used)
    with pytest.raises(ValueError):
        FallAware(FallAware(make_critic("random", 3)))
    c = FallAware(make_critic("random", 3))
    X = c.ask(2)
    with pytest.raises(ValueError):
        c.tell(X, np.ones(2), c.last_tags, fell=np.zeros(3, bool))
    with pytest.raises(ValueError):
        c.tell(X, np.ones(2), c.last_tags, fell=np.array([0.5, 1.0]))
    with pytest.raises(ValueError):
        c.tell(X, np.ones(3), c.last_tags)
    assert c.n_told == 0 and c.inner.n_told == 0


def test_fall_aware_turbo_tells_its_falls_and_starts_near_the_warm_start():
    """The phase critic with max_fall_prob: TuRBO-m's design fills the initial side around x0,
    the wrapper passes the fall flags on, and a batch that falls shrinks the region."""
    from latentune.pipeline.phases import FALL_DESIGN_SIDE, make_phase_critic

    x0 = np.full(4, 0.5)
    c = make_phase_critic("turbo", 4, batch_size=4, seed=0, x0=x0, budget=40,
                          max_fall_prob=0.5)
    inner = c.inner
    assert inner.fall_shrink == 0.5 and inner.design_side == FALL_DESIGN_SIDE
    half = FALL_DESIGN_SIDE / 2
    assert all(np.all(np.abs(inner.design_point(inner.regions[0], k) - 0.5) <= half + 1e-12)
               for k in range(inner.n_init))
    plain = make_phase_critic("turbo", 4, batch_size=4, seed=0, x0=x0, budget=40)
    assert plain.fall_shrink is None and plain.design_side is None
    while inner.regions[0].n_points < inner.n_init:
        X = c.ask()
        c.tell(X, 1.0 + ((X - 0.3) ** 2).sum(1), c.last_tags, fell=np.zeros(len(X), bool))
    X = c.ask()
    assert all(decode_tag(t)[1] == KIND_THOMPSON for t in c.last_tags)
    side = inner.regions[0].length
    c.tell(X, np.full(len(X), 150.0), c.last_tags, fell=np.ones(len(X), bool))
    assert inner.regions[0].length == pytest.approx(side / 2)
    assert inner.fell[-len(X):].all()


def test_max_fall_prob_1_runs_turbo(tmp_path, run_cli):
    """--max-fall-prob 1, which the flags take ((0, 1]), stopped phase 1, ask and the plain
    phase 3 with TuRBO-m in a traceback ('fall_shrink must be in [0, 1), got 1.0'); it runs
    (no share of falls exceeds 1: falls never halve a region by that rule)."""
    from latentune.pipeline.phases import make_phase_critic

    c = make_phase_critic("turbo", 4, batch_size=4, seed=0, x0=np.full(4, 0.5), budget=40,
                          max_fall_prob=1.0)
    assert c.inner.fall_shrink == 1.0
    code, out, err = run_cli("phase1", "--system", "examples.toy_plant:make_system", "--backend",
                             "serial", "--workers", "1", "--out", tmp_path / "r",
                             "--phase1-evals", "3", "--max-fall-prob", "1")
    assert code == 0 and "Traceback" not in err, err


# ----------------------------------------------------------------------------- diagnostics
def test_failed_classifier_and_gp_fits_are_reported_once_each(monkeypatch, caplog):
    """Failed fits of the fall model and of the inner TuRBO-m (both BoTorch fits) are counted
    in stats() and each model's failure is logged exactly once."""
    import botorch.optim.fit

    def broken(*args, **kwargs):
        raise FloatingPointError("forced numerical failure")

    monkeypatch.setattr(botorch.optim.fit, "fit_gpytorch_mll_scipy", broken)
    c = critic("turbo", 0, True)
    with caplog.at_level("WARNING", logger="latentune.critic"):
        run(c, 45)
    st = c.stats()
    assert st["n_fit_failed"] == st["n_fits"] >= 2, st
    inner = st["inner_stats"]
    assert inner["n_fit_failed"] == inner["n_fits"] >= 2, inner
    by_logger = [r.name for r in caplog.records if r.levelname == "WARNING"]
    assert sorted(by_logger) == ["latentune.critic.fall_model", "latentune.critic.turbo"]
    assert c.best_y < np.inf          # the critic kept working on its starting hyperparameters


# ----------------------------------------------------------------------------- the interface
def test_fall_aware_reads_no_critic_internals():
    """The wrapper works through the critic protocol only: it names no concrete critic and
    reads no critic's internals (trust regions, design boxes, population)."""
    import ast
    import inspect

    import latentune.critic.fall_aware as fa

    tree = ast.parse(inspect.getsource(fa))
    names = {n.id for n in ast.walk(tree) if isinstance(n, ast.Name)}
    names |= {n.attr for n in ast.walk(tree) if isinstance(n, ast.Attribute)}
    modules = {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
    modules |= {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    assert not names & {"TurboM", "CMAES", "regions", "popsize", "design_box", "decode_tag",
                        "deepcopy", "hypers"}, names
    assert not any(m and m.split(".")[-1] in ("turbo", "cmaes", "random_search", "copy")
                   for m in modules), modules


class _Oracle(FallModel):
    """A fall model that knows the problem's fall region (a user-supplied model)."""

    def __init__(self, dim: int) -> None:
        from latentune.critic.base import FitReport

        self.dim, self.fit_report, self.n_fit = dim, FitReport("oracle", None), 0

    def fit(self, X, fell):
        self.n_fit += 1
        return True

    @property
    def active(self):
        return True

    def p_fall(self, X, kappa=0.0):
        return problem(X)[1].astype(float)


@pytest.mark.parametrize("method", ["random", "turbo", "cma"])
def test_any_fall_model_plugs_in(method):
    """A FallModel given to FallAware screens every critic from the first ask."""
    model = _Oracle(3)
    c = critic(method, 0, True, batch=5, model=model)
    falls, _ = run(c, 40)
    assert falls == 0 and model.n_fit > 0
    assert c.n_screened > 0
    with pytest.raises(ValueError):
        FallAware(make_critic("random", 3), prior_X=np.zeros((2, 3)),
                  prior_fell=np.array([True, False]), model=model).fall_prob(np.zeros((1, 3)))
    with pytest.raises(ValueError):
        FallAware(make_critic("random", 3), model=GPFallModel(2))


def test_fall_model_upper_bound_prior_and_determinism():
    rng = np.random.default_rng(4)
    X = rng.random((80, 3))
    f = problem(X)[1]
    a, b = GPFallModel(3), GPFallModel(3)
    assert a.fit(X, f) and b.fit(X, f)
    T = rng.random((200, 3))
    np.testing.assert_array_equal(a.p_fall(T), b.p_fall(T))          # a function of the data
    assert np.all(a.p_fall(T, kappa=2.0) >= a.p_fall(T))
    assert a.fit_report.as_dict() == {"n_fits": 1, "n_fit_failed": 0}
    a.fit(X, f)
    assert a.fit_report.n_fits == 1                                     # same data: no refit
    pr = GPFallModel(3)
    pr.set_prior(X, f)                                                  # prior only: active
    assert pr.fit(np.empty((0, 3)), np.empty(0, bool))
    p = pr.p_fall(np.array([[0.95, 0.95, 0.5], [0.1, 0.1, 0.5]]))
    assert p[0] > 0.7 and p[1] < 0.2


# ----------------------------------------------------------------------------- stored runs
@pytest.mark.parametrize("method", ["turbo", "cma", "random"])
def test_stored_runs_of_the_hand_written_classifier_resume(method):
    """Runs stored before the fall model moved behind the critic protocol (histories and
    state_dict written by commit 728b357) resume: the inner critic replays the same state and
    asks valid points."""
    import json
    from pathlib import Path

    data = json.loads((Path(__file__).parent / "data" / "fall_aware_v1.json").read_text())
    r = data["runs"][method]
    c = FallAware(make_critic(method, 3, **r["kw"]), prior_X=np.array(r["prior_X"]),
                  prior_fell=np.array(r["prior_fell"]))
    c.tell(np.array(r["X"]), np.array(r["y"]), np.array(r["tags"]), fell=np.array(r["fell"]))
    c.load_state_dict(r["state"])
    if method == "turbo":
        assert c.inner.region_state() == r["region_state"]
    assert c.n_told == c.inner.n_told == len(r["X"])
    X = c.ask()
    assert X.shape == (4, 3) and np.all((X >= 0) & (X <= 1))
    assert np.all(c.last_fall_prob <= c.max_fall_prob)
    c.tell(X, problem(X)[0], c.last_tags, fell=problem(X)[1])
    assert c.n_told == len(r["X"]) + 4


def test_ask_latency_measures_the_fall_model_against_none(tmp_path, monkeypatch):
    """``benchmarks.ask_latency --max-fall-prob`` (tiny): two studies on a cost with falls, one
    whose critic screens with a fall model fitted on both classes, one whose critic has none;
    the output holds both studies' timed asks and tells and their ratios. The timed ``ask`` and
    ``tell`` commands run in this process (``latentune.cli.main``), not in new ones: what is
    checked is the benchmark's bookkeeping, and ten interpreter starts would be most of the
    test's time (the commands in a new process are the CLI tests')."""
    import contextlib
    import io
    import json
    import time
    from pathlib import Path

    from latentune.cli import main as cli_main

    root = Path(__file__).resolve().parents[1]
    monkeypatch.syspath_prepend(str(root))
    from benchmarks import ask_latency

    import latentune as lt
    from latentune.pipeline.loop import phase_critic
    from latentune.pipeline.phases import replay

    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.setattr(ask_latency.tempfile, "mkdtemp", lambda prefix="": str(work))

    def cli_seconds(*args: str) -> tuple[float, str]:
        t, buf = time.perf_counter(), io.StringIO()
        with contextlib.redirect_stdout(buf):
            assert cli_main(list(args)) == 0, args
        return time.perf_counter() - t, buf.getvalue()

    monkeypatch.setattr(ask_latency, "cli_seconds", cli_seconds)
    monkeypatch.setattr(ask_latency, "python_seconds", lambda code: 0.0)
    out = tmp_path / "o.json"
    assert ask_latency.main(["--told", "12", "--dim", "4", "--repeats", "1",
                             "--max-fall-prob", "0.3", "--out", str(out)]) == 0
    res = json.loads(out.read_text())
    studies = res["studies"]
    assert set(studies) == {"plain", "fall model"}
    for name, s in studies.items():
        assert s["n_fell"] > 0, name                       # falls in the data
        for mode in ("prepared", "cold"):
            assert len(s[mode]["ask"]["s"]) == len(s[mode]["tell"]["s"]) == 1
    ratio = res["ratio_fall_model_over_plain"]["cold ask median"]
    assert ratio == pytest.approx(studies["fall model"]["cold"]["ask"]["median_s"]
                                  / studies["plain"]["cold"]["ask"]["median_s"])
    for name, screens in (("plain", False), ("fall_model", True)):
        with lt.Study(work / name) as st:
            pc = st.manifest.config()["phase1"]
            crit = phase_critic(1, pc, st.manifest.space(), st.dir)
            replay(st.store, 1, crit)
            assert isinstance(crit, FallAware) == screens, name
            if screens:                                      # fitted on both classes
                assert pc["max_fall_prob"] == 0.3
                assert crit.fall_prob(np.full((1, 4), 0.5)) is not None


def test_a_study_resumes_to_the_uninterrupted_run_after_its_fall_prior_grew(tmp_path):
    """A fall prior (or optuna-cmaes's source run) is read again on resume: once the prior run
    had more trials, the resumed phase asked other θ than the run never stopped. The phase
    records how many trials it began with (``prior_counts``) and a resume reads those."""
    import latentune as lt

    sp = lt.ParameterSpace(["a", "b", "c"], [0] * 3, [1] * 3, manual=[0.5] * 3)

    def fn(x):
        y, fell = problem(x)
        return float(y[0]), bool(fell[0])

    system = lt.FunctionSystem(sp, fn, name="fall3")
    with lt.Study(tmp_path / "prior", seed=1) as st:
        st.phase1(system, 12, method="random")
    runs = {}
    for name, stop in (("whole", None), ("resumed", 8)):
        with lt.Study(tmp_path / name) as st:
            st.phase1(system, 20, max_fall_prob=0.3, fall_prior=tmp_path / "prior",
                      max_new=stop)
    with lt.Study(tmp_path / "prior") as st:
        st.phase1(system, 30, method="random")          # the prior grows meanwhile
    for name in ("whole", "resumed"):
        with lt.Study(tmp_path / name) as st:
            st.phase1(system, 20, max_fall_prob=0.3, fall_prior=tmp_path / "prior")
            runs[name] = np.array([r.theta for r in st.store.rows(1)])
            assert st.config()["phase1"]["prior_counts"] == {"1": 12, "3": 0}
    np.testing.assert_array_equal(runs["resumed"], runs["whole"])
