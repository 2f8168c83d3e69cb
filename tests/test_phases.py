"""The phase loop (latentune.pipeline.phases): identity and resume, exact resume of TuRBO-m,
a run stopped in the middle of a batch resumed to the uninterrupted run (TuRBO-m and Optuna's
samplers), independence of the completion order, the training set, phase 3 through a
decoder."""
from __future__ import annotations

import numpy as np
import pytest

from latentune.pipeline.store import RunStore


def quad(x: np.ndarray) -> float:
    return float(np.sum((np.asarray(x) - 0.3) ** 2) * 100)


def test_phase_identity_and_resume(tmp_path):
    from latentune.pipeline.evaluators import SerialEvaluator
    from latentune.pipeline.phases import make_phase_critic, run_phase

    def critic():
        return make_phase_critic("turbo", 6, 4, 0, np.full(6, 0.5), 30, regions=1)

    with RunStore(tmp_path / "r", create=True) as st:
        r = run_phase(st, 1, quad, critic(), 30, SerialEvaluator(), max_new=14)
        assert r.n == 14 and r.n_new == 14
        np.testing.assert_allclose(st.rows(1)[0].theta, 0.5)      # starts from x0
        r = run_phase(st, 1, quad, critic(), 30, SerialEvaluator())   # resume
        assert r.n == 30 and r.n_new == 16
        rows = st.rows(1)
        assert [x.idx for x in rows] == list(range(30))
        assert all(x.z is None for x in rows)
        assert r.best_cost == min(x.cost for x in rows) < quad(np.full(6, 0.5))
        r = run_phase(st, 1, quad, critic(), 30, SerialEvaluator())    # nothing left to do
        assert r.n_new == 0


def _critic60():
    from latentune.pipeline.phases import make_phase_critic

    return make_phase_critic("turbo", 6, 4, 0, None, 60, regions=2)


def _thetas(st: RunStore) -> np.ndarray:
    return np.array([r.theta for r in st.rows(1)])


@pytest.fixture(scope="module")
def whole_run(tmp_path_factory) -> np.ndarray:
    """θ (60, 6) of an uninterrupted serial 60-evaluation TuRBO-m phase (shared: the reference
    of the resume and completion-order tests)."""
    from latentune.pipeline.evaluators import SerialEvaluator
    from latentune.pipeline.phases import run_phase

    with RunStore(tmp_path_factory.mktemp("whole") / "run", create=True) as st:
        run_phase(st, 1, quad, _critic60(), 60, SerialEvaluator())
        return _thetas(st)


def test_a_resumed_turbo_run_is_the_uninterrupted_run(tmp_path, whole_run):
    """The store keeps TuRBO-m's warm-started GP hyperparameters (its state_dict) after every
    batch, so a run stopped between batches and resumed asks exactly the points of a run that
    was never stopped; without that state it would not (the hyperparameters are refitted cold)."""
    from latentune.pipeline.evaluators import SerialEvaluator
    from latentune.pipeline.phases import run_phase, state_key

    with RunStore(tmp_path / "resumed", create=True) as st:
        for stop in (20, 36, 60):
            run_phase(st, 1, quad, _critic60(), 60, SerialEvaluator(), max_new=stop - st.count(1))
        np.testing.assert_array_equal(_thetas(st), whole_run)
    with RunStore(tmp_path / "stateless", create=True) as st:
        run_phase(st, 1, quad, _critic60(), 60, SerialEvaluator(), max_new=36)
        st.set_meta(state_key(1), {})
        run_phase(st, 1, quad, _critic60(), 60, SerialEvaluator(), max_new=8)   # two batches
        theta = _thetas(st)
        np.testing.assert_array_equal(theta[:36], whole_run[:36])
        assert not np.array_equal(theta[36:44], whole_run[36:44])


class _Killed(BaseException):
    """The process dying (not an Exception: nothing in the loop handles it)."""


class _DyingEvaluator:
    """Serial, and "dies" (raises :class:`_Killed`) when asked for a result after ``after`` of
    them: mid-batch, or after a batch's last trial is stored but before it is told."""

    def __init__(self, after: int) -> None:
        self.left = after

    def imap(self, fun, X):
        from latentune.system import Outcome

        for i, x in enumerate(X):
            if self.left == 0:
                raise _Killed
            self.left -= 1
            yield i, Outcome(fun(x))
        if self.left == 0:
            raise _Killed


def _stopped_and_resumed(path, critic, budget: int, after: int) -> np.ndarray:
    """θ of a phase killed by :class:`_DyingEvaluator` after ``after`` trials, then resumed."""
    from latentune.pipeline.evaluators import SerialEvaluator
    from latentune.pipeline.phases import batch_key, run_phase

    with RunStore(path, create=True) as st:
        with pytest.raises(_Killed):
            run_phase(st, 1, quad, critic(), budget, _DyingEvaluator(after))
        assert st.count(1) == after and st.get_meta(batch_key(1))    # the batch is recorded
        run_phase(st, 1, quad, critic(), budget, SerialEvaluator())
        assert st.get_meta(batch_key(1)) is None
        return _thetas(st)


@pytest.mark.parametrize("after", [22, 24])
def test_a_turbo_run_killed_mid_batch_resumes_to_the_uninterrupted_run(tmp_path, whole_run,
                                                                       after):
    """Killed with two of a batch's four trials stored (22), or all four stored and not told
    (24): the resume asks the recorded batch again (TuRBO-m's GP fits happen in the ask),
    runs its missing points and continues as the uninterrupted run."""
    np.testing.assert_array_equal(
        _stopped_and_resumed(tmp_path / "r", _critic60, 60, after), whole_run)


@pytest.mark.parametrize("method", ["optuna-tpe", "optuna-cmaes", "optuna-gp"])
def test_an_optuna_run_killed_mid_batch_resumes_to_the_uninterrupted_run(tmp_path, method):
    """Optuna's samplers: a stop after 10 of 24 trials (two of the third batch's four) resumes
    to the θ of the run that was never stopped (before the batch was recorded, the resumed
    critic told the two stored trials and asked the lost ones again, after them: other θ)."""
    pytest.importorskip("optuna")
    from latentune.pipeline.evaluators import SerialEvaluator
    from latentune.pipeline.phases import make_phase_critic, run_phase

    def critic():
        return make_phase_critic(method, 6, 4, 0, np.full(6, 0.5), 24)

    with RunStore(tmp_path / "whole", create=True) as st:
        run_phase(st, 1, quad, critic(), 24, SerialEvaluator())
        whole = _thetas(st)
    np.testing.assert_array_equal(_stopped_and_resumed(tmp_path / "r", critic, 24, 10), whole)


class _ReversedEvaluator:
    """Yields each batch's results last-first, as workers that finish out of order would."""

    def imap(self, fun, X):
        from latentune.system import Outcome

        return reversed([(i, Outcome(fun(x))) for i, x in enumerate(X)])


def test_phase_same_seed_same_run_whatever_the_completion_order(tmp_path, whole_run):
    from latentune.pipeline.phases import run_phase

    with RunStore(tmp_path / "reversed", create=True) as st:
        run_phase(st, 1, quad, _critic60(), 60, _ReversedEvaluator())
        rev = sorted(tuple(r.theta) for r in st.rows(1))
    assert len(rev) == 60 and rev == sorted(tuple(t) for t in whole_run)


def test_a_run_whose_workers_finish_out_of_order_resumes_to_the_uninterrupted_run(tmp_path,
                                                                                 whole_run):
    """Rows are stored as the workers finish, a row out of ask order with the index it was
    asked at, so a resume tells the critic its batches in the order it was told them (told in
    completion order, it asked other θ), stopped between batches (36) or in one (22); the
    rows keep their indices."""
    from latentune.pipeline.phases import ASKED, run_phase, told_order

    with RunStore(tmp_path / "r", create=True) as st:
        for stop in (22, 36, 60):
            run_phase(st, 1, quad, _critic60(), 60, _ReversedEvaluator(),
                      max_new=stop - st.count(1))
        rows = st.rows(1)
        np.testing.assert_array_equal([r.theta for r in told_order(rows)], whole_run)
        assert [r.idx for r in rows] == list(range(60))
        assert rows[3].info[ASKED] == 0                 # the first batch, stored reversed


def test_training_set_does_not_depend_on_completion_order(tmp_path):
    from latentune.pipeline.phases import training_set

    rng = np.random.default_rng(0)
    X, y = rng.random((20, 5)), np.where(rng.random(20) < 0.3, 150.0, 10.0)
    sets = []
    for name, order in (("a", np.arange(20)), ("b", rng.permutation(20))):
        with RunStore(tmp_path / name, create=True) as st:
            for idx, i in enumerate(order):
                st.add(1, idx, X[i], float(y[i]), fell=bool(y[i] >= 100))
            sets.append(training_set(st))
    assert sets[0].shape == (int((y < 100).sum()), 5)      # the trials that did not fall
    np.testing.assert_array_equal(sets[0], sets[1])


def test_phase_with_decoder_and_task(tmp_path):
    from latentune.pipeline.evaluators import SerialEvaluator
    from latentune.pipeline.phases import ensure_manual, make_phase_critic, run_phase
    from latentune.task import Task

    task = Task("a1", "trot", steps=150)
    d = task.space.dim
    W = np.random.default_rng(0).normal(size=(3, d))
    man = task.space.manual

    def decoder(U):        # a fixed 3-dim "latent space" around the manual θ
        return np.clip(man + 0.1 * (np.atleast_2d(U) - 0.5) @ W, 0, 1)

    crit = make_phase_critic("random", 3, 3, 0, None, 6)
    with RunStore(tmp_path / "r", create=True) as st:
        assert ensure_manual(st, task) == st.rows(0)[0].cost
        r = run_phase(st, 3, task, crit, 6, SerialEvaluator(), decoder=decoder)
        rows = st.rows(3)
        assert r.n == 6 and len(rows) == 6
        for row in rows:
            assert row.z.shape == (3,) and row.theta.shape == (d,)
            np.testing.assert_allclose(row.theta, decoder(row.z)[0])
            assert row.wall_s > 0 and row.fell == (row.cost >= 100)


def _falls_right(x: np.ndarray):
    import latentune as lt

    return lt.Outcome(None, failed=True) if x[0] > 0.5 else float(np.sum(x ** 2))


def _one_fall_critic():
    """Random search with a fall budget of one fall (the transfer critic's protocol)."""
    from latentune.critic.random_search import RandomSearch

    class OneFall(RandomSearch):
        def falls_allowed(self) -> int:
            return 1

        def fall_budget_spent_after(self, fell: np.ndarray) -> bool:
            return int(self._fell.sum()) + int(np.sum(fell)) >= 1

        @property
        def fall_budget_spent(self) -> bool:
            return self.fall_budget_spent_after(np.zeros(0, dtype=bool))

    return OneFall(3, batch_size=4, seed=3)


class _KilledAfter:
    """Serial, and "dies" (raises :class:`_Killed`) when asked for a trial after ``after``
    results, whatever its ``stop`` says."""

    def __init__(self, after: int) -> None:
        self.left = after

    def imap(self, fun, X, stop=None):
        from latentune.pipeline.evaluators import run_trial

        for i, x in enumerate(X):
            if self.left == 0:
                raise _Killed
            self.left -= 1
            yield i, run_trial(fun, None, x)


def test_a_phase_starts_no_trial_of_its_batch_once_its_fall_budget_is_spent(tmp_path):
    """A critic with a fall budget (one fall) whose batch's second trial fell: the phase ran
    the batch's third and fourth trials before it stopped. It now stops at the fall (the
    rest of the batch not run, recorded, the critic told the two), and a run killed right
    after the fall resumes to the same stop without running them."""
    import latentune as lt
    from latentune.pipeline.evaluators import SerialEvaluator
    from latentune.pipeline import phases
    from latentune.pipeline.phases import batch_key, run_phase

    sys_ = lt.FunctionSystem(lt.ParameterSpace(["a", "b", "c"], [0.0] * 3, [1.0] * 3),
                             _falls_right)
    asked = _one_fall_critic().ask(4)
    assert [bool(x > 0.5) for x in asked[:, 0]] == [False, True, False, False]
    with RunStore(tmp_path / "whole", create=True) as st:
        res = run_phase(st, 1, sys_, _one_fall_critic(), 12, SerialEvaluator())
        assert res.n == 2 and res.not_run == 2, res
        np.testing.assert_array_equal(_thetas(st), asked[:2])
        assert st.get_meta(phases.fall_stop_key(1)) == {"n": 2, "not_run": 2}
        assert st.get_meta(batch_key(1)) is None
    with RunStore(tmp_path / "killed", create=True) as st:
        with pytest.raises(_Killed):
            run_phase(st, 1, sys_, _one_fall_critic(), 12, _KilledAfter(2))
        assert st.count(1) == 2 and st.get_meta(batch_key(1))
        res = run_phase(st, 1, sys_, _one_fall_critic(), 12, SerialEvaluator())
        assert (res.n, res.n_new, res.not_run) == (2, 0, 2), res
        np.testing.assert_array_equal(_thetas(st), asked[:2])
