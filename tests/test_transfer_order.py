"""The transfer critic uses its source as a set (``source_order="canonical"``): the order a
parallel phase 1 stored its trials in does not change what phase 3 asks."""
from __future__ import annotations

import numpy as np
import pytest

from latentune.critic.transfer import (ADDED_OPTIONS, TRANSFER_DEFAULTS, Transfer, canonical_order,
                                      resolved_options)

from test_transfer import D, _bowl, source  # noqa: F401 - shared fixtures


def _asks(src, perm: np.ndarray, n: int = 7, **kw) -> np.ndarray:
    """(n, D) what a critic fitted on the source rows in order ``perm`` asks (no stored hypers:
    it fits its source models itself)."""
    X, y, f, c = src
    cr = Transfer((X[perm], y[perm], f[perm]), None, None, batch_size=1, seed=5, max_points=60,
                  **kw)
    for _ in range(n):
        th = cr.ask(1)
        yy, ff = _bowl(th, np.full(D, 0.45), 0.6)
        cr.tell(th, yy, cr.last_tags, fell=ff)
    return cr.X


def _swapped_pairs(n: int) -> np.ndarray:
    """A permutation that swaps rows 2↔3, 4↔5, … as two workers finishing a batch out of order
    store them."""
    p = np.arange(n)
    for i in range(2, n - 1, 2):
        p[i], p[i + 1] = p[i + 1], p[i]
    return p


def test_canonical_order_sorts_a_set_the_same_way_whatever_its_order():
    rng = np.random.default_rng(1)
    X = rng.random((50, 4))
    y = rng.random(50).round(1)                      # ties in cost, broken by fell then θ
    f = rng.random(50) < 0.3
    o = canonical_order(X, y, f)
    assert np.all(np.diff(y[o]) >= 0)
    p = rng.permutation(50)
    q = canonical_order(X[p], y[p], f[p])
    assert np.array_equal(X[p][q], X[o]) and np.array_equal(y[p][q], y[o])


def test_the_order_of_the_source_does_not_change_the_asks(source):
    assert TRANSFER_DEFAULTS["source_order"] == "canonical"
    n = source[0].shape[0]
    same = np.arange(n)
    a = _asks(source, same)
    assert np.array_equal(a, _asks(source, _swapped_pairs(n)))
    assert np.array_equal(a, _asks(source, np.random.default_rng(2).permutation(n)))


def test_stored_order_is_the_behaviour_of_runs_before_the_option():
    assert ADDED_OPTIONS["source_order"] == "stored"


def test_stored_order_uses_the_rows_as_given(source):
    """With ``source_order="stored"`` the fitted subset follows the rows' order: a permuted
    source asks other θ (what made parallel sources irreproducible)."""
    n = source[0].shape[0]
    perm = np.random.default_rng(2).permutation(n)
    a = _asks(source, np.arange(n), source_order="stored")
    b = _asks(source, perm, source_order="stored")
    assert not np.allclose(a, b)


def test_an_unknown_source_order_is_refused(source):
    X, y, f, _ = source
    with pytest.raises(ValueError, match="source_order"):
        Transfer((X, y, f), None, None, source_order="sorted")


def _own_run(tmp, name: str, X: np.ndarray, y: np.ndarray, order: np.ndarray):
    """A run directory whose phase-1 rows are (X, y) stored in ``order`` (as a parallel phase 1
    stores a batch in completion order)."""
    from latentune.constants import Phase
    from latentune.pipeline.store import RunStore

    d = tmp / name
    d.mkdir()
    with RunStore(d, create=True) as st:
        for i, j in enumerate(order):
            st.add(Phase.PHASE1, i, X[j], float(y[j]), fell=bool(y[j] > 30))
    return d


def test_phase3_on_its_own_source_is_the_same_whatever_order_phase1_stored(tmp_path, source):
    """The pipeline's own-task phase 3 (``latentune tune``) tells the critic the source's best
    trials and elites as target data: with rows swapped in pairs it asks the same θ."""
    from latentune.pipeline.loop import transfer_critic
    from latentune.space import ParameterSpace

    X, y, _, _ = source
    n = len(y)
    space = ParameterSpace([f"w{i}" for i in range(D)], np.zeros(D), np.ones(D))
    pc = {"batch_size": 1, "seed": 2, "max_fall_prob": None}
    asked, told = [], []
    for name, order in (("a", np.arange(n)), ("b", _swapped_pairs(n))):
        d = _own_run(tmp_path, name, X, y, order)
        cr = transfer_critic(pc, space, d, d, None)
        told.append(cr.X.copy())                # the source rows told as target data
        cr.opts["max_points"] = 60
        for _ in range(4):
            th = cr.ask(1)
            yy, ff = _bowl(th, np.full(D, 0.45), 0.6)
            cr.tell(th, yy, cr.last_tags, fell=ff)
        asked.append(cr.X[-4:])
    assert len(told[0]) > 0 and np.array_equal(told[0], told[1])
    assert np.array_equal(asked[0], asked[1])


def test_stored_options_are_what_a_stored_run_resumes_with():
    """A state recorded before ``source_order`` and ``explore_falls`` existed resumes with their
    old behaviour; a state recorded before options were recorded resumes with the legacy set;
    a state of another critic has none."""
    from latentune.critic.transfer import LEGACY_OPTIONS, stored_options

    old = {k: v for k, v in TRANSFER_DEFAULTS.items() if k not in ("source_order",
                                                                     "explore_falls")}
    o = stored_options({"options": old})
    assert (o["source_order"], o["explore_falls"]) == ("stored", 0)
    assert {k: o[k] for k in old} == old
    assert stored_options({"options": dict(TRANSFER_DEFAULTS)}) == TRANSFER_DEFAULTS
    assert stored_options({"last_decision": {}}) == LEGACY_OPTIONS
    assert stored_options({"regions": []}) is None


def test_paper_report_names_the_seeds_that_did_not_run_todays_default():
    from latentune.reporting.paper_report import _options_note

    today = resolved_options({})        # as a run stores them: explore_fall_prob resolved
    old = {**today, "explore_falls": 0}
    arm = {"seeds": [0, 1, 2, 3], "options": [old, dict(today), old, None]}
    note = _options_note(arm)
    assert "seeds 0, 2: `explore_falls=0` (default 3)" in note
    assert "1" not in note.split("differ here:")[1].replace("0, 2", "")
    assert _options_note({"seeds": [0], "options": [dict(today)]}) == ""
    # a row of the default before session 39 is named; today's default at another
    # max_fall_prob is judged against that bound's explore_fall_prob (⅔ of it)
    s38 = {**today, "explore_gp": False, "explore_fall_prob": 0.0}
    assert "`explore_fall_prob=0.0` (default 0.2)" in _options_note({"seeds": [5],
                                                                    "options": [s38]})
    loose = resolved_options({"max_fall_prob": 0.6})
    assert loose["explore_fall_prob"] == 0.4
    assert _options_note({"seeds": [0], "options": [loose]}) == \
        "Not today's default: the default phase 3's rows stored before an option existed " \
        "resume with the options they ran with, which differ here: seed 0: " \
        "`max_fall_prob=0.6` (default 0.3)."
    assert _options_note(None) == ""
