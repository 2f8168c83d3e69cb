"""Ask/tell on the one phase loop: the same rows as a phase run, options and seed from the
store, several askers with leases, status, amendments, trials as data, failing phases."""
from __future__ import annotations

import contextlib
import inspect
import json
import logging
import math
import multiprocessing as mp
import os
import re
import shutil
import sqlite3
import time
from pathlib import Path
from typing import Any, Iterator

import numpy as np
import pytest

import latentune as lt
from latentune.constants import C1, Phase
from latentune.errors import LatentuneError, StoreError, UsageError
from latentune.pipeline import asktell, phases
from latentune.pipeline import store as store_module
from latentune.pipeline.asktell import write_suggestion_files
from latentune.pipeline.loop import phase_critic
from latentune.pipeline.phases import FAIL_STREAK, replay, state_key
from latentune.pipeline.store import RunStore
from latentune.system import evaluate

SPACE = lt.ParameterSpace(["a", "b", "c", "d"], [-1.0] * 4, [1.0] * 4, manual=[0.5] * 4)


def plant_fn(x: np.ndarray, shift: float = 0.0):
    """A quadratic with a fall region (a > 0.6, physical)."""
    if x[0] > 0.6:
        return lt.Outcome(None, failed=True, info={"reason": "a too big"})
    return float(np.sum((x - 0.2 - shift) ** 2))


def plant(shift: float = 0.0) -> lt.FunctionSystem:
    return lt.FunctionSystem(SPACE, lambda x: plant_fn(x, shift))


def all_fail(x: np.ndarray):
    return lt.Outcome(None, failed=True)


def rows_of(study: lt.Study, phase: int) -> list[tuple]:
    return [(r.theta.tobytes(), r.cost, r.fell) for r in study.store.rows(phase)]


def person(study: lt.Study, plant_: lt.FunctionSystem, n_trials: int, **ask_kw) -> None:
    """A person asking one suggestion at a time and telling its result."""
    for _ in range(n_trials):
        (s,) = study.ask(**ask_kw)
        out = evaluate(plant_, s.theta)
        study.tell(s.id, out.cost, failed=out.failed)


@pytest.fixture(scope="module")
def src30(tmp_path_factory) -> Path:
    """A source run of the plant: phase 1 (30, seed 0) and a 2-d latent space. Tests copy it."""
    d = tmp_path_factory.mktemp("src30") / "src"
    with lt.Study(d, seed=0) as src:
        src.phase1(plant(), 30)
        src.train_latent(latent_dim=2, epochs=30)
    return d


# ---------------------------------------------------------------------------- one loop
def test_ask_tell_gives_the_rows_of_the_phase_run_with_fall_avoidance(tmp_path):
    sys_ = plant()
    with lt.Study(tmp_path / "run", seed=2) as run:
        run.phase1(sys_, 20, max_fall_prob=0.4)
    with lt.Study(tmp_path / "ask", seed=2) as at:
        person(at, sys_, 20, system=sys_, max_fall_prob=0.4, budget=20)
        cfg = at.config()
    assert cfg["phase1"]["max_fall_prob"] == 0.4 and cfg["phase1"]["start"] == "manual"
    with lt.Study(tmp_path / "run") as run, lt.Study(tmp_path / "ask") as at:
        assert rows_of(at, Phase.PHASE1) == rows_of(run, Phase.PHASE1)
        assert sum(f for _, _, f in rows_of(at, Phase.PHASE1)) > 0        # falls were seen


def test_ask_tell_phase3_with_handover_and_start_gives_the_rows_of_the_phase_run(tmp_path):
    with lt.Study(tmp_path / "src", seed=1) as src:
        src.phase1(plant(), 40)
        src.train_latent(latent_dim=2, epochs=40)
    target = plant(0.2)
    start = np.full(4, 0.4)
    opts = {"patience": 6}
    with lt.Study(tmp_path / "run", seed=1) as run:
        run.phase3(target, 24, latent=tmp_path / "src", handover=opts, start=start,
                   max_fall_prob=0.5)
        hand_run = run.config()["phase3_handover"]["handover_at"]
    with lt.Study(tmp_path / "ask", seed=1) as at:
        first = at.ask(system=target, phase=3, latent=tmp_path / "src", handover=opts,
                       start=start, max_fall_prob=0.5, budget=24)[0]
        assert first.phase == Phase.ZERO_SHOT and first.phase_name == "zero-shot"
        out = evaluate(target, first.theta)
        at.tell(first.id, out.cost, failed=out.failed)
        person(at, target, 24)                 # later asks take every option from the store
        assert at.config()["phase3_handover"]["handover_at"] == hand_run
        with pytest.raises(StoreError, match="budget of 24 trials is told"):
            at.ask()
    with lt.Study(tmp_path / "run") as run, lt.Study(tmp_path / "ask") as at:
        assert rows_of(at, Phase.PHASE3) == rows_of(run, Phase.PHASE3)
        assert rows_of(at, Phase.ZERO_SHOT) == rows_of(run, Phase.ZERO_SHOT)
    assert hand_run is not None


def test_a_reopened_study_takes_its_seed_and_options_from_the_store(tmp_path):
    d = tmp_path / "s"
    a = lt.Study(d, seed=7)
    s1 = a.ask(2, space=SPACE, method="cma", budget=30)
    a.close()
    b = lt.Study(d)                                    # no seed: the stored one
    assert b.seed == 7
    with pytest.raises(StoreError, match="seed = 7, not 3"):
        lt.Study(d, seed=3)
    for kw, stored in ((dict(method="turbo"), "'cma'"), (dict(max_fall_prob=0.2), "None"),
                       (dict(budget=10), "30"), (dict(phase=3), "phase 1"),
                       (dict(start=[0.1] * 4), "'manual'")):
        with pytest.raises(StoreError, match=stored) as e:
            b.ask(**kw)
        assert "\n" not in str(e.value)
    with pytest.raises(LatentuneError, match="handover is an option of phase 3"):
        b.ask(handover=True)
    with pytest.raises(LatentuneError, match="latent space is an option of phase 3"):
        b.ask(latent=tmp_path)
    again = b.ask(2)                                   # the same asker: its pending ones again
    assert [s.id for s in again] == [s.id for s in s1] and all(s.again for s in again)
    grown = b.ask(3, budget=40)                        # a budget may grow
    assert grown[2].id not in {s.id for s in s1} and b.config()["phase1"]["budget"] == 40
    b.close()
    # the same suggestions as a study created with that seed
    with lt.Study(tmp_path / "control", seed=7) as c:
        ctl = c.ask(3, space=SPACE, method="cma", budget=30)
    np.testing.assert_array_equal([s.theta for s in ctl], [s.theta for s in grown])


# ---------------------------------------------------------------------------- one θ, one trial
MANUAL_BEST = lt.ParameterSpace(["a", "b", "c", "d"], [-1.0] * 4, [1.0] * 4, manual=[0.0] * 4)
"""A space whose manual θ (0.5 in the unit box) is the optimum of :func:`bowl` without a shift:
a source's phase 1 never beats it, so the source's best θ (the zero-shot θ) is the manual θ."""


def bowl(shift: float = 0.0, ran: list | None = None) -> lt.FunctionSystem:
    """A quadratic about ``shift`` on :data:`MANUAL_BEST` that adds every θ it runs (physical)
    to ``ran``."""
    def fn(x: np.ndarray) -> float:
        if ran is not None:
            ran.append(tuple(np.round(x, 12)))
        return float(np.sum((x - shift) ** 2))
    return lt.FunctionSystem(MANUAL_BEST, fn)


@pytest.fixture(scope="module")
def src_manual_best(tmp_path_factory) -> Path:
    """A source run whose best θ is the manual θ: phase 1 (12, seed 0) of :func:`bowl` and a
    2-d latent space (300 epochs: fewer leave it decoding every code to about one θ). Tests
    copy it."""
    d = tmp_path_factory.mktemp("srcmb") / "src"
    with lt.Study(d, seed=0) as src:
        src.phase1(bowl(), 12)
        src.train_latent(latent_dim=2, epochs=300)
    return d


@pytest.fixture
def decodes_manual(monkeypatch) -> None:
    """A decoder that gives the manual θ exactly for codes it decodes near it (within 0.06 of
    it in every unit-box entry): a latent space whose decoded start is the manual θ itself."""
    from latentune.latent.vae import LatentSpace

    orig = LatentSpace.decode_code

    def snapped(self, z):
        th = orig(self, z)
        near = np.all(np.abs(np.atleast_2d(th) - 0.5) < 0.06, axis=1)
        out = np.atleast_2d(th).copy()
        out[near] = 0.5
        return out[0] if np.ndim(th) == 1 else out
    monkeypatch.setattr(LatentSpace, "decode_code", snapped)


def plain_by_asktell(d: Path, src: Path, target_ran: list, n: int, budget: int = 6) -> lt.Study:
    """A person running the plain phase 3 of ``d`` on :func:`bowl` (0.1) by ask/tell, one
    suggestion at a time: the zero-shot trial, then phase-3 trials, ``n`` in all."""
    target = bowl(0.1, target_ran)
    with lt.Study(d, seed=1) as at:
        for i in range(n):
            kw = dict(system=target, phase=3, latent=src, strategy="plain",
                      budget=budget) if i == 0 else {}
            try:
                (s,) = at.ask(**kw)
            except StoreError:          # the budget is told
                break
            out = evaluate(target, s.theta)
            at.tell(s.id, out.cost, failed=out.failed)
    return lt.Study(d)


def test_the_plain_phase_3_runs_the_manual_theta_once_when_it_is_the_sources_best(
        tmp_path, src_manual_best, decodes_manual, caplog):
    """``Study.phase3(strategy="plain")`` ran the manual θ (phase 0), then the source's best θ
    as the zero-shot trial, then the decoded start of the search: the same θ three times on
    the target when the source's best is the manual θ and the start decodes to it. It runs it
    once: the zero-shot trial and the start are stored with its outcome (``info["reused"]``,
    said at INFO), and the start's row counts in phase 3's budget."""
    shutil.copytree(src_manual_best, tmp_path / "src")
    with lt.Study(tmp_path / "src") as src:
        assert np.array_equal(src.best().theta, MANUAL_BEST.manual)     # the premise
    ran: list = []
    caplog.set_level(logging.INFO, logger="latentune")
    with lt.Study(tmp_path / "run", seed=1) as run:
        res = run.phase3(bowl(0.1, ran), 6, latent=tmp_path / "src", strategy="plain")
        zs = run.store.rows(Phase.ZERO_SHOT)[0]
        p3 = run.store.rows(Phase.PHASE3)
    assert len(ran) == len(set(ran)), ran                          # no θ run twice
    assert ran.count(tuple(np.zeros(4))) == 1
    assert res.n == 6 and len(ran) == 1 + 6 - sum(bool(r.info.get("reused")) for r in p3)
    assert zs.info.get("reused") and np.array_equal(zs.theta, MANUAL_BEST.manual)
    assert p3[0].info.get("reused") and np.array_equal(p3[0].theta, MANUAL_BEST.manual)
    assert "not run again" in caplog.text


def test_status_report_and_summary_say_which_trials_were_not_run_again(
        tmp_path, src_manual_best, decodes_manual, run_cli):
    """The plain phase 3 stores its zero-shot trial and its decoded start with the manual θ's
    outcome (one trial on the target, three rows); status said "phase 3: 6 trials", the
    report "6 evaluations" and the three rows' falls as three, without a word that two were
    never run. The rows still count (the budget counts them), and status, report.md and
    summary.json say how many of each phase's trials repeat a stored trial."""
    shutil.copytree(src_manual_best, tmp_path / "src")
    with lt.Study(tmp_path / "run", seed=1) as run:
        run.phase3(bowl(0.1), 6, latent=tmp_path / "src", strategy="plain")
        st = run.status()
    assert st["phases"]["phase 3"]["reused"] == 1 and st["phases"]["zero-shot"]["reused"] == 1
    assert st["phases"]["manual"]["reused"] == 0 and st["phases"]["phase 3"]["n"] == 6
    code, out, err = run_cli("status", tmp_path / "run")
    assert code == 0, err
    assert "phase 3: 6 of 6 trials (1 repeats a stored trial, not run again), 0 failed" in out, out
    assert run_cli("report", tmp_path / "run", "--no-sim")[0] == 0
    md = (tmp_path / "run" / "report.md").read_text()
    assert ("Phase 3 (latent, TuRBO-m): 1 of its 6 trials repeats the θ of a stored trial, "
            "stored with that trial's outcome, not run again; the table counts it.") in md, md
    assert "Zero-shot (source best θ): its trial repeats the θ of a stored trial" in md, md
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert (summary["phase3_reused"], summary["phase3_evals"]) == (1, 6)


def test_an_amended_trial_corrects_the_rows_that_repeat_it(tmp_path, src_manual_best,
                                                          decodes_manual, run_cli):
    """Ask/tell's plain phase 3 stores its decoded start with the zero-shot trial's outcome
    (the same θ). Amending the zero-shot trial (0.04 → 3.0) left that row at 0.04: status and
    best named "best: 0.04 (phase 3, evaluation 0)", a cost the robot never gave for that θ.
    The rows that repeat an amended trial are corrected with it (their own amendment in the
    audit trail), and the critic is rebuilt from the corrected rows."""
    shutil.copytree(src_manual_best, tmp_path / "src")
    with plain_by_asktell(tmp_path / "at", tmp_path / "src", [], 4) as at:
        zs = at.store.rows(Phase.ZERO_SHOT)[0]
        start = at.store.rows(Phase.PHASE3)[0]
        assert start.info.get("same_as") == [int(Phase.ZERO_SHOT), 0]        # the premise
        at.tell(zs.info["trial"], 3.0, amend=True)
        start = at.store.rows(Phase.PHASE3)[0]
        assert (start.cost, start.fell) == (3.0, False)
        assert start.info["reused"] and start.info["same_as"] == [int(Phase.ZERO_SHOT), 0]
        assert {a["trial"] for a in at.amendments()} == {zs.info["trial"], start.info["trial"]}
        assert at.best().cost != 0.04 or at.best().phase != Phase.PHASE3
        at.tell(zs.info["trial"], 200.0, failed=True, amend=True)    # then: it fell
        assert at.store.rows(Phase.PHASE3)[0].fell
    code, out, err = run_cli("status", tmp_path / "at")
    assert code == 0, err
    assert "best: 0.04 (phase 3, evaluation 0" not in out, out
    code, out, err = run_cli("tell", tmp_path / "at", zs.info["trial"], "--cost", "2.5",
                             "--amend")
    assert code == 0, err
    assert out.strip() == (f"amended {zs.info['trial']}: zero-shot evaluation 0, cost 2.5; also "
                           f"amended: 1 copy: phase 3 evaluation 0 (suggestion "
                           f"{start.info['trial']}), stored from it"), out


def test_ask_tell_never_hands_out_a_told_theta_as_the_plain_phase_3s_start(
        tmp_path, src_manual_best, decodes_manual):
    """Ask/tell's plain phase 3 handed out the zero-shot θ (the source's best, here the manual
    θ), then its decoded start: the same θ, two trials on the robot. The start is stored with
    the zero-shot trial's outcome instead (a told row of phase 3, in its budget), and the
    first phase-3 suggestion is the next point of the design."""
    shutil.copytree(src_manual_best, tmp_path / "src")
    ran: list = []
    with plain_by_asktell(tmp_path / "at", tmp_path / "src", ran, 4) as at:
        p3 = at.store.rows(Phase.PHASE3)
    assert len(ran) == 4 and len(ran) == len(set(ran)), ran        # no θ handed out twice
    assert p3[0].info.get("reused") and np.array_equal(p3[0].theta, MANUAL_BEST.manual)


def test_both_front_ends_give_the_plain_phase_3_the_same_theta_and_trials(
        tmp_path, src_manual_best, decodes_manual, caplog):
    """For a seed, the phase run and ask/tell store the same phase-3 rows (θ, cost, fall,
    reused or run, in the order the critic is told them), and run the same θ, each once, on
    the target (the phase run's manual θ, phase 0, is the θ ask/tell runs as the zero-shot
    trial); so does a phase run stopped in its first batch and resumed."""
    shutil.copytree(src_manual_best, tmp_path / "src")
    ran_run: list = []
    with lt.Study(tmp_path / "run", seed=1) as run:
        run.phase3(bowl(0.1, ran_run), 6, latent=tmp_path / "src", strategy="plain")
    ran_at: list = []
    plain_by_asktell(tmp_path / "at", tmp_path / "src", ran_at, 20).close()

    def rows(d: Path) -> list[tuple]:
        with lt.Study(d) as st:
            return [(r.phase, r.theta.tobytes(), r.cost, r.fell, bool(r.info.get("reused")))
                    for ph in (Phase.PHASE3,) for r in phases.told_order(st.store.rows(ph))]
    assert rows(tmp_path / "run") == rows(tmp_path / "at")
    assert sorted(ran_run) == sorted(ran_at) and len(ran_at) == len(set(ran_at))
    ran_cut: list = []          # stopped in its first batch, after the start's reused row
    for max_new in (2, None):
        with lt.Study(tmp_path / "cut", seed=1) as cut:
            cut.phase3(bowl(0.1, ran_cut), 6, latent=tmp_path / "src", strategy="plain",
                       max_new=max_new)
    assert "not deterministic" not in caplog.text
    assert rows(tmp_path / "cut") == rows(tmp_path / "run") and sorted(ran_cut) == sorted(ran_run)


@pytest.fixture
def decodes_coarse(monkeypatch) -> None:
    """A decoder that snaps every θ entry to 0.3 or 0.7 (16 θ in all): a batch of 4 the plain
    phase 3 asks often holds one θ twice."""
    from latentune.latent.vae import LatentSpace

    orig = LatentSpace.decode_code

    def snapped(self, z):
        th = orig(self, z)
        return np.where(np.asarray(th) < 0.5, 0.3, 0.7)
    monkeypatch.setattr(LatentSpace, "decode_code", snapped)


def test_a_theta_asked_twice_in_one_batch_runs_once_in_both_front_ends(
        tmp_path, src_manual_best, decodes_coarse, monkeypatch, caplog):
    """The plain phase 3 reused a θ the study held a trial of, but ran a θ asked twice within
    one batch twice (two trials on the target for one θ). The second is stored with the
    first's outcome once it is told (``reused``, ``same_as``), in the phase run and ask/tell
    alike: the same rows, each θ run once."""
    shutil.copytree(src_manual_best, tmp_path / "src")
    ran_run: list = []
    with lt.Study(tmp_path / "run", seed=1) as run:
        run.phase3(bowl(0.1, ran_run), 12, latent=tmp_path / "src", strategy="plain")
        p3 = run.store.rows(Phase.PHASE3)
    twins = [(a, b) for a in p3 for b in p3 if a.idx < b.idx and a.idx // 4 == b.idx // 4
             and np.array_equal(a.theta, b.theta) and not a.info.get("reused")]
    assert twins, "premise: a batch of 4 asks one θ twice"
    assert all(b.info.get("reused") and b.info.get("same_as") == [Phase.PHASE3, a.idx]
               for a, b in twins), [(a.idx, b.idx, b.info) for a, b in twins]
    assert len(ran_run) == len(set(ran_run)), ran_run
    ran_at: list = []
    plain_by_asktell(tmp_path / "at", tmp_path / "src", ran_at, 20, budget=12).close()

    def rows(d: Path) -> list[tuple]:
        with lt.Study(d) as st:
            return [(r.theta.tobytes(), r.cost, r.fell, r.info.get("same_as"))
                    for r in phases.told_order(st.store.rows(Phase.PHASE3))]
    assert rows(tmp_path / "at") == rows(tmp_path / "run")
    assert sorted(ran_at) == sorted(ran_run)
    caplog.set_level(logging.WARNING, logger="latentune")
    seen_wait = False
    ran_4: list = []                    # asks of a whole batch (4): the second of a θ is not
    target = bowl(0.1, ran_4)           # handed out, and is told with the first
    with lt.Study(tmp_path / "at4", seed=1) as at:
        (z,) = at.ask(system=target, phase=3, latent=tmp_path / "src", strategy="plain",
                      budget=12)
        at.tell(z.id, evaluate(target, z.theta).cost)
        while at.store.count(Phase.PHASE3) < 12:
            try:
                got = at.ask(4)
            except StoreError as exc:       # the batch's θ were all stored ones: told at once
                assert "is told" in str(exc) and at.store.count(Phase.PHASE3) == 12
                break
            assert len({s.theta.tobytes() for s in got}) == len(got)
            if len(got) < 4 and at.store.trials("queued"):
                assert "asked twice waits for the first one's result" in caplog.text
                seen_wait = True
            for s in got:
                at.tell(s.id, evaluate(target, s.theta).cost)
    assert len(ran_4) == len(set(ran_4)) and seen_wait, ran_4   # (asks of 4 reach into the
    twins = asktell.tell_twins                  # a kill after a tell, before its twins' tell

    def not_in_tell(*a):
        if __import__("sys")._getframe(1).f_code.co_name != "tell":
            twins(*a)
    monkeypatch.setattr(asktell, "tell_twins", not_in_tell)
    ran_k: list = []
    plain_by_asktell(tmp_path / "kill", tmp_path / "src", ran_k, 20, budget=12).close()
    assert len(ran_k) == len(set(ran_k)), ran_k   # the next ask told the twin, not handed it
    assert rows(tmp_path / "kill") == rows(tmp_path / "run")
    with lt.Study(tmp_path / "at4") as at:      # next batch when one was stored θ: other rows)
        assert at.store.count(Phase.PHASE3) == 12 and not at.store.trials("queued")


def test_a_tell_that_stores_a_repeat_of_its_theta_says_so(tmp_path, src_manual_best,
                                                          decodes_coarse, run_cli):
    """A θ asked twice in a batch waits and is stored with the first one's result when that
    is told; the tell said nothing of it (only at -v), and ``status`` then counted one trial
    more than was told. The tell's line (and ``--json``'s ``copies``) names the copy it stored
    too; an amendment names the copies it amended with the trial."""
    shutil.copytree(src_manual_best, tmp_path / "src")
    target = bowl(0.1)
    d = tmp_path / "at"
    with lt.Study(d, seed=1) as at:
        (z,) = at.ask(system=target, phase=3, latent=tmp_path / "src", strategy="plain",
                      budget=12)
        at.tell(z.id, evaluate(target, z.theta).cost)
        got = at.ask(4)
        (w,) = at.store.trials("queued")                # premise: a twin waits
    first = next(s for s in got if np.array_equal(s.theta, w.theta))
    for s in got:
        if s.id != first.id:
            code, out, _ = run_cli("tell", d, s.id, "--cost", "0.9")
            assert code == 0 and "copy" not in out and "copies" not in out, out
    code, out, _ = run_cli("tell", d, first.id, "--cost", "0.5")
    with lt.Study(d) as at:
        (twin,) = [r for r in at.store.rows(Phase.PHASE3) if r.info.get("trial") == w.id]
        assert twin.info.get("same_as") and twin.cost == 0.5
        assert code == 0 and f"1 copy: phase 3 evaluation {twin.idx} (suggestion {w.id})" \
            in out, out
        assert at.status()["phases"]["phase 3"]["n"] == len(got) + 1
    code, out, _ = run_cli("tell", d, first.id, "--cost", "0.6", "--amend", "--json")
    rec = json.loads(out)
    assert code == 0 and rec["id"] == first.id and rec["amended"] and rec["cost"] == 0.6
    assert rec["copies"] == [{"id": w.id, "phase": int(Phase.PHASE3), "phase_name": "phase 3",
                              "idx": twin.idx}], rec


@contextlib.contextmanager
def _zero_shot_told_a_typo(tmp_path: Path, src: Path, target: Any) -> Iterator[tuple[Any, Any]]:
    """An ask/tell plain phase 3 on ``target`` from a copy of the source ``src`` whose zero-shot
    trial was told 90.0 where 0.04 was measured: yields (the open study, that suggestion)."""
    shutil.copytree(src, tmp_path / "src")
    with lt.Study(tmp_path / "at", seed=1) as at:
        (z,) = at.ask(system=target, phase=3, latent=tmp_path / "src", strategy="plain",
                      budget=6)
        at.tell(z.id, 90.0)
        yield at, z


def test_amending_a_trial_amends_the_rows_stored_from_it(tmp_path, src_manual_best,
                                                         decodes_manual):
    """The plain phase 3 stores a θ the study holds a trial of with that trial's outcome
    (``same_as``). Amending that trial (a typo in the zero-shot cost) left the row stored from
    it with the typo: phase 3's row, its best and the rebuilt critic kept the wrong cost. The
    rows stored from an amended trial are amended with it (in the audit trail too)."""
    target = bowl(0.1)
    with _zero_shot_told_a_typo(tmp_path, src_manual_best, target) as (at, z):
        (s,) = at.ask()
        (r0,) = [r for r in at.store.rows(Phase.PHASE3) if r.idx == 0]
        assert r0.info.get("same_as") == [Phase.ZERO_SHOT, 0] and r0.cost == 90.0  # premise
        at.tell(z.id, 0.04, amend=True, note="typo")
        (r0,) = [r for r in at.store.rows(Phase.PHASE3) if r.idx == 0]
        assert r0.cost == 0.04 and r0.info.get("same_as") == [Phase.ZERO_SHOT, 0]
        assert r0.info.get("reused") and r0.info.get("trial") != z.id
        trail = at.amendments()
        assert [a["trial"] for a in trail] == [z.id, r0.info["trial"]]
        assert trail[1]["old"]["cost"] == 90.0 and trail[1]["new"]["cost"] == 0.04


def test_amending_a_trial_amends_the_copies_a_phase_run_stored_from_it(
        tmp_path, src_manual_best, decodes_manual):
    """The amendment of a told trial reached only the copies ask/tell stored (a suggestion id):
    a plain phase 3 run in the same directory after the zero-shot trial was told stores the
    manual θ's row (phase 0) and its start (phase 3) as copies of it (``same_as``), and they
    kept the typo. Every copy follows the original, whichever front end stored it, each in the
    audit trail (a row without a suggestion: ``trial`` None)."""
    target = bowl(0.1)
    with _zero_shot_told_a_typo(tmp_path, src_manual_best, target) as (at, z):
        at.phase3(target, 6, latent=tmp_path / "src", strategy="plain")
        copies = [r for p in (Phase.MANUAL, Phase.PHASE3) for r in at.store.rows(p)
                  if r.info.get("same_as")]
        assert len(copies) >= 2 and all(r.cost == 90.0 and r.info.get("trial") is None
                                        for r in copies)          # premise: the phase run's
        at.tell(z.id, 0.04, amend=True, note="typo")
        now = {(r.phase, r.idx): r for p in (Phase.MANUAL, Phase.PHASE3)
               for r in at.store.rows(p)}
        for c in copies:
            r = now[(c.phase, c.idx)]
            assert r.cost == 0.04 and r.info.get("same_as") == c.info["same_as"], r
            assert r.info.get("reused") and r.info.get("trial") is None
        trail = at.amendments()
        assert {(a["phase"], a["idx"]) for a in trail[1:]} == {(c.phase, c.idx) for c in copies}
        assert all(a["trial"] is None and a["old"]["cost"] == 90.0 and a["new"]["cost"] == 0.04
                   for a in trail[1:])
        assert at.best().cost == 0.04


def test_a_first_ask_of_two_gives_the_plain_phase_3_the_rows_of_the_phase_run(
        tmp_path, src_manual_best):
    """A first ``ask(2)`` of the plain phase 3 hands out the zero-shot θ and a phase-3 θ before
    the zero-shot trial is told. The plain critic never sees the zero-shot trial, yet the ask
    counted it among the θ the critic asks again: it asked one point more and dropped its
    first, the search's start, so the phase-3 rows differed from the phase run's (and its
    design asked a told θ again). It asks its own handed-out θ again only, as the phase run
    it gives the rows of."""
    shutil.copytree(src_manual_best, tmp_path / "src")
    with lt.Study(tmp_path / "run", seed=1) as run:
        run.phase3(bowl(0.1), 6, latent=tmp_path / "src", strategy="plain")
        want = rows_of(run, Phase.PHASE3)
    target = bowl(0.1)
    with lt.Study(tmp_path / "at", seed=1) as at:
        first = at.ask(2, system=target, phase=3, latent=tmp_path / "src", strategy="plain",
                       budget=6)
        assert [s.phase_name for s in first] == ["zero-shot", "phase 3"]
        for s in first:
            at.tell(s.id, evaluate(target, s.theta).cost)
        while at.store.count(Phase.PHASE3) < 6:
            person(at, target, 1)
        assert rows_of(at, Phase.PHASE3) == want


def test_asks_that_end_with_the_batch_give_the_rows_of_the_phase_run_others_do_not(
        tmp_path, src30):
    """README: ask/tell gives the phase run's suggestions when each ask ends with the critic's
    batch of 4 (``--n 1`` first, then ``--n 4``); an ask of 3 reaches into the next batch,
    which the critic then asks with the ask's first θ not told, so later rows differ."""
    target = plant(0.2)
    with lt.Study(tmp_path / "run", seed=1) as run:
        run.phase3(target, 12, latent=src30)
        want = rows_of(run, Phase.PHASE3)

    def by_asktell(d: Path, n: int) -> list[tuple]:
        with lt.Study(d, seed=1) as at:
            (s,) = at.ask(system=target, phase=3, latent=src30, budget=12)
            out = evaluate(target, s.theta)
            at.tell(s.id, out.cost, failed=out.failed)
            while at.store.count(Phase.PHASE3) < 12:
                for s in at.ask(n):
                    out = evaluate(target, s.theta)
                    at.tell(s.id, out.cost, failed=out.failed)
            return rows_of(at, Phase.PHASE3)
    assert by_asktell(tmp_path / "at4", 4) == want
    got3 = by_asktell(tmp_path / "at3", 3)
    assert got3[:4] == want[:4] and got3 != want


def test_an_ask_whose_batch_is_all_told_theta_asks_on_or_says_the_budget_is_told(
        tmp_path, src_manual_best, decodes_manual):
    """A first ``ask(2)`` whose phase-3 start decodes to the zero-shot θ handed out with it:
    the start is not handed out twice (it is held back, and the design later asks θ it told,
    stored from their trials). An ask whose batch held only such θ said "the critic gave no θ
    that is not handed out already" when it used the last of the budget; it asks the next
    batch, or says the budget is told. No θ runs twice on the target."""
    shutil.copytree(src_manual_best, tmp_path / "src")
    ran: list = []
    target = bowl(0.1, ran)
    with lt.Study(tmp_path / "at", seed=1) as at:
        for s in at.ask(2, system=target, phase=3, latent=tmp_path / "src", strategy="plain",
                        budget=8):
            at.tell(s.id, evaluate(target, s.theta).cost)
        with pytest.raises(StoreError, match="budget of 8 trials is told"):
            for _ in range(9):
                (s,) = at.ask()
                at.tell(s.id, evaluate(target, s.theta).cost)
        assert at.store.count(Phase.PHASE3) == 8
        assert any(r.info.get("reused") for r in at.store.rows(Phase.PHASE3))
    assert len(ran) == len(set(ran)), ran


# ---------------------------------------------------------------------------- several askers
def test_leases_expire_and_are_released(tmp_path):
    st = lt.Study(tmp_path / "s", seed=0)
    (a,) = st.ask(space=SPACE, asker="alice", lease_s=0.3)
    (b,) = st.ask(asker="bob")
    assert b.id != a.id and not b.again
    (a2,) = st.ask(asker="alice")                      # alice's own, handed out again
    assert a2.id == a.id and a2.again
    a3 = st.ask(asker="alice", lease_s=0.3)[0]
    time.sleep(0.4)                                    # alice's lease expires
    (c,) = st.ask(asker="carol")
    assert c.id == a3.id and c.again and c.asker == "carol"
    st.release(b.id)                                   # bob gives his back
    (d,) = st.ask(asker="dave")
    assert d.id == b.id
    s = st.status()
    assert s["leases"][str(b.id)]["asker"] == "dave"
    st.tell(d.id, 1.0)
    with pytest.raises(StoreError, match="told, not pending"):
        st.release(d.id)
    st.close()


def test_a_second_tell_after_an_expired_lease_says_whose_result_stands(tmp_path, run_cli,
                                                                      error_line, caplog):
    """Alice's lease expired, bob was handed the suggestion and told it; alice's tell then said
    only "already told ... tell it again with --amend", which would silently overwrite bob's
    result. The refusal names the result that stands: its cost (and fall), note, when it was
    told and to whom the suggestion was handed out then; the store is untouched. Bob's ask
    says whose expired lease it took over."""
    st = lt.Study(tmp_path / "s", seed=0)
    (a,) = st.ask(space=SPACE, asker="alice", lease_s=0.3)
    time.sleep(0.4)                                    # alice's lease expires
    caplog.set_level(logging.WARNING, logger="latentune")
    (b,) = st.ask(asker="bob")
    assert b.id == a.id and b.again
    assert f"suggestion {a.id} was handed out to alice, whose lease expired" in caplog.text
    st.tell(b.id, 2.5, failed=True, note="bob's run")
    with pytest.raises(StoreError, match="already told") as e:
        st.tell(a.id, 5.0)                             # alice's result, for the same θ
    msg = str(e.value)
    told = time.strftime("%Y-%m-%d", time.gmtime())
    for part in ("cost 2.5 (failed)", "note \"bob's run\"", f"told {told}", "handed out to bob",
                 "amend=True"):
        assert part in msg, (part, msg)
    st.close()
    code, out, err = run_cli("tell", tmp_path / "s", a.id, "--cost", "5")
    line = error_line(code, err)
    assert "handed out to bob" in line and "--amend" in line and "amend=True" not in line, line
    with lt.Study(tmp_path / "s") as st:
        assert [(r.cost, r.fell) for r in st.store.rows(1)] == [(2.5, True)]


def test_a_tell_records_its_asker_and_one_naming_another_than_a_live_lease_is_refused(
        tmp_path, run_cli, error_line):
    """Alice's lease expired and bob was handed her suggestion; alice's tell was stored all the
    same, and bob's tell was then refused with "... while handed out to bob", a cost he never
    told. A tell names its asker (``asker``, ``--asker``): it is recorded with the trial
    (``info["told_by"]``, in ``trials()`` and the audit trail), a tell naming another asker
    than the holder of a live lease is refused (nothing stored), and a refusal of a second tell
    names who told the result that stands. A tell without an asker is stored as before."""
    st = lt.Study(tmp_path / "s", seed=0)
    (a,) = st.ask(space=SPACE, asker="alice", lease_s=0.3)
    time.sleep(0.4)                                    # alice's lease expires
    (b,) = st.ask(asker="bob")
    assert b.id == a.id
    with pytest.raises(StoreError, match="handed out to bob") as e:
        st.tell(a.id, 5.0, asker="alice")
    assert "alice's result is not stored" in str(e.value), str(e.value)
    assert st.store.rows(1) == []
    st.tell(b.id, 2.0, asker="bob")
    with pytest.raises(StoreError, match="already told") as e:
        st.tell(a.id, 5.0, asker="alice")
    assert "by bob" in str(e.value), str(e.value)
    (rec,) = st.trials()
    assert rec.info["told_by"] == "bob" and rec.cost == 2.0
    st.tell(b.id, 2.1, asker="carol", amend=True)
    (am,) = st.amendments()
    assert am["old"]["info"]["told_by"] == "bob" and am["new"]["info"]["told_by"] == "carol"
    with pytest.raises(StoreError, match="by carol"):
        st.tell(a.id, 5.0)
    (c,) = st.ask(asker="dave")                         # a tell without an asker: as before
    st.tell(c.id, 3.0)
    assert "told_by" not in st.store.rows(1)[-1].info
    with pytest.raises(StoreError, match="already told") as e:
        st.tell(c.id, 4.0, asker="dave")
    assert "by a tell that named no asker" in str(e.value) and "by dave" not in str(e.value)
    with pytest.raises(UsageError, match="asker"):
        st.tell(c.id, 4.0, asker=" ")
    st.close()
    d = tmp_path / "c"                                  # the command line
    sp = tmp_path / "S.yaml"
    sp.write_text(SPACE_YAML)
    assert run_cli("ask", d, "--space", sp, "--asker", "alice", "--lease", "0.3")[0] == 0
    time.sleep(0.4)
    code, _, err = run_cli("ask", d, "--asker", "bob")
    assert "a tell naming that asker is refused while this lease lasts" in err, err
    line = error_line(*run_cli("tell", d, "1", "--cost", "5", "--asker", "alice")[::2])
    assert "handed out to bob" in line, line
    code, out, _ = run_cli("tell", d, "1", "--cost", "2", "--asker", "bob")
    assert code == 0 and "told 1" in out
    line = error_line(*run_cli("tell", d, "1", "--cost", "5")[::2])
    assert "by bob" in line and "--amend" in line, line


def test_an_ask_beyond_the_budget_hands_out_the_suggestions_left(tmp_path):
    """A batch of 4 asked for a budget of 4, 3 handed out and told: ask(3) raised "the budget
    is handed out (3 told, 1 pending)", and the one it had just leased was never shown."""
    with lt.Study(tmp_path / "s", seed=0) as st:
        first = st.ask(3, space=SPACE, budget=4)
        for s in first:
            st.tell(s.id, float(np.sum(s.theta ** 2)))
        (last,) = st.ask(3)
        assert last.id not in {s.id for s in first} and not last.again
        st.tell(last.id, 1.0)
        with pytest.raises(StoreError, match="budget of 4 trials is told"):
            st.ask()


def _asker(d: str, name: str, rounds: int, q: "mp.Queue") -> None:
    study = lt.Study(d)
    rng = np.random.default_rng(abs(hash(name)) % 2 ** 32)
    for _ in range(rounds):
        (s,) = study.ask(asker=name)
        t0 = time.time()
        time.sleep(float(rng.uniform(0, 0.05)))
        q.put((name, s.id, t0, time.time(), s.theta.tobytes()))
        study.tell(s.id, float(np.sum(s.theta ** 2)))
    study.close()


def test_four_concurrent_askers_never_hold_one_suggestion(tmp_path):
    d = tmp_path / "s"
    with lt.Study(d, seed=0) as st:
        st.ask(space=SPACE, budget=60, asker="setup")
        st.release(1)
    ctx = mp.get_context("forkserver")      # the askers start at once (conftest's preload)
    q = ctx.Queue()
    procs = [ctx.Process(target=_asker, args=(str(d), f"robot{i}", 6, q)) for i in range(4)]
    for p in procs:
        p.start()
    got = [q.get(timeout=300) for _ in range(24)]
    for p in procs:
        p.join(timeout=60)
        assert p.exitcode == 0
    ids = [g[1] for g in got]
    assert len(set(ids)) == 24                          # every suggestion went to one asker
    assert len({g[4] for g in got}) == 24               # and no θ twice
    with RunStore(d) as st:
        assert st.count(Phase.PHASE1) == 24
        assert sorted(r.info["trial"] for r in st.rows(Phase.PHASE1)) == sorted(ids)
        st.check()


def _ask_then_die(d: str) -> None:
    study = lt.Study(d)
    study.ask(asker="doomed")
    os._exit(0)                                         # noqa: SLF001 - a kill after the ask


def test_a_kill_during_ask_loses_nothing(tmp_path):
    d = tmp_path / "s"
    with lt.Study(d, seed=0, batch_size=4) as st:
        st.ask(space=SPACE)
    ctx = mp.get_context("spawn")
    p = ctx.Process(target=_ask_then_die, args=(str(d),))
    p.start()
    p.join(timeout=2.5)                                 # at most 2.5 s: no wait once it exited
    if p.is_alive():
        p.kill()                                        # during its ask, or after it
    p.join()
    with lt.Study(d) as st:
        st.store.check()
        trials = st.store.trials()
        assert len({t.theta.tobytes() for t in trials}) == len(trials)
        assert {t.status for t in trials} <= {"queued", "pending"}
        s = st.ask(asker="next")[0]
        st.tell(s.id, 1.0)
        assert st.store.count(Phase.PHASE1) == 1


# ---------------------------------------------------------------------------- prepared batches
class CriticSpy:
    """Records which step (``where``) built a critic, through ``asktell.phase_critic``."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch) -> None:
        self.where, self.builds = "", []
        real = asktell.phase_critic

        def spy(*a, **k):
            self.builds.append(self.where)
            return real(*a, **k)

        monkeypatch.setattr(asktell, "phase_critic", spy)


def _phase1_script(d: Path, spy: CriticSpy) -> list[tuple]:
    """A person at a fall-prone plant: one trial at a time, then an ask of more than a batch,
    an amendment, a grown budget; returns every suggestion handed out (id, θ)."""
    sys_ = plant()
    got: list[tuple] = []

    def step(name: str, n: int = 1, **kw) -> list:
        spy.where = f"ask {name}"
        sugg = st.ask(n, **kw)
        got.extend((s.id, s.theta.tobytes()) for s in sugg)
        for s in sugg:
            spy.where = f"tell {name}"
            out = evaluate(sys_, s.theta)
            st.tell(s.id, out.cost, failed=out.failed)
        return sugg

    with lt.Study(d, seed=3) as st:
        step("0", system=sys_, budget=40, max_fall_prob=0.4)
        for i in range(1, 8):
            step(str(i))                       # the 4th and the 8th tell end a batch
        step("6 at once", 6)                   # more than the prepared batch of 4
        first = st.trials(phases=(Phase.PHASE1,))[1]
        spy.where = "amend"
        st.tell(first.trial, first.cost + 1.0, amend=True)
        for name in ("after the amend", "a", "b", "c"):
            step(name)                          # the tell of c ends the batch
        step("budget", budget=48)              # another options record than prepared for
        step("last")
    return got


def test_a_prepared_batch_gives_the_suggestions_and_rows_of_asking_the_critic(tmp_path,
                                                                               monkeypatch):
    spy = CriticSpy(monkeypatch)
    prepared = _phase1_script(tmp_path / "prepared", spy)
    builds = spy.builds
    spy.builds = []
    with monkeypatch.context() as m:
        m.setattr(asktell, "prepare", lambda study: False)
        control = _phase1_script(tmp_path / "control", spy)
    assert prepared == control                          # the same ids and θ, in order
    with lt.Study(tmp_path / "prepared") as a, lt.Study(tmp_path / "control") as b:
        assert rows_of(a, Phase.PHASE1) == rows_of(b, Phase.PHASE1)
        assert a.store.get_meta(state_key(1)) == b.store.get_meta(state_key(1))
        assert a.amendments()[0]["new"] == b.amendments()[0]["new"]
    # without preparation every batch is asked by an ask; with it, by the tell before it,
    # except when the prepared batch is stale or too small
    assert spy.builds == ["ask 0", "ask 4", "ask 6 at once", "ask after the amend",
                          "ask budget"]
    assert builds == ["ask 0", "tell 3", "tell 7", "ask 6 at once", "tell 6 at once", "amend",
                      "tell c", "ask budget"]


def _poison(study: lt.Study) -> None:
    """Replace the θ of the prepared batch by a sentinel, its key kept."""
    prep = study.store.get_meta(asktell.NEXT_KEY)
    assert prep, "no prepared batch"
    prep["thetas"] = [[0.123] * len(t) for t in prep["thetas"]]
    study.store.set_meta(asktell.NEXT_KEY, prep)


def _settle(study: lt.Study) -> None:
    """Tell every open suggestion (the last tell prepares a batch)."""
    n = sum(t.status in ("queued", "pending") for t in study.store.trials())
    for s in study.ask(n) if n else []:
        study.tell(s.id, float(np.sum(s.theta ** 2)))


def test_a_tell_whose_preparation_fails_is_stored_and_says_so(tmp_path, monkeypatch, run_cli):
    """A critic error while the tell prepared the next batch (a ValueError of the transfer
    critic on costs 1e155 apart was one) ended ``latentune tell`` with a traceback and exit
    status 1, though the result was stored (telling it again: "already told"). The tell now
    succeeds with one warning line; the next ask meets the error."""
    d = tmp_path / "a"
    with lt.Study(d, seed=0, batch_size=1) as st:      # the tell leaves nothing queued
        (s,) = st.ask(system=plant(), budget=6)

    def broken(*a, **k):
        raise ValueError("cannot convert float NaN to integer")

    monkeypatch.setattr(asktell, "_critic_batch", broken)
    code, out, err = run_cli("tell", d, s.id, "--cost", "0.5")
    assert code == 0 and f"told {s.id}" in out, (out, err)
    assert err.count("\n") == 1 and "the next suggestion was not prepared (ValueError: cannot " \
        "convert float NaN to integer); the next ask asks the critic" in err, err
    assert lt.Study(d).store.count(Phase.PHASE1) == 1


def test_a_phase_3_whose_source_run_was_moved_says_it_does_not_exist(run_cli, tmp_path,
                                                                     src30, error_line):
    """After the source run of an ask/tell phase 3 was moved, ``latentune ask`` said "latent:
    …/src holds a latent space but no run store (run.db): … copy the run directory with its
    run.db": the directory holds nothing, it is gone. It now says the source run does not
    exist and to put it back."""
    shutil.copytree(src30, tmp_path / "src")
    d = tmp_path / "t"
    with lt.Study(d, seed=0) as st:
        (z,) = st.ask(system=plant(0.3), phase=3, latent=tmp_path / "src", budget=4)
    shutil.move(tmp_path / "src", tmp_path / "moved")
    code, out, err = run_cli("tell", d, z.id, "--cost", "0.5")
    assert code == 0 and "does not exist (moved or deleted?)" in err, err
    line = error_line(*run_cli("ask", d)[::2])
    assert f"the source run {tmp_path / 'src'} does not exist (moved or deleted?): phase 3 " \
        "learns from its trials; put the run directory back there" in line, line
    assert "holds a latent space" not in line


def test_a_stale_prepared_batch_is_never_handed_out(tmp_path):
    sentinel = np.full(4, 0.123)
    with lt.Study(tmp_path / "s", seed=0) as st:
        st.ask(space=SPACE, budget=100)
        _settle(st)
        _poison(st)
        (s,) = st.ask()                                 # a fresh one is handed out as it is
        np.testing.assert_array_equal(s.theta, sentinel)
        st.tell(s.id, 1.0)

        def held_by_bob() -> None:                      # bob's ask from another process
            st.store.queue_trials(1, [np.full(4, 0.9)], [None], [-1])
            st.store.lease("bob", (1,), 1, 60.0)

        stale = {
            "the critic's state changed": lambda: st.store.set_meta(state_key(1), {}),
            "a result amended without preparing": lambda: st.store.amend_trial(
                s.id, 2.0, fell=False),
            "a suggestion held by another asker": held_by_bob,
            "a row added behind its back": lambda: st.store.add(
                Phase.PHASE1, st.store.next_idx(1), np.full(4, 0.7), 0.5),
        }
        for why, change in stale.items():
            _settle(st)
            _poison(st)
            change()
            got = st.ask()
            assert not np.array_equal(got[0].theta, sentinel), why
            assert st.store.get_meta(asktell.NEXT_KEY) is None, why
            for t in st.store.trials("pending"):
                if t.asker == "bob":
                    st.release(t.id)
        for why, kw in (("more than the batch", dict(n=5)), ("a grown budget", dict(budget=120))):
            _settle(st)
            _poison(st)
            got = st.ask(**kw)
            assert not any(np.array_equal(g.theta, sentinel) for g in got), why
        st.store.check()


def test_a_transfer_phase3_ask_takes_the_default_start_as_left_out(tmp_path, src30):
    """start="manual" (ask --start manual, the help's default) is what Study.phase3 takes with
    the transfer strategy: the option left out, on the first ask and on a later one; another
    start is refused in one line on both (found: ask refused "manual" that phase3 took)."""
    shutil.copytree(src30, tmp_path / "src")
    with lt.Study(tmp_path / "t", seed=0) as st:
        (s,) = st.ask(system=plant(0.2), phase=3, latent=tmp_path / "src", budget=30,
                      start="manual")
        st.tell(s.id, evaluate(plant(0.2), s.theta).cost)
        (s,) = st.ask(start="manual")
        assert s.phase_name == "phase 3"
        assert st.config()["phase3"]["start"] == "manual"
        for start in ([0.4] * 4, "scratch"):
            with pytest.raises(UsageError, match="start is an option of phase 1 and of the "
                                                 "plain phase 3"):
                st.ask(start=start)
    with lt.Study(tmp_path / "p", seed=0) as st:
        with pytest.raises(UsageError, match="start is an option of the plain phase 3"):
            st.phase3(plant(0.2), 4, latent=tmp_path / "src", start=None)


def test_a_prepared_transfer_phase3_gives_the_rows_of_asking_the_critic(tmp_path, monkeypatch,
                                                                         src30):
    shutil.copytree(src30, tmp_path / "src")
    target = plant(0.2)
    spy = CriticSpy(monkeypatch)

    def person3(d: Path) -> list[tuple]:
        got = []
        with lt.Study(d, seed=0) as st:
            for i in range(10):
                spy.where = f"ask {i}"
                (s,) = st.ask(system=target, phase=3, latent=tmp_path / "src", budget=30) \
                    if i == 0 else st.ask()
                got.append((s.id, s.phase_name, s.theta.tobytes()))
                spy.where = f"tell {i}"
                out = evaluate(target, s.theta)
                st.tell(s.id, out.cost, failed=out.failed)
            assert st.config()["phase3"]["strategy"] == "transfer"
            for start in ([0.4] * 4, "scratch"):
                with pytest.raises(LatentuneError, match="start is an option of phase 1 and "
                                                         "of the plain phase 3"):
                    st.ask(start=start)
        return got

    prepared, builds = person3(tmp_path / "prepared"), spy.builds
    spy.builds = []
    with monkeypatch.context() as m:
        m.setattr(asktell, "prepare", lambda study: False)
        control = person3(tmp_path / "control")
    assert prepared == control and prepared[0][1] == "zero-shot"
    with lt.Study(tmp_path / "prepared") as a, lt.Study(tmp_path / "control") as b:
        for ph in (Phase.ZERO_SHOT, Phase.PHASE3):
            assert rows_of(a, ph) == rows_of(b, ph)
    # zero-shot first, then batches of 4 asked by ask 1 and ask 5 (ask 9) without preparing
    assert spy.builds == ["ask 1", "ask 5", "ask 9"]
    assert builds == ["tell 0", "tell 4", "tell 8"]
    with lt.Study(tmp_path / "prepared") as st:         # the source run grew since
        _settle(st)
        _poison(st)
        with lt.Study(tmp_path / "src") as src:
            src.phase1(plant(), 31)
        (s,) = st.ask()
        assert not np.allclose(s.theta, 0.123)


def _tell_and_die(d: str, tid: int, at: str) -> None:
    def die(*a, **k):
        os._exit(0)                                     # noqa: SLF001 - a kill

    setattr(asktell, at, die)
    lt.Study(d).tell(tid, 1.0)


@pytest.mark.parametrize("at", ["prepare", "ask_batch"])
def test_a_kill_after_a_tell_loses_nothing(tmp_path, monkeypatch, at):
    """Killed after the told result is stored: before the preparation, or while it asks."""
    def start(d: Path) -> int:
        with lt.Study(d, seed=1) as st:
            sugg = st.ask(4, space=SPACE)
            for s in sugg[:3]:
                st.tell(s.id, float(np.sum(s.theta ** 2)))
        return sugg[3].id

    tid = start(tmp_path / "s")
    ctx = mp.get_context("forkserver")
    p = ctx.Process(target=_tell_and_die, args=(str(tmp_path / "s"), tid, at))
    p.start()
    p.join(timeout=300)
    assert p.exitcode == 0
    with monkeypatch.context() as m:
        m.setattr(asktell, "prepare", lambda study: False)
        ctl = start(tmp_path / "control")
        with lt.Study(tmp_path / "control") as c:
            c.tell(ctl, 1.0)
            expected = c.ask(2)
    with lt.Study(tmp_path / "s") as st:
        st.store.check()
        assert st.store.count(Phase.PHASE1) == 4 and st.store.rows(1)[3].info["trial"] == tid
        assert st.store.get_meta(asktell.NEXT_KEY) is None
        got = st.ask(2)
    assert [(s.id, s.theta.tobytes()) for s in got] == \
        [(s.id, s.theta.tobytes()) for s in expected]


def test_start_through_ask(tmp_path):
    with lt.Study(tmp_path / "a", seed=0) as st:
        start = np.array([0.1, 0.9, 0.3, 0.6])
        (s,) = st.ask(space=SPACE, start=start)
        np.testing.assert_allclose(s.theta, start)     # the critic starts from it
        assert st.config()["phase1"]["start"] == start.tolist()
        assert st.ask(start=start)[0].id == s.id        # the stored one may be repeated
        for other, shown in (("manual", "not 'manual'"), ("scratch", "not 'scratch'")):
            with pytest.raises(StoreError, match=shown):
                st.ask(start=other)
        with pytest.raises(LatentuneError, match="start must be 'manual', 'scratch' or a θ"):
            st.ask(start="best")
    with lt.Study(tmp_path / "b", seed=0) as st:
        sugg = st.ask(4, space=SPACE, start="scratch")
        assert st.config()["phase1"]["start"] is None
        assert not any(np.allclose(s.theta, SPACE.manual) for s in sugg)
        # the refusal names --start's value, not the stored record of scratch (None)
        with pytest.raises(StoreError, match="start = 'scratch' \\(stored\\), not 'manual'"):
            st.ask(start="manual")
    with lt.Study(tmp_path / "c", seed=0) as st:
        assert np.allclose(st.ask(space=SPACE)[0].theta, SPACE.manual)


# ---------------------------------------------------------------------------- status, best
def test_status_names_phases_and_counts_the_zero_shot_trial(tmp_path, src30):
    shutil.copytree(src30, tmp_path / "src")
    target = plant(0.3)
    with lt.Study(tmp_path / "t", seed=0) as st:
        sugg = st.ask(3, system=target, phase=3, latent=tmp_path / "src")
        assert [s.phase_name for s in sugg] == ["zero-shot", "phase 3", "phase 3"]
        st.tell(sugg[0].id, 0.01)                      # the zero-shot trial is the best
        st.tell(sugg[1].id, 0.5)
        st.tell(sugg[2].id, None, failed=True)
        s = st.status()
        assert set(s["phases"]) == {"zero-shot", "phase 3"}
        assert s["phases"]["phase 3"] == {"n": 2, "budget": 200, "failed": 1, "pending": 0,
                                          "reused": 0, "best": 0.5, "best_idx": 0,
                                          "best_trial": sugg[1].id}
        assert s["best"]["phase"] == "zero-shot" and s["best"]["trial"] == sugg[0].id
        assert json.loads(Path(s["best"]["params_file"]).read_text()) == sugg[0].params
        assert st.best().phase == Phase.ZERO_SHOT
        # the files of the phase run: no phase4_best.json named after the store's code
        assert sorted(f.name for f in st.dir.glob("*best.json")) == ["best.json",
                                                                      "phase3_best.json"]
        p = st.best_params(tmp_path / "deploy.json")
        assert json.loads(p.read_text()) == sugg[0].params
        nxt = st.ask()[0]
        assert st.status()["phases"]["phase 3"]["pending"] == 1 and nxt.phase_name == "phase 3"
        write_suggestion_files(st.dir, [nxt])
        assert json.loads(Path(nxt.path).read_text()) == nxt.params


def test_no_best_file_for_a_failed_theta_and_a_failing_phase_says_so(tmp_path, caplog):
    sys_ = lt.FunctionSystem(SPACE, all_fail)
    with caplog.at_level(logging.WARNING):
        with lt.Study(tmp_path / "s", seed=0) as st:
            st.phase1(sys_, 2 * FAIL_STREAK + 2)
            assert st.best() is None
            with pytest.raises(StoreError, match="all .* trials failed"):
                st.best_params()
    warned = [r for r in caplog.records if "trials all failed" in r.getMessage()]
    assert len(warned) == 1 and warned[0].levelno == logging.WARNING
    assert f"phase 1: the last {FAIL_STREAK} trials all failed" in warned[0].getMessage()
    assert not (tmp_path / "s" / "phase1_best.json").exists()
    assert not (tmp_path / "s" / "best.json").exists()
    caplog.clear()
    with caplog.at_level(logging.WARNING), lt.Study(tmp_path / "a", seed=0) as at:
        for i in range(FAIL_STREAK):
            (s,) = at.ask(space=SPACE)
            at.tell(s.id, None, failed=True)
    assert sum("trials all failed" in r.getMessage() for r in caplog.records) == 1


def test_a_phase_whose_standing_trials_all_cost_the_same_says_so_once(tmp_path, caplog, src30):
    """A cost that does not depend on θ (a constant by mistake, a saturated or rounded cost)
    gives the search nothing to follow: once FLAT_COUNT trials of a phase stood, all at one
    cost, one warning says so, in a phase run and through ask/tell alike (before: phases 1 and
    3 spent their budgets with no word). A cost that varies says nothing."""
    from latentune.pipeline.phases import FLAT_COUNT

    flat = lt.FunctionSystem(SPACE, lambda x: 1.0)

    def said() -> list[str]:
        return [r.getMessage() for r in caplog.records if "all cost" in r.getMessage()]
    with caplog.at_level(logging.WARNING):
        with lt.Study(tmp_path / "p1", seed=0) as st:
            st.phase1(flat, FLAT_COUNT + 4)
        assert said() == [f"phase 1: its {FLAT_COUNT} trials that stood so far all cost 1: "
                          "the cost does not tell these θ apart, so the search has nothing "
                          "to follow; check what the system returns (a constant by mistake, "
                          "a cost that saturates or is rounded)"]
        caplog.clear()
        with lt.Study(tmp_path / "p3", seed=0) as st:
            st.phase3(flat, FLAT_COUNT + 2, latent=src30)
        assert len(said()) == 1 and said()[0].startswith("phase 3: its ")
        caplog.clear()
        with lt.Study(tmp_path / "a", seed=0) as at:
            for i in range(FLAT_COUNT + 3):
                (s,) = at.ask(space=SPACE)
                at.tell(s.id, 2.5, failed=i % 4 == 3)    # falls do not count
        assert len(said()) == 1 and "all cost 2.5" in said()[0]
        caplog.clear()
        with lt.Study(tmp_path / "v", seed=0) as st:
            st.phase1(plant(), FLAT_COUNT + 2)
        assert said() == []


@pytest.mark.parametrize("strategy", ["transfer", "plain"])
def test_a_failing_phase_3_suggests_what_its_strategy_can_take(tmp_path, caplog, src30,
                                                               strategy):
    """Phase 3 on a target where every θ fails warns once, through a phase run and through
    ask/tell alike (ask/tell: in a new directory), and suggests only what the strategy takes:
    the hand-over is refused under the transfer strategy, so its warning does not offer it."""
    sys_ = lt.FunctionSystem(SPACE, all_fail)
    msgs = []
    for how in ("run", "ask"):
        caplog.clear()
        with caplog.at_level(logging.WARNING), lt.Study(tmp_path / how, seed=0) as st:
            given = None if strategy == "transfer" else strategy       # transfer: the default
            if how == "run":
                st.phase3(sys_, FAIL_STREAK + 2, latent=src30, strategy=given)
            else:
                person(st, sys_, FAIL_STREAK + 2, system=sys_, phase=3, latent=src30,
                       strategy=given, budget=FAIL_STREAK + 2)
        warned = [r.getMessage() for r in caplog.records if "trials all failed" in r.getMessage()]
        assert len(warned) == 1 and warned[0].startswith("phase 3: the last")
        msgs.append(warned[0])
    new = ", in a new directory (the first ask fixed this one's options),"
    assert new not in msgs[0] and new in msgs[1]       # ask/tell's options are fixed
    assert msgs[0] == msgs[1].replace(new, "")
    assert ("the hand-over (handover)" in msgs[0]) == (strategy == "plain")   # Python's words
    assert ("manual θ" in msgs[0]) == (strategy == "transfer")
    assert ("screens at 0.3 unless told" in msgs[0]) == (strategy == "transfer")


@pytest.mark.parametrize("kw", [{"method": "cma"}, {"regions": 3}, {"start": None},
                                {"start": np.full(4, 0.3)}])
def test_the_plain_phase_3s_options_are_refused_by_the_transfer_phase_3(tmp_path, src30, kw):
    """``method``, ``regions`` and ``start`` steer only the plain phase 3: the transfer phase 3
    (the default) refuses them by name before anything is stored (they were taken, changed
    nothing, and were recorded, so a resume without them was refused); with ``strategy="plain"``
    they stand. The refusal names the strategy as Python gives it ("(strategy='plain')"; it
    said "(strategy plain)", which the command line turned into its flag)."""
    with lt.Study(tmp_path / "t", seed=0) as st:
        with pytest.raises(UsageError, match=f"{next(iter(kw))} is an option of the plain phase 3"
                           ) as e:
            st.phase3(plant(), 4, latent=src30, **kw)
        assert "the plain phase 3 (strategy='plain'), not of the transfer" in str(e.value), e.value
        assert st.manifest.config().get("phase3") is None and st.trials() == []
        if "start" not in kw:       # ask --phase 3 --method cma / --regions 3 took and stored them
            with pytest.raises(UsageError, match=f"{next(iter(kw))} is an option of the plain"):
                st.ask(system=plant(), phase=3, latent=src30, **kw)
            assert st.manifest.config().get("phase3") is None and st.trials() == []
    with lt.Study(tmp_path / "p", seed=0) as st:
        st.phase3(plant(), 3, latent=src30, strategy="plain", **kw)
        assert st.manifest.config()["phase3"]["strategy"] == "plain"


def test_a_target_whose_box_differs_from_the_source_is_refused(tmp_path, src30):
    """Same names, other bounds or scale: the source's unit-box θ would mean other physical
    values on the target (its zero-shot trial ran 100 times the source's best), so phase 3,
    ask and a fall prior refuse it by name before anything is stored; the manual θ may
    differ."""
    from latentune.errors import LatentError

    wide = lt.ParameterSpace(SPACE.names, [-1.0] * 4, [1.0, 1.0, 100.0, 1.0], manual=[0.5] * 4)
    logd = lt.ParameterSpace(SPACE.names, [1e-3] * 4, [1.0] * 4, log=[True] * 4)
    assert SPACE.box_difference(wide.to_dict()) == "c: [-1, 100] there, [-1, 1] here"
    assert wide.box_difference(SPACE.to_dict()) == "c: [-1, 1] there, [-1, 100] here"
    assert logd.box_difference(SPACE.to_dict()) == "a: [-1, 1] there, [0.001, 1] log here"
    moved = lt.ParameterSpace(SPACE.names, [-1.0] * 4, [1.0] * 4, manual=[0.1] * 4)
    assert SPACE.box_difference(moved.to_dict()) is None
    for sp in (wide, logd):
        sys_ = lt.FunctionSystem(sp, lambda x: float(np.sum(x ** 2)))
        with lt.Study(tmp_path / f"t{sp.dim}{sp.log[0]}", seed=0) as st:
            with pytest.raises(LatentError, match="another box than the system's"):
                st.phase3(sys_, 4, latent=src30)
            with pytest.raises(LatentError, match="another box than the system's"):
                st.ask(system=sys_, phase=3, latent=src30)
            assert st.trials() == []
        with lt.Study(tmp_path / f"p{sp.log[0]}", seed=0) as st:
            with pytest.raises(StoreError, match="fall prior .* another box"):
                st.phase1(sys_, 4, max_fall_prob=0.3, fall_prior=src30)


def test_a_fall_prior_that_would_be_ignored_is_refused(tmp_path, src30):
    """ask --phase 3 --fall-prior RUN --max-fall-prob 0.3 stored the latent source as the prior
    (the given run ignored), and a fall prior without max_fall_prob (ask, Study.phase1) was
    dropped without a word."""
    with lt.Study(tmp_path / "t", seed=0) as st:
        with pytest.raises(UsageError, match="fall_prior is an option of phase 1"):
            st.ask(system=plant(), phase=3, latent=src30, max_fall_prob=0.3, fall_prior=src30)
        with pytest.raises(UsageError, match="fall_prior needs max_fall_prob"):
            st.ask(system=plant(), fall_prior=src30)
        with pytest.raises(UsageError, match="fall_prior needs max_fall_prob"):
            st.phase1(plant(), 4, fall_prior=src30)
        assert st.trials() == [] and st.manifest.config().get("phase1") is None


def test_a_phase_run_in_process_is_refused_while_suggestions_are_out(tmp_path, src30):
    """A phase run in-process while ask/tell has suggestions of the phase out (phase 3: its
    zero-shot trial too) would run them again: 12 phase-1 trials for a budget of 10, the
    zero-shot θ twice. It is refused, naming them, and runs once they are told; the batch's
    suggestions not handed out yet are withdrawn."""
    sys_ = plant()
    with lt.Study(tmp_path / "p1", seed=0) as st:
        out = st.ask(2, system=sys_, budget=10)
        with pytest.raises(StoreError, match="2 suggestions of phase 1 are handed out"):
            st.phase1(sys_, 10)
        for s in out:
            st.tell(s.id, plant_fn(SPACE.to_physical(s.theta)))
        assert st.phase1(sys_, 10).n == 10 and st.store.count(Phase.PHASE1) == 10
        assert not [t for t in st.store.trials() if t.status in ("queued", "pending")]
    with lt.Study(tmp_path / "p3", seed=0) as st:
        (zs,) = st.ask(1, system=sys_, phase=3, latent=src30, budget=4)
        assert zs.phase_name == "zero-shot"
        with pytest.raises(StoreError, match=r"1 suggestion of phase 3 is handed out to ask/tell \(id \d+\)"):
            st.phase3(sys_, 4, latent=src30)
        assert len(st.trials()) == 0


def test_a_phase_run_after_a_mid_batch_tell_keeps_the_told_and_withdraws_the_rest(tmp_path,
                                                                                  src30):
    """ask 4 (the zero-shot and three of a batch of 4), tell 2, then a phase run: it is refused
    while the other 2 are out, naming them and how to go on (release); once they are released
    it withdraws them and the batch's unasked one, keeps the told rows (the zero-shot, phase 3's
    first), asks its own batches up to the budget, and a later tell of a withdrawn one says
    so. (A tell of a suggestion never runs twice and a told result is never lost.)"""
    sys_ = plant()
    with lt.Study(tmp_path / "p3", seed=0, batch_size=4) as st:
        out = st.ask(4, system=sys_, phase=3, latent=src30, budget=8)
        assert [s.phase_name for s in out] == ["zero-shot"] + ["phase 3"] * 3
        told = {s.id: plant_fn(SPACE.to_physical(s.theta)) for s in out[:2]}
        for i, c in told.items():
            st.tell(i, c)
        with pytest.raises(StoreError, match=rf"ids {out[2].id}, {out[3].id}\).*release"):
            st.phase3(sys_, 8, latent=src30)
        for s in out[2:]:
            st.release(s.id)
        assert st.phase3(sys_, 8, latent=src30).n == 8
        assert st.store.count(Phase.PHASE3) == 8 and st.store.count(Phase.ZERO_SHOT) == 1
        assert st.store.rows(Phase.ZERO_SHOT)[0].cost == told[out[0].id]
        first = st.store.rows(Phase.PHASE3)[0]
        assert first.cost == told[out[1].id] and np.array_equal(first.theta, out[1].theta)
        status = {t.id: t.status for t in st.store.trials()}
        assert [status[s.id] for s in out] == ["told", "told", "dropped", "dropped"]
        assert list(status.values()).count("dropped") == 3          # and the unasked one
        assert len({r.theta.tobytes() for r in st.store.rows(Phase.PHASE3)}) == 8
        with pytest.raises(StoreError, match="dropped"):
            st.tell(out[2].id, 1.0)


def test_a_transfer_phase_3_resumes_from_the_source_trials_it_began_with(tmp_path, src30):
    """The source run's phase 1 grows while a transfer phase 3 from it is stopped: the resume
    asks what the uninterrupted run asked from the source as it was (the counts it began with
    are recorded, ``source_counts``), through a phase run and through ask/tell."""
    frozen, grown = tmp_path / "frozen", tmp_path / "grown"
    shutil.copytree(src30, frozen)
    shutil.copytree(src30, grown)
    target = plant(0.1)
    with lt.Study(tmp_path / "a", seed=0) as st:
        st.phase3(target, 6, latent=frozen)
    with lt.Study(tmp_path / "b", seed=0) as st:
        st.phase3(target, 6, latent=grown, max_new=3)      # mid-batch (batch 4)
        assert st.config()["phase3"]["source_counts"] == {"1": 30, "3": 0}
    with lt.Study(grown, seed=0) as src:
        src.phase1(plant(), 40)
    with lt.Study(tmp_path / "b", seed=0) as st:
        st.phase3(target, 6, latent=grown)
        assert st.config()["phase3"]["source_counts"] == {"1": 30, "3": 0}
    with lt.Study(tmp_path / "a") as a, lt.Study(tmp_path / "b") as b:
        assert rows_of(a, Phase.PHASE3) == rows_of(b, Phase.PHASE3)


def test_an_amendment_keeps_the_queue_when_nothing_changed_and_the_decisions_always(
        tmp_path, src30):
    """Amending a phase-3 result to the value it had (a typo fixed twice) leaves the queued
    suggestions as they were (they were dropped, and the search changed); amending it to
    another value drops them and rebuilds the critic from the corrected rows, but keeps the
    transfer critic's record of decisions (it was wiped: ``status`` forgot every ask)."""
    from latentune.pipeline.results import decisions

    sys_ = plant(0.1)
    with lt.Study(tmp_path / "p3", seed=0) as st:
        (zs,) = st.ask(1, system=sys_, phase=3, latent=src30, budget=8)
        st.tell(zs.id, plant_fn(SPACE.to_physical(zs.theta), 0.1))
        (s,) = st.ask(1)
        cost = plant_fn(SPACE.to_physical(s.theta), 0.1)
        st.tell(s.id, cost)

        def queued():
            return [t.id for t in st.store.trials() if t.status == "queued"]

        before, n_dec = queued(), len(decisions(st.store))
        assert before and n_dec >= 1
        st.tell(s.id, cost, amend=True)
        assert queued() == before
        st.tell(s.id, cost + 1.0, amend=True)
        assert queued() != before and len(decisions(st.store)) == n_dec


def test_a_told_trial_reads_the_strategy_only_when_it_warns(monkeypatch, caplog):
    """``warn_if_failing`` takes the strategy as a function (what ``tell`` gives it: a read of
    the study's config) and calls it only when the failing streak is reached."""
    from latentune.pipeline import phases

    calls = []

    def strategy() -> str:
        calls.append(1)
        return "transfer"

    for streak, warns in ((FAIL_STREAK - 1, False), (FAIL_STREAK, True), (FAIL_STREAK + 1, False)):
        monkeypatch.setattr(phases, "failure_streak", lambda store, phase: streak)
        with caplog.at_level(logging.WARNING):
            assert phases.warn_if_failing(None, 3, strategy) is warns
    assert len(calls) == 1
    assert sum("manual θ" in r.getMessage() for r in caplog.records) == 1


# ---------------------------------------------------------------------------- corrections
def test_amend_keeps_an_audit_trail_and_rebuilds_the_critic(tmp_path):
    st = lt.Study(tmp_path / "s", seed=0, batch_size=2)
    ids = []
    for cost in (4.0, 2.0, 3.0):
        (s,) = st.ask(space=SPACE)
        ids.append(s.id)
        st.tell(s.id, -3.0 if cost == 2.0 else cost)   # a typo on the second
    assert st.best().cost == -3.0
    with pytest.raises(StoreError, match="already told") as e:
        st.tell(ids[1], 2.0)
    assert str(e.value).endswith("to replace it, tell it again with "
                                 "amend=True"), e.value
    assert "was already told: cost -3, told " in str(e.value), e.value
    assert "while handed out without an asker's name" in str(e.value), e.value
    queued = [t for t in st.store.trials() if t.status == "queued"]
    assert queued                                       # asked from the typo
    row = st.tell(ids[1], 2.0, amend=True, note="typo: -3")
    assert row.cost == 2.0 and st.best().cost == 2.0
    (a,) = st.amendments()
    assert a["trial"] == ids[1] and a["old"]["cost"] == -3.0 and a["new"]["cost"] == 2.0
    assert a["note"] == "typo: -3"
    assert all(t.status == "dropped" for t in st.store.trials() if t.id in {q.id for q in queued})
    pc = st.config()["phase1"]
    control = phase_critic(Phase.PHASE1, pc, SPACE, st.dir)
    replay(st.store, Phase.PHASE1, control)             # the corrected rows alone
    expected = control.ask(2)
    nxt = st.ask(2)
    np.testing.assert_array_equal([s.theta for s in nxt], expected)
    with pytest.raises(StoreError, match="only a told result"):
        st.tell(nxt[0].id, 1.0, amend=True)
    st.close()


def test_an_amendment_without_a_note_keeps_the_trials_note(tmp_path, run_cli):
    """``tell 1 --cost 3.2 --note "slipped once"`` then ``tell 1 --cost 2.9 --amend`` (a typo
    in the cost) dropped the operator's note from the trial: ``trials()`` showed none. A
    correction without ``--note`` keeps it; one with ``--note`` gives the trial that note."""
    sp = tmp_path / "S.yaml"
    sp.write_text(SPACE_YAML)
    d = tmp_path / "r"
    assert run_cli("ask", d, "--space", sp, "--n", "2")[0] == 0
    assert run_cli("tell", d, "1", "--cost", "3.2", "--note", "slipped once")[0] == 0
    assert run_cli("tell", d, "1", "--cost", "2.9", "--amend")[0] == 0
    assert run_cli("tell", d, "2", "--cost", "4", "--note", "old")[0] == 0
    assert run_cli("tell", d, "2", "--cost", "5", "--amend", "--note", "typo: 4")[0] == 0
    with lt.Study(d) as st:
        notes = {t.trial: (t.cost, t.info.get("note")) for t in st.trials()}
        assert notes == {1: (2.9, "slipped once"), 2: (5.0, "typo: 4")}
        a = st.amendments()
        assert a[0]["new"]["info"]["note"] == "slipped once" and a[0]["note"] is None
        assert a[0]["old"]["info"]["note"] == "slipped once"


def test_amending_the_only_success_to_a_failure_removes_the_best_files(tmp_path):
    """best.json (the θ to deploy) and phase1_best.json were left with the θ of a trial that
    was amended to a failure, and summary.json still named phase1_best.json."""
    st = lt.Study(tmp_path / "s", seed=0)
    (s,) = st.ask(space=SPACE)
    st.tell(s.id, 3.0)
    assert (st.dir / "best.json").is_file() and (st.dir / "phase1_best.json").is_file()
    st.tell(s.id, failed=True, amend=True)
    assert not (st.dir / "best.json").exists() and not (st.dir / "phase1_best.json").exists()
    summary = st.summary()
    assert summary["phase1_best_params"] is None and "best" not in summary["artifacts"]
    st.tell(s.id, 2.0, amend=True)                      # standing again: written again
    assert json.loads((st.dir / "best.json").read_text()) == SPACE.as_dict(s.theta)
    assert st.summary()["phase1_best_params"] == "phase1_best.json"
    st.close()


# ---------------------------------------------------------------------------- trials as data
def test_trials_are_records_with_named_phases_and_physical_params(tmp_path, monkeypatch):
    with lt.Study(tmp_path / "s", seed=0) as st:
        st.phase1(plant(), 8)
        recs = st.trials()
        assert [r.phase for r in recs] == ["manual"] + ["phase 1"] * 8
        r = recs[3]
        assert set(r.params) == set(SPACE.names)
        np.testing.assert_allclose(list(r.params.values()), SPACE.to_physical(r.theta))
        assert r.trial is None and isinstance(r.failed, bool)
        assert json.loads(json.dumps(r.to_dict()))["phase"] == "phase 1"
    with lt.Study(tmp_path / "a", seed=0) as at:
        (s,) = at.ask(space=SPACE)
        at.tell(s.id, 1.5, note="by hand")
        (rec,) = at.trials()
        assert rec.trial == s.id and rec.cost == 1.5 and rec.info["note"] == "by hand"
        import pandas as pd

        df = at.trials_dataframe()
        assert isinstance(df, pd.DataFrame) and len(df) == 1
        assert list(df.columns) == ["phase", "idx", "trial", "cost", "failed",
                                    *[f"params_{n}" for n in SPACE.names], "info"]
        assert df["phase"].tolist() == ["phase 1"] and df["trial"].tolist() == [s.id]
        assert df.loc[0, "cost"] == 1.5 and df.loc[0, "info"]["note"] == "by hand"
        np.testing.assert_allclose(df.loc[0, [f"params_{n}" for n in SPACE.names]].to_numpy(
            dtype=float), SPACE.to_physical(s.theta))
        monkeypatch.setitem(__import__("sys").modules, "pandas", None)
        with pytest.raises(ImportError, match="pip install pandas"):
            at.trials_dataframe()
    monkeypatch.delitem(__import__("sys").modules, "pandas")
    with lt.Study(tmp_path / "s") as st:                # a phase run and its manual θ
        df = st.trials_dataframe()
        assert df["phase"].tolist() == ["manual"] + ["phase 1"] * 8
        assert str(df["trial"].dtype) == "Int64" and df["trial"].isna().all()
        assert df["idx"].dtype == np.int64 and df["cost"].dtype == np.float64
        assert df["failed"].dtype == bool and df["failed"].sum() == sum(r.failed for r in recs)
        assert all(df[f"params_{n}"].dtype == np.float64 for n in SPACE.names)
        np.testing.assert_allclose(df[[f"params_{n}" for n in SPACE.names]].to_numpy(),
                                   SPACE.to_physical(np.array([r.theta for r in recs])))
        assert st.trials_dataframe(phases=(Phase.MANUAL,)).shape[0] == 1


def test_trials_are_listed_in_the_order_they_were_stored(tmp_path, src30):
    """``Study.trials()`` listed a phase-3 study's zero-shot trial (the first made on the
    target) after phase 3's trials: phases were ordered by their number (zero-shot is 4).
    Trials are listed as they were stored (told): the zero-shot trial first when told first,
    between phase 3's when told between them; a phase's own rows in idx order."""
    shutil.copytree(src30, tmp_path / "src")
    with lt.Study(tmp_path / "t", seed=0) as st:
        (z,) = st.ask(1, system=plant(0.3), phase=3, latent=tmp_path / "src")
        assert z.phase_name == "zero-shot"
        st.tell(z.id, 0.5)
        for s in st.ask(2):
            st.tell(s.id, 0.7)
        assert [(r.phase, r.idx) for r in st.trials()] == [
            ("zero-shot", 0), ("phase 3", 0), ("phase 3", 1)]
        assert st.trials_dataframe()["phase"].tolist() == ["zero-shot", "phase 3", "phase 3"]
    with lt.Study(tmp_path / "u", seed=0) as st:         # zero-shot told between phase 3's
        got = st.ask(3, system=plant(0.3), phase=3, latent=tmp_path / "src")
        assert [s.phase_name for s in got] == ["zero-shot", "phase 3", "phase 3"]
        for s in (got[1], got[0], got[2]):
            st.tell(s.id, 0.6)
        recs = st.trials()
        assert [(r.phase, r.trial) for r in recs] == [
            ("phase 3", got[1].id), ("zero-shot", got[0].id), ("phase 3", got[2].id)]
        assert [r.phase for r in st.trials(phases=(Phase.PHASE3, Phase.ZERO_SHOT))] == \
            [r.phase for r in recs]


def test_trials_dataframe_without_trials_has_the_parameter_columns(tmp_path):
    """``trials_dataframe()`` of a run without a told trial (asked only, or a phase that holds
    none) had no ``params_<name>`` columns, unlike with trials: code selecting them raised a
    KeyError. When the space is known the empty frame has the same columns and dtypes."""
    import pandas as pd

    cols = ["phase", "idx", "trial", "cost", "failed", *[f"params_{n}" for n in SPACE.names],
            "info"]
    with lt.Study(tmp_path / "a", seed=0) as at:
        (s,) = at.ask(space=SPACE)
        empty = at.trials_dataframe()
        assert isinstance(empty, pd.DataFrame) and len(empty) == 0
        assert list(empty.columns) == cols
        assert all(empty[f"params_{n}"].dtype == np.float64 for n in SPACE.names)
        at.tell(s.id, 1.5)
        assert list(at.trials_dataframe().columns) == cols
        assert list(at.trials_dataframe(phases=(Phase.MANUAL,)).columns) == cols
    with lt.Study(tmp_path / "none") as st:             # no store: no space to name
        assert list(st.trials_dataframe().columns) == ["phase", "idx", "trial", "cost",
                                                       "failed", "info"]


def test_the_store_decodes_non_finite_costs_and_names_no_fall_constant(tmp_path):
    with RunStore(tmp_path / "r", create=True) as st:
        st.add(1, 0, [0.1], math.inf, fell=True)
        st.add(1, 1, [0.2], -math.inf, fell=False)
        st.add(1, 2, [0.3], 150.0)                    # failed only when told so
        assert [r.cost for r in st.rows(1)] == [math.inf, -math.inf, 150.0]
        assert list(st.costs(1)) == [math.inf, -math.inf, 150.0]
        assert [r.fell for r in st.rows(1)] == [True, False, False]
    src = inspect.getsource(store_module)
    assert "C1" not in src and "STABLE_CAP" not in src and "fail_cost" not in src


def test_a_version_2_store_is_upgraded_by_its_first_ask(tmp_path):
    d = tmp_path / "s"
    with lt.Study(d, seed=0) as st:
        st.ask(space=SPACE)
    con = sqlite3.connect(d / "run.db")                 # back to version 2: no leases
    con.executescript("DROP TABLE amendments; ALTER TABLE trials DROP COLUMN asker; "
                      "ALTER TABLE trials DROP COLUMN lease_until; "
                      "UPDATE trials SET status='pending' WHERE status='queued';")
    con.execute("UPDATE meta SET value='2' WHERE key='version'")
    con.commit()
    con.close()
    with lt.Study(d) as st:
        assert st.status()["pending"] == [1, 2, 3, 4]
        got = st.ask(2, asker="new")                    # unleased pending: handed out again
        assert [s.id for s in got] == [1, 2] and all(s.again for s in got)
        st.tell(1, 1.0)
        assert st.store.get_meta("version") == 3


def test_tell_takes_the_outcome_of_evaluate(tmp_path):
    """``tell(id, system.evaluate(θ))``: an Outcome is stored as it is (a failed one without a
    cost takes the C1 convention); an Outcome with ``failed`` or ``info`` beside it is refused."""
    from latentune.errors import UsageError
    from latentune.system import Outcome

    st = lt.Study(tmp_path / "o", seed=0)
    a, b, c = st.ask(3, system=plant(), phase=1, method="sobol", budget=6)
    row = st.tell(a.id, Outcome(None, True, {"reason": "x0 too big"}))
    assert row.fell and row.cost == 200.0 and row.info["reason"] == "x0 too big"
    assert st.tell(b.id, Outcome(1.5)).cost == 1.5
    with pytest.raises(UsageError, match="give an Outcome alone"):
        st.tell(c.id, Outcome(2.0), failed=True)
    st.close()


def test_ask_refuses_odd_arguments_from_python(tmp_path):
    """From Python: ``budget=0`` on a first ask was taken as the default 200; ``space`` as a
    dict raised AttributeError; ``space`` beside a system of another space was ignored;
    ``start`` as a dict TypeError; ``lease_s=True`` / ``"5"`` were leases of 1 and 5 s, an
    asker ``"a\\nb"`` broke status's lines and ``["x"]`` was stored as "['x']"; ``phase="x"`` ValueError and
    ``phase=1.5`` was taken as 1; a later ``budget="x"`` TypeError; ``budget=2**63`` (past the
    store's integers) was taken. Each is one UsageError or
    StoreError now, and a first ask that is refused leaves no phase."""
    from latentune.errors import UsageError

    sp = lt.ParameterSpace(["a"], [0], [1])
    cases = [(dict(budget=0), UsageError, "budget must be an integer >= 1 and below 2\\*\\*63, got 0"),
             (dict(budget=2 ** 63), UsageError, f"below 2\\*\\*63, got {2 ** 63}"),
             (dict(space={"names": ["a"], "low": [0], "high": [1]}), UsageError,
              "space must be a latentune.ParameterSpace, not dict"),
             (dict(start={"a": 0.2}), UsageError, "start must be numbers"),
             (dict(phase="x"), UsageError, "runs phase 1 or 3, not 'x'"),
             (dict(phase=1.5), UsageError, "not 1.5"),
             (dict(system=lt.FunctionSystem(lt.ParameterSpace(["b"], [0], [2]), float)),
              UsageError, "give a system or a space, not both"),
             (dict(lease_s=True), UsageError, "lease_s must be a positive number"),
             (dict(lease_s="5"), UsageError, "lease_s must be"),
             (dict(asker="a\nb"), UsageError, "asker must be a non-empty name on one line"),
             (dict(asker=["x"]), UsageError, "asker must be")]
    for i, (kw, err, expect) in enumerate(cases):
        st = lt.Study(tmp_path / f"s{i}")
        with pytest.raises(err, match=expect):
            st.ask(1, **{"space": sp, **kw})
        assert not (st.config().get("asktell") or {})
    st = lt.Study(tmp_path / "later")
    st.ask(1, space=sp, budget=5)
    for kw, expect in ((dict(budget="x"), "budget = 5 \\(stored\\), not 'x'"),
                       (dict(phase="x"), "not 'x'"), (dict(phase=1.5), "not 1.5")):
        with pytest.raises(LatentuneError, match=expect):
            st.ask(1, **kw)
    assert st.status()["pending"] == [1]


def test_best_and_trials_refuse_a_phase_that_is_not_one(tmp_path):
    """``best("x")`` raised ValueError, ``best(1.5)`` gave phase 1's best and ``best(2)`` None
    (no such phase); ``trials(1)`` raised TypeError. A phase is one number of the store's
    phases or several now; anything else is a UsageError naming them."""
    from latentune.errors import UsageError

    st = lt.Study(tmp_path / "o", seed=0)
    a, = st.ask(1, space=lt.ParameterSpace(["a"], [0], [1]), budget=4)
    st.tell(a.id, 2.0)
    assert st.best(1).cost == 2.0 and st.best(3) is None
    assert len(st.trials(1)) == len(st.trials([1])) == 1 and st.trials((3,)) == []
    for bad in ("x", 1.5, 2, True):
        with pytest.raises(UsageError, match="a phase is one of 0, 1, 3, 4, 5"):
            st.best(bad)
        with pytest.raises(UsageError, match="a phase is one of"):
            st.trials((1, bad))
    st.close()


def test_tell_refuses_an_info_that_is_not_a_dict_and_a_bad_fall_step(tmp_path):
    """``tell(id, 1.0, info=[1])`` raised TypeError from ``dict()``; a fall_step that is not a
    whole number of steps (``"x"``, −1 without a horizon) raised ValueError from ``int()`` or
    was stored. Now one UsageError each, nothing stored; a whole float step is taken."""
    from latentune.errors import UsageError

    st = lt.Study(tmp_path / "o", seed=0)
    a, = st.ask(1, system=plant(), phase=1, method="sobol", budget=6)
    for kw, expect in ((dict(cost=1.0, info=[1]), "info must be a dict, got list"),
                       (dict(cost=1.0, info="x"), "info must be a dict, got str"),
                       (dict(failed=True, info={"fall_step": "x"}), "got fall_step 'x'"),
                       (dict(failed=True, info={"fall_step": -1}), "whole number of steps")):
        with pytest.raises(UsageError, match=expect):
            st.tell(a.id, **kw)
    assert st.store.count(1) == 0
    assert st.tell(a.id, failed=True, info={"fall_step": 3.0}).fall_step == 3
    st.close()


def test_a_failed_trial_may_report_a_non_finite_cost_and_a_standing_one_may_not(tmp_path):
    """A simulator that blew up reports ``(nan, failed)``: a fall with the C1 convention and the
    reported value in its info, through tell and through a phase run; a trial that did not fail
    with a non-finite cost is refused and nothing is stored."""
    from latentune.errors import UsageError

    st = lt.Study(tmp_path / "o", seed=0)
    a, b, c = st.ask(3, system=plant(), phase=1, method="sobol", budget=6)
    row = st.tell(a.id, float("nan"), failed=True)
    assert row.fell and row.cost == 200.0 and row.info["reported_cost"] == "nan"
    assert st.tell(b.id, float("-inf"), failed=True).info["reported_cost"] == "-inf"
    with pytest.raises(UsageError, match="non-finite cost"):
        st.tell(c.id, float("inf"))
    assert len(st.store.rows(Phase.PHASE1)) == 2
    st.close()

    def blows_up(x):
        return (float("nan"), True) if x[0] > 0 else (float(np.sum(x ** 2)), False)

    sysm = lt.FunctionSystem(SPACE, blows_up)
    res = lt.Study(tmp_path / "p", seed=1).phase1(sysm, 12, method="sobol")
    rows = lt.Study(tmp_path / "p").store.rows(Phase.PHASE1)
    assert res.n == 12 and any(r.fell for r in rows) and any(not r.fell for r in rows)
    assert all(r.cost == 200.0 and r.info["reported_cost"] == "nan" for r in rows if r.fell)


def test_status_says_no_trial_told_yet_while_every_suggestion_is_out(run_cli, tmp_path):
    """With suggestions out and none told, status said 'no trial without a fall', as if every
    trial had fallen; it says none is told yet, and after a told fall it says that."""
    d = tmp_path / "s"
    assert run_cli("ask", d, "--system", "examples.lqr_chain:make_system", "--n", "2")[0] == 0
    code, out, _ = run_cli("status", d)
    assert code == 0 and "0 of 200 trials, 0 failed, 2 pending; no trial told yet" in out
    assert run_cli("tell", d, "1", "--failed")[0] == 0
    out = run_cli("status", d)[1]
    assert "1 of 200 trials, 1 failed, 1 pending; no trial without a fall" in out


def test_status_says_each_phase_s_budget(run_cli, tmp_path):
    """status said "phase 1: 3 trials, 1 pending" and never the phase's budget, though an ask
    past it is refused ("phase 1's budget of 10 trials is told") and the report says "holds
    3 trials of its budget of 10": a phase with a budget says "3 of 10 trials" (--json:
    ``budget``), after a grown budget its new one; the manual θ and zero-shot have none."""
    d = tmp_path / "s"
    assert run_cli("ask", d, "--system", "examples.lqr_chain:make_system", "--n", "4",
                   "--budget", "10")[0] == 0
    for i in (1, 2, 3):
        assert run_cli("tell", d, str(i), "--cost", "1.5")[0] == 0
    out = run_cli("status", d)[1]
    assert "phase 1: 3 of 10 trials, 0 failed, 1 pending; best 1.5" in out, out
    assert run_cli("ask", d, "--budget", "12")[0] == 0
    p1 = json.loads(run_cli("status", d, "--json")[1])["phases"]["phase 1"]
    assert (p1["n"], p1["budget"]) == (3, 12)
    with lt.Study(tmp_path / "run", seed=0) as st:
        st.phase1(lt.FunctionSystem(SPACE, lambda x: float(np.sum(x ** 2))), 5, method="sobol")
        got = st.status()["phases"]
    assert (got["manual"]["budget"], got["phase 1"]["budget"], got["phase 1"]["n"]) == \
        (None, 5, 5)


def test_status_of_a_run_without_trials_says_so(run_cli, tmp_path):
    """A run stopped before its first trial (killed while the first ran, or every suggestion
    released) printed only "pending suggestions: 0", not what the run holds: it says no trial
    is stored yet."""
    d = tmp_path / "s"
    assert run_cli("ask", d, "--system", "examples.lqr_chain:make_system")[0] == 0
    assert run_cli("release", d, "1")[0] == 0
    code, out, _ = run_cli("status", d)
    assert code == 0 and out.splitlines() == ["no trial stored yet", "pending suggestions: 0"]


def test_report_says_what_the_tables_do_not_show(run_cli, tmp_path):
    """report.md of a run under way said nothing of the trials still out, of the budget not
    reached, or of amended results: each is a line under the table, and a finished run has
    none of them."""
    d = tmp_path / "s"
    sysargs = ("--system", "examples.lqr_chain:make_system")
    assert run_cli("ask", d, *sysargs, "--n", "3", "--budget", "4")[0] == 0
    assert run_cli("tell", d, "1", "--cost", "0.9")[0] == 0
    assert run_cli("tell", d, "1", "--cost", "0.8", "--amend")[0] == 0
    assert run_cli("report", d, *sysargs, "--no-sim")[0] == 0
    md = (d / "report.md").read_text()
    assert "Phase 1 (θ, TuRBO-m) holds 1 trial of its budget of 4." in md
    assert "2 suggestions are handed out to ask/tell and not told" in md
    assert "1 told result was amended" in md
    for i in (2, 3):
        assert run_cli("tell", d, str(i), "--cost", "1.0")[0] == 0
    code, out, err = run_cli("ask", d, "--n", "1")
    assert code == 0, err
    assert run_cli("tell", d, out.split()[0], "--cost", "1.0")[0] == 0
    assert run_cli("report", d, *sysargs, "--no-sim")[0] == 0
    md = (d / "report.md").read_text()
    assert "budget of" not in md and "handed out" not in md and "1 told result was" in md


def test_ask_reopens_a_study_run_with_another_seed_than_0(run_cli, tmp_path, error_line):
    """`latentune ask DIR` on a study a phase run had run with --seed 5 said 'the study was run
    with seed = 5, not 0 (leave the seed out to reopen it)' though no seed was given: an ask
    without --seed takes the stored one, as every other command does."""
    d = tmp_path / "s"
    with lt.Study(d, seed=5) as st:
        st.phase1(plant(), 4)
    code, out, err = run_cli("ask", d, "--budget", "6")
    assert code == 0, err
    with lt.Study(d) as st:
        assert st.seed == 5 and st.config()["asktell"]["seed"] == 5
    assert "--seed 5 (stored), not --seed 0" in error_line(*run_cli("ask", d, "--seed", "0")[::2])


def test_a_fall_step_that_is_no_step_number_is_refused_in_one_line(tmp_path):
    """``tell(id, failed=True, info={"fall_step": "abc"})`` (or nan, 1e20) ended in a
    ValueError/OverflowError traceback, and -5, 2.7 or True were stored as fall steps -5, 2
    and 1; each is a bad result now (UsageError naming the suggestion), the store untouched,
    and a system returning one stops its phase with an EvaluationError, not a ValueError."""
    from latentune.system import EvaluationError

    with lt.Study(tmp_path / "s") as st:
        st.ask(2, space=SPACE)
        for k in ("abc", float("nan"), 1e20, -5, 2.7, True):
            with pytest.raises(UsageError, match="bad result for suggestion 1: got fall_step"):
                st.tell(1, failed=True, info={"fall_step": k})
        assert st.store.count(Phase.PHASE1) == 0
        assert st.tell(1, failed=True, info={"fall_step": 30.0}).fall_step == 30
        assert st.tell(2, failed=True, info={"fall_step": np.int64(7), "horizon": 10}).cost == 130
    bad = lt.FunctionSystem(SPACE, lambda x: lt.Outcome(None, True, {"fall_step": "abc"}))
    with lt.Study(tmp_path / "r") as st, pytest.raises(EvaluationError, match="fall_step 'abc'"):
        st.phase1(bad, 4)


def test_ask_and_tell_refuse_a_lease_asker_or_info_of_the_wrong_type(tmp_path):
    """``ask(lease_s="abc")`` or ``lease_s=[1]`` ended in a ValueError/TypeError traceback,
    ``lease_s=True`` leased for 1 s, ``asker=["x"]`` leased to the name "['x']", and
    ``tell(id, 1.0, info="hello")`` ended in a ValueError: each is a UsageError now, nothing
    leased or stored."""
    with lt.Study(tmp_path / "s") as st:
        st.ask(1, space=SPACE)
        for lease in ("abc", [1], True, 0, float("nan")):
            with pytest.raises(UsageError, match="lease_s must be a positive number"):
                st.ask(1, lease_s=lease, asker="b")
        for who in (["x"], 7, " "):
            with pytest.raises(UsageError, match="asker must be a non-empty name"):
                st.ask(1, asker=who)
        with pytest.raises(UsageError, match="info must be a dict, got str"):
            st.tell(1, 1.0, info="hello")
        assert [t.asker for t in st.store.trials("pending")] == ["default"]
        assert st.store.count(Phase.PHASE1) == 0
        assert st.ask(1, asker="b", lease_s=np.float64(5.0))[0].asker == "b"


def test_asks_while_the_zero_shot_trial_is_out_hand_out_the_whole_budget(tmp_path, src30):
    """While the zero-shot suggestion was out (not told), the transfer critic asks its θ
    again as its first point; a batch asked then came out one short, and once the other
    points were held an ask by another asker answered nothing at all (exit 0, no line): the
    budget's suggestions are all handed out now, and an ask past them is refused."""
    shutil.copytree(src30, tmp_path / "src")
    with lt.Study(tmp_path / "s", seed=0) as st:
        a = st.ask(2, system=plant(0.2), phase=3, latent=tmp_path / "src", budget=5, asker="a")
        assert [s.phase_name for s in a] == ["zero-shot", "phase 3"]
        c = st.ask(5, asker="c")
        assert len(c) == 4 and all(s.phase == Phase.PHASE3 for s in c)
        ids = [s.id for s in a + c]
        assert len(set(ids)) == 6
        assert len({s.theta.tobytes() for s in a + c}) == 6
        with pytest.raises(StoreError, match="budget of 5 trials is handed out"):
            st.ask(1, asker="d")


def test_telling_a_released_suggestion_says_so(run_cli, tmp_path, error_line):
    """A suggestion handed out, released, then told was refused with 'suggestion 1 was never
    handed out (queued)', which it was; the line says it is not handed out now (released or
    never asked for). ``ask --lease inf`` named the API's lease_s; it names --lease."""
    d = tmp_path / "s"
    assert run_cli("ask", d, "--system", "examples.lqr_chain:make_system")[0] == 0
    assert run_cli("release", d, "1")[0] == 0
    line = error_line(*run_cli("tell", d, "1", "--cost", "1")[::2])
    assert "never handed out" not in line and "released" in line
    assert "--lease must be a positive" in error_line(*run_cli("ask", d, "--lease", "inf")[::2])


def test_amending_the_zero_shot_trial_withdraws_phase_3s_queued_suggestions(tmp_path, src30):
    """The transfer critic is told the zero-shot trial; amending its result (a success found
    to be a fall) kept phase 3's suggestions asked from the old result queued, and handed
    them out. They are withdrawn now, as for an amended phase-3 trial; an amended note alone
    keeps them."""
    shutil.copytree(src30, tmp_path / "src")
    with lt.Study(tmp_path / "s", seed=0) as st:
        (z,) = st.ask(system=plant(0.2), phase=3, latent=tmp_path / "src", budget=8)
        st.tell(z.id, 0.3)
        (s,) = st.ask()
        queued = [t.id for t in st.store.trials("queued")]
        assert queued and all(st.store.trials_by_id(i).phase == Phase.PHASE3 for i in queued)
        st.tell(z.id, 0.3, note="seen", amend=True)
        assert [t.id for t in st.store.trials("queued")] == queued
        st.tell(z.id, None, failed=True, amend=True)
        assert st.store.trials("queued") == []
        assert {st.store.trials_by_id(i).status for i in queued} == {"dropped"}
        assert st.store.trials_by_id(s.id).status == "pending"
        assert st.ask(asker="b")[0].id > max(queued)


def test_status_says_which_leases_expired(run_cli, tmp_path):
    """status listed a suggestion whose lease had expired as 'held by' its asker, though the
    next ask hands it to anyone; it says the lease expired."""
    d = tmp_path / "s"
    # b first: its ask builds the critic, which may take longer than a's short lease
    assert run_cli("ask", d, "--system", "examples.lqr_chain:make_system", "--asker", "b")[0] == 0
    assert run_cli("ask", d, "--asker", "a", "--lease", "0.2")[0] == 0
    time.sleep(0.3)
    out = run_cli("status", d)[1]
    assert "pending suggestions: 2 (suggestion 1 held by b, suggestion 2 free again: a's lease expired)" in out


def test_asking_phase_3_where_ask_tell_runs_phase_1_says_where_to(tmp_path):
    """``ask --phase 3`` in a directory whose ask/tell runs phase 1 said only 'runs phase 1
    (stored), not 3'; it says to ask phase 3 in another directory with this one's latent
    space."""
    d = tmp_path / "s"
    with lt.Study(d) as st:
        st.ask(space=SPACE)
        with pytest.raises(StoreError, match=re.escape(f"another directory, with latent='{d}'")):
            st.ask(phase=3)


def test_asking_phase_3_with_a_latent_space_where_ask_tell_runs_phase_1_names_it(tmp_path):
    """``Study.ask(phase=3, latent=MINE)`` (or without ``phase``) in a directory whose
    ask/tell runs phase 1 said to ask phase 3 'with --vae' this directory, or to 'use another
    directory' alone; both now name the latent space given, the one to ask with elsewhere, by
    the keyword that gives it in Python (``latent=``; the command line's ``--vae``)."""
    d, mine = tmp_path / "s", tmp_path / "my space"
    with lt.Study(d) as st:
        st.ask(space=SPACE)
        for phase in (3, None):
            with pytest.raises(LatentuneError) as e:
                st.ask(phase=phase, latent=mine)
            assert str(e.value).endswith(f"in another directory, with latent='{mine}'"), e.value


def test_asking_phase_1_with_a_latent_space_names_the_keywords(tmp_path):
    """``Study.ask(phase=1, latent=DIR)`` said "--phase 1 with --vae: ... ask --phase 3 (or
    leave --phase 1 out)", the command line's flags, to a Python caller; it names the keywords
    (the command line keeps its flags: test_cli_phase3)."""
    d = tmp_path / "s"
    with lt.Study(d) as st, pytest.raises(UsageError) as e:
        st.ask(space=SPACE, phase=1, latent=tmp_path / "src")
    assert str(e.value) == (f"{d}: phase=1 with latent: a latent space is an option of phase 3: "
                            "ask phase=3 (or leave phase=1 out)"), e.value


def test_suggestion_files_are_the_suggestions_handed_out(run_cli, tmp_path):
    """`release DIR ID` left suggestions/ID.json behind, and kept it when an amendment then
    withdrew the suggestion (tell ID: 'not handed out (dropped)'): the operator saw a θ to run
    that no ask hands out. The directory now holds the files of the pending suggestions only."""
    d = tmp_path / "s"
    files = lambda: sorted(p.name for p in (d / "suggestions").iterdir())   # noqa: E731
    assert run_cli("ask", d, "--system", "examples.lqr_chain:make_system", "--n", "3")[0] == 0
    assert files() == ["1.json", "2.json", "3.json"]
    assert run_cli("release", d, "3")[0] == 0
    assert files() == ["1.json", "2.json"]
    code, out, _ = run_cli("ask", d, "--n", "3")           # 1, 2 again, then 3
    assert code == 0 and [ln.split()[0] for ln in out.splitlines()] == ["1", "2", "3"]
    assert files() == ["1.json", "2.json", "3.json"]
    assert run_cli("release", d, "3")[0] == 0
    assert run_cli("tell", d, "1", "--cost", "1.0")[0] == 0
    assert run_cli("tell", d, "1", "--cost", "2.0", "--amend")[0] == 0     # withdraws 3
    with lt.Study(d) as st:
        assert st.store.trials_by_id(3).status == "dropped"
    assert files() == ["2.json"]


def test_tell_refuses_a_suggestion_file_edited_by_hand(run_cli, tmp_path, error_line):
    """A θ edited in suggestions/ID.json (a gain lowered by hand before running it) was told as
    suggestion ID: the store recorded the result for the suggested θ, which the robot never
    ran. tell now refuses in one line naming the changed value, the store untouched; the
    file as written (or deleted) is told as before."""
    d = tmp_path / "s"
    assert run_cli("ask", d, "--system", "examples.lqr_chain:make_system", "--n", "3")[0] == 0
    f = d / "suggestions" / "1.json"
    params = json.loads(f.read_text())
    name = next(iter(params))
    edited = {**params, name: params[name] * 0.5 + 0.01}
    f.write_text(json.dumps(edited))
    line = error_line(*run_cli("tell", d, "1", "--cost", "1.0")[::2])
    assert f"{name} = {edited[name]:.6g} in it, {params[name]:.6g} suggested" in line
    assert "release" in line
    f.write_text("{not json")
    assert "not valid JSON" in error_line(*run_cli("tell", d, "1", "--cost", "1.0")[::2])
    with lt.Study(d) as st:
        assert st.store.count(Phase.PHASE1) == 0
    assert run_cli("ask", d)[0] == 0                       # 1 again: its file rewritten
    assert json.loads(f.read_text()) == params
    assert run_cli("tell", d, "1", "--cost", "1.0")[0] == 0
    (d / "suggestions" / "2.json").unlink()                # no file: nothing to compare
    assert run_cli("tell", d, "2", "--cost", "1.0")[0] == 0


def test_commands_suggested_for_a_directory_with_spaces_are_quoted(run_cli, tmp_path,
                                                                    error_line):
    """``status`` ("write it with: latentune best runs/my run") and ``tell`` on an edited
    suggestion file ("latentune ask runs/my run", "latentune release runs/my run 1") printed
    a run directory with a space unquoted, so the command pasted into a shell named another
    directory; they quote it, as the report's resume hint does."""
    import shlex

    d = tmp_path / "my run é"
    q = shlex.quote(str(d))
    assert run_cli("ask", d, "--system", "examples.lqr_chain:make_system", "--n", "2")[0] == 0
    f = d / "suggestions" / "1.json"
    params = json.loads(f.read_text())
    name = next(iter(params))
    f.write_text(json.dumps({**params, name: params[name] * 0.5 + 0.01}))
    line = error_line(*run_cli("tell", d, "1", "--cost", "1.0")[::2])
    assert f"`latentune ask {q}`" in line and line.endswith(f"latentune release {q} 1")
    assert run_cli("tell", d, "2", "--cost", "1.0")[0] == 0
    (d / "best.json").unlink()                  # status then says how to write it
    out = run_cli("status", d)[1]
    assert out.splitlines()[-1].endswith(f"; write it with: latentune best {q}"), out


def test_ask_phase_3_in_a_phase_1_run_with_a_space_quotes_the_vae_directory(run_cli, tmp_path,
                                                                           error_line):
    """``ask DIR --phase 3`` on a phase-1 ask/tell run in a directory with a space said "then
    ask phase 3 in another directory, with --vae runs/my run" (the train-vae command beside
    it quoted): the --vae value is quoted for a shell too."""
    import shlex

    sp = tmp_path / "S.yaml"
    sp.write_text(SPACE_YAML)
    d = tmp_path / "my run"
    assert run_cli("ask", d, "--space", sp)[0] == 0
    assert run_cli("tell", d, "1", "--cost", "1.0")[0] == 0
    line = error_line(*run_cli("ask", d, "--phase", "3")[::2])
    assert line.endswith(f"ask phase 3 in another directory, with --vae {shlex.quote(str(d))}")


def test_ask_says_when_the_fall_model_rates_a_suggestion_above_its_screen(run_cli, tmp_path,
                                                                          src30):
    """The transfer critic's design ask after the zero-shot θ fell hands out the source's
    elites though its fall model rates them 1.0 likely to fall (its screen: 0.3), and the
    operator at the robot was told nothing. Such a suggestion now carries ``fall_risk`` (the
    ask's highest rated probability and the bound), and `ask` prints one warning line for it."""
    shutil.copytree(src30, tmp_path / "src")
    d = tmp_path / "t"
    with lt.Study(d, seed=0) as st:
        z = st.ask(1, system=plant(0.3), phase=3, latent=tmp_path / "src")[0]
        assert z.phase_name == "zero-shot" and z.fall_risk is None
        st.tell(z.id, None, failed=True)
        (s,) = st.ask()
        assert s.phase_name == "phase 3" and s.fall_risk is not None
        p, bound = s.fall_risk
        assert p > bound and s.to_dict()["fall_risk"] == {"max_fall_prob": p, "bound": bound}
    code, out, err = run_cli("ask", d)                      # s again
    assert code == 0 and out.split()[0] == str(s.id)
    assert err.splitlines() == [
        f"latentune: warning: suggestion {s.id}: the fall model rates θ of the ask that gave it "
        f"up to {p:.2f} likely to fall, above its screen of {bound:.2f}: be ready to catch the "
        f"robot, or release it"]
    code, out, err = run_cli("ask", d, "--json")
    assert json.loads(out)[0]["fall_risk"] == {"max_fall_prob": p, "bound": bound}


def test_a_suggestion_keeps_the_fall_risk_of_the_ask_that_gave_it_after_an_amendment(
        tmp_path, src30):
    """An amendment rebuilds the critic, whose next ask records its decision under the same
    generation as the ask that handed out the pending suggestions, replacing it: a suggestion
    handed out again then carried the new ask's fall risk (the warning said "the ask that gave
    it" rated θ 0.81 likely to fall where that ask had said 0.35, or said nothing). Each
    suggestion keeps the risk of the ask that queued it."""
    shutil.copytree(src30, tmp_path / "src")
    with lt.Study(tmp_path / "t", seed=0) as st:
        z = st.ask(1, system=plant(0.3), phase=3, latent=tmp_path / "src")[0]
        st.tell(z.id, None, failed=True)
        (s,) = st.ask(asker="alice")
        assert s.fall_risk is not None
        st.tell(z.id, 0.5, amend=True)              # it stood after all: the critic is rebuilt
        (other,) = st.ask(asker="bob")
        assert other.id != s.id and other.fall_risk != s.fall_risk
        (again,) = st.ask(asker="alice")
        assert again.id == s.id and again.again and again.fall_risk == s.fall_risk


def test_tell_says_when_a_robot_trial_fell(run_cli, tmp_path, error_line):
    """At the robot, a fall could only be told as --failed, which costs 2·C1 whenever it fell:
    the falls were all equal and nothing ranked them (the transfer critic learns from a later
    fall being better). ``tell --failed --fall-step K --horizon N`` costs C1·(2 − K/N), as a
    simulated fall; the two flags go together, need --failed and 0 ≤ K ≤ N."""
    d = tmp_path / "s"
    assert run_cli("ask", d, "--system", "examples.lqr_chain:make_system", "--n", "3")[0] == 0
    code, out, err = run_cli("tell", d, "1", "--failed", "--fall-step", "75", "--horizon", "100")
    assert code == 0, err
    assert run_cli("tell", d, "2", "--failed")[0] == 0
    with lt.Study(d) as st:
        rows = st.store.rows(Phase.PHASE1)
    assert sorted(r.cost for r in rows) == [C1 * 1.25, 2 * C1]
    assert [(r.info["fall_step"], r.info["horizon"]) for r in rows
            if "fall_step" in r.info] == [(75, 100)]
    for flags, want in ((["--failed", "--fall-step", "3"], "go together"),
                        (["--cost", "1", "--fall-step", "3", "--horizon", "9"], "add --failed"),
                        (["--failed", "--fall-step", "12", "--horizon", "9"], "within 0"),
                        (["--failed", "--fall-step", "1", "--horizon", "0"], "within 0")):
        assert want in error_line(*run_cli("tell", d, "3", *flags)[::2]), flags
    with lt.Study(d) as st:
        assert len(st.store.rows(Phase.PHASE1)) == 2


def test_status_lists_the_phases_in_the_order_they_ran(tmp_path):
    """status listed phase 3 before the zero-shot trial that opens it (the phases' numbers)."""
    from latentune.pipeline.results import status

    with store_module.RunStore(tmp_path / "s", create=True) as st:
        st.add(Phase.PHASE3, 0, np.zeros(2), 1.0, fell=False, tag=-1)
        st.add(Phase.ZERO_SHOT, 0, np.ones(2), 2.0, fell=False, tag=-1)
        assert list(status(st, tmp_path / "s")["phases"]) == ["zero-shot", "phase 3"]


def test_a_target_naming_its_parameters_in_another_order_is_told_which(tmp_path, src30):
    """A target with the source's names in another order (or one renamed) was refused with
    'trained on θ with other names than the system's', which read as a bug when the names were
    the same: the line says they are in another order, or which names differ, before anything
    is stored."""
    from latentune.errors import LatentError

    other = lt.ParameterSpace(["b", "a", "c", "d"], [-1.0] * 4, [1.0] * 4)
    renamed = lt.ParameterSpace(["a", "b", "c", "e"], [-1.0] * 4, [1.0] * 4)
    assert SPACE.box_difference(other.to_dict()) == \
        "the same names in another order (b, a, c, d there; a, b, c, d here)"
    assert SPACE.box_difference(renamed.to_dict()) == "other names (e there, not here; d here, " \
                                                      "not there)"
    for sp, expect in ((other, r"the same names in another order \(a, b, c, d there; "
                                r"b, a, c, d here\)"),
                       (renamed, r"other names \(d there, not here; e here, not there\)")):
        sys_ = lt.FunctionSystem(sp, lambda x: float(np.sum(x ** 2)))
        with lt.Study(tmp_path / "".join(sp.names), seed=0) as st:
            with pytest.raises(LatentError, match=expect):
                st.phase3(sys_, 4, latent=src30)
            with pytest.raises(LatentError, match=expect):
                st.ask(system=sys_, phase=3, latent=src30)
            assert st.trials() == []


def test_status_and_report_count_one_ask_and_one_fall_in_the_singular(run_cli, tmp_path, src30):
    """``latentune status`` said "phase 3 decisions: 1 asks" and "1 falls counted, 1 allowed"
    after a transfer phase 3's first ask and fall; the report "1 asks: design 1". Each count
    of one is now singular."""
    shutil.copytree(src30, tmp_path / "src")
    with lt.Study(tmp_path / "t", seed=0) as st:
        s = st.ask(2, system=plant(0.3), phase=3, latent=tmp_path / "src", budget=4,
                   transfer_options={"fall_budget": 0.25})
        st.tell(s[0].id, 0.2)
        st.tell(s[1].id, None, failed=True)
    code, out, err = run_cli("status", tmp_path / "t")
    assert code == 0, err
    assert "phase 3 decisions: 1 ask (" in out, out
    assert "fall budget: 1 fall counted" in out and "1 allowed" in out, out
    assert re.search(r"\b1 (asks|falls|trials)\b", out) is None, out
    code, out, err = run_cli("report", tmp_path / "t", "--no-sim", "--quiet")
    assert code == 0, err
    md = (tmp_path / "t" / "report.md").read_text()
    assert "\n1 ask: design 1." in md, md
    assert re.search(r"\b1 (asks|falls|trials|evaluations)\b", md) is None, md


def test_a_failing_ask_tell_phase_advises_a_new_directory_and_what_it_does_not_run(
        run_cli, tmp_path, caplog, error_line):
    """After 8 falls in a row, ``latentune tell`` on an ask/tell phase 1 asked with
    ``--max-fall-prob 0.4`` advised "try the fall-aware critic (--max-fall-prob 0.3), a start
    θ that does not fail, or narrower bounds": the phase screens at 0.4 already, and the next
    ask refuses another --max-fall-prob or --start (the first ask fixed them). The advice now
    names the screen it runs and says the options go with a new directory; a phase run names
    its screen too."""
    d = tmp_path / "a"
    with lt.Study(d, seed=0) as st:
        ids = [s.id for s in st.ask(FAIL_STREAK, system=lt.FunctionSystem(SPACE, all_fail),
                                    max_fall_prob=0.4)]
    for i in ids[:-1]:
        assert run_cli("tell", d, i, "--failed")[0] == 0
    code, out, err = run_cli("tell", d, ids[-1], "--failed")
    assert code == 0, err
    (msg,) = [ln for ln in err.splitlines() if "trials all failed" in ln]
    assert "--max-fall-prob 0.3" not in msg and "a lower --max-fall-prob (it screens at 0.4)" \
        in msg, msg
    assert "in a new directory (the first ask fixed this one's options)" in msg, msg
    refused = error_line(*run_cli("ask", d, "--max-fall-prob", "0.3")[::2])
    assert "runs with --max-fall-prob 0.4 (stored), not --max-fall-prob 0.3" in refused
    caplog.clear()
    with caplog.at_level(logging.WARNING), lt.Study(tmp_path / "run", seed=0) as st:
        st.phase1(lt.FunctionSystem(SPACE, all_fail), FAIL_STREAK, max_fall_prob=0.4)
    (msg,) = [r.getMessage() for r in caplog.records if "trials all failed" in r.getMessage()]
    assert "it screens at 0.4" in msg and "new directory" not in msg, msg


def test_the_tell_that_spends_the_fall_budget_says_the_phase_is_over(run_cli, tmp_path, src30):
    """The tell that spent a transfer phase 3's fall budget warned "the next suggestion was not
    prepared (…fall budget is spent (2 falls; 4 trials told)…); the next ask asks the critic",
    though the next ask only refuses, and the refusal named the API's ``fall_budget``. The tell
    now says once that the fall budget is spent and the best θ is the result, with the falls
    allowed by name; at the command line it names the flag (an ask with a larger --budget),
    where it said budget (the ask's refusal was translated, the tell's warning not)."""
    shutil.copytree(src30, tmp_path / "src")
    d = tmp_path / "t"
    with lt.Study(d, seed=0, batch_size=2) as st:
        s = st.ask(3, system=plant(0.3), phase=3, latent=tmp_path / "src", budget=4,
                   transfer_options={"fall_budget": 0.25})
        st.tell(s[0].id, 0.2)
        st.tell(s[1].id, None, failed=True)
    code, out, err = run_cli("tell", d, s[2].id, "--cost", "0.3")
    assert code == 0, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "not prepared" not in err and "asks the critic" not in err, err
    assert "phase 3's fall budget is spent (1 fall allowed; 2 trials told): its best θ is " \
        "the result; an ask with a larger --budget allows more falls" in lines[0], err
    code, out, err = run_cli("ask", d)
    assert code == 2 and "fall budget is spent" in err and "fall_budget" not in err, err
    assert "an ask with a larger --budget allows more falls" in err, err


def falls_mid(x: np.ndarray):
    """A quadratic that falls where b + c > 0.5 (physical)."""
    if x[1] + x[2] > 0.5:
        return lt.Outcome(None, failed=True)
    return float(np.sum((x - 0.2) ** 2))


def test_a_phase_run_stops_in_its_batch_where_ask_tell_stops_at_the_fall_budget(run_cli,
                                                                                 tmp_path, src30,
                                                                                 caplog):
    """``phase3(..., transfer_options={"fall_budget": 0.1})`` (1 fall allowed) whose first
    trial after the standing zero-shot one fell ran the other three trials of its batch all
    the same (one more fall: 2 counted, 1 allowed), where ask/tell hands out nothing after
    that tell. The phase run now starts no trial once the budget is spent: it stores the rows
    ask/tell stores, says it stopped with 3 trials of its batch not run, and ``status``
    reports the budget (3 asked, not run) as for ask/tell. The stop was said only at -v
    (``phase3`` ended with fewer trials and no word why): it is a warning now."""
    shutil.copytree(src30, tmp_path / "src")
    sys_ = lt.FunctionSystem(SPACE, falls_mid)
    opts = {"fall_budget": 0.1}
    lines: list[str] = []
    with lt.Study(tmp_path / "run", seed=0, log=lines.append) as run:
        res = run.phase3(sys_, 12, latent=tmp_path / "src", transfer_options=opts)
        got = rows_of(run, Phase.PHASE3), rows_of(run, Phase.ZERO_SHOT), run.status()
    assert res.n == 1 and res.not_run == 3, res
    assert lines[-1].endswith("stopped at 1 of 12 trials: its fall budget (1 fall) is spent "
                              "(3 trials of its last batch not run)"), lines[-1]
    with lt.Study(tmp_path / "run", seed=0) as run, caplog.at_level(logging.WARNING):
        again = run.phase3(sys_, 12, latent=tmp_path / "src", transfer_options=opts)
        assert (again.n, again.n_new, again.not_run) == (1, 0, 3) and run.status() == got[2]
    # said without -v (a warning, as the tell that spends it), by the run and its resume
    assert [r.getMessage() for r in caplog.records if "fall budget" in r.getMessage()] == [
        "phase 3's fall budget is spent (1 fall allowed): stopped after 1 of 12 trials (3 "
        "trials of its last batch not run); its best θ is the result"] * 2
    with lt.Study(tmp_path / "at", seed=0) as at:
        with pytest.raises(asktell.FallBudgetSpent):
            person(at, sys_, 12, system=sys_, phase=3, latent=tmp_path / "src", budget=12,
                   transfer_options=opts)
        want = rows_of(at, Phase.PHASE3), rows_of(at, Phase.ZERO_SHOT), at.status()
    assert got[:2] == want[:2]
    assert got[2]["fall_budget"] == want[2]["fall_budget"] == {
        "falls_allowed": 1, "falls": 1, "counts": "after_stand", "spent": True, "not_run": 3}
    code, out, _ = run_cli("status", tmp_path / "run")
    assert code == 0 and "1 allowed; spent: phase 3 asks no more (3 trials asked not run)" \
        in out, out


def test_an_ask_after_the_fall_budget_is_spent_refuses_as_status_says(run_cli, tmp_path, src30,
                                                                      caplog):
    """``latentune status`` said "fall budget: 1 fall counted, 1 allowed; spent: phase 3 asks no
    more", while ``latentune ask`` went on handing out the rest of the batch asked before the
    fall (the robot fell again on them), and the tell that spent it said nothing. An ask now
    refuses once the fall budget is spent, as status says, naming the suggestions still out
    (they may be told); the store is unchanged; the tell that spends it says so."""
    shutil.copytree(src30, tmp_path / "src")
    d = tmp_path / "t"
    with lt.Study(d, seed=0) as st:
        (z,) = st.ask(system=plant(0.3), phase=3, latent=tmp_path / "src", budget=4,
                      transfer_options={"fall_budget": 0.25})
        st.tell(z.id, 0.2)
        a, b = st.ask(2)                    # a batch of 4: two handed out, two queued
        with caplog.at_level(logging.WARNING):
            st.tell(a.id, None, failed=True)    # the one fall allowed: the tell says so
        (msg,) = [r.getMessage() for r in caplog.records if "fall budget" in r.getMessage()]
        assert "phase 3's fall budget is spent (1 fall allowed; 1 trial told): its best θ is " \
            "the result" in msg and f"suggestion {b.id} handed out before may still" in msg, msg
        assert st.status()["fall_budget"]["spent"]
        before = [(t.id, t.status, t.asker) for t in st.store.trials()]
        assert [s for _, s, _ in before].count("queued") == 2
        with pytest.raises(asktell.FallBudgetSpent, match=f"suggestion {b.id} handed out before "
                                                          "may still be told"):
            st.ask()
        assert [(t.id, t.status, t.asker) for t in st.store.trials()] == before
        st.tell(b.id, 0.3)
    code, out, err = run_cli("status", d)
    assert code == 0 and "spent: phase 3 asks no more" in out, out
    code, out, err = run_cli("ask", d)
    assert code == 2 and out == "" and "fall budget is spent" in err, (out, err)
    assert "may still be told" not in err and len(err.strip().splitlines()) == 1, err


def test_an_ask_past_a_told_budget_names_the_flag_and_no_pending_suggestions(run_cli, tmp_path,
                                                                            error_line):
    """``latentune ask`` on an ask/tell phase whose whole budget was told said "budget of 2
    trials is handed out (2 told, 0 pending): tell the pending ones, or ask with a larger
    budget": there is nothing pending, and the flag is ``--budget``. It now says the budget is
    told and names --budget; with suggestions out it still says to tell them."""
    d = tmp_path / "a"
    with lt.Study(d, seed=0) as st:
        s = st.ask(2, system=plant(), budget=2)
        st.tell(s[0].id, 0.5)
    line = error_line(*run_cli("ask", d, "--asker", "bob")[::2])
    assert "(1 told, 1 pending): tell the pending ones, or ask with a larger --budget" in line
    with lt.Study(d) as st:
        st.tell(s[1].id, 0.4)
    line = error_line(*run_cli("ask", d)[::2])
    assert "phase 1's budget of 2 trials is told: its best θ is the result " in line, line
    assert "pending" not in line and line.endswith("or ask with a larger --budget"), line
    d = tmp_path / "fell"
    with lt.Study(d, seed=0) as st:
        for s in st.ask(2, system=plant(), budget=2):
            st.tell(s.id, failed=True)
    line = error_line(*run_cli("ask", d)[::2])      # said its best θ is the result
    assert "phase 1's budget of 2 trials is told and no trial stood: there is no θ to deploy; " \
           "ask with a larger --budget" in line and "best θ" not in line, line


def test_telling_a_told_zero_shot_trial_again_names_its_phase(tmp_path, src30):
    """Telling the zero-shot suggestion a second time was refused with '(evaluation 0 of phase
    4; ...)': the store's code of the zero-shot phase, a phase the user never heard of. The
    line names the phase as ``tell`` and ``status`` do: 'zero-shot evaluation 0'."""
    shutil.copytree(src30, tmp_path / "src")
    with lt.Study(tmp_path / "t", seed=0) as st:
        (s,) = st.ask(1, system=plant(0.3), phase=3, latent=tmp_path / "src")
        assert s.phase_name == "zero-shot"
        st.tell(s.id, 0.5)
        with pytest.raises(StoreError) as err:
            st.tell(s.id, 0.4)
    msg = str(err.value)
    assert "phase 4" not in msg and "(zero-shot evaluation 0)" in msg and "amend=True" in msg


def test_a_refused_first_ask_of_phase_3_leaves_no_files(run_cli, tmp_path, src30, error_line):
    """A refused first ``latentune ask DIR --phase 3`` (a missing or bad --vae, a latent space
    of another dimension, --target-scores with --strategy plain, a latent space given to phase
    1) left a run.db and run.lock in DIR (with --target-scores also a copied latent space),
    where ``latentune phase3`` writes nothing. It now refuses before it creates anything."""
    space = tmp_path / "space.json"
    space.write_text(json.dumps(SPACE.to_dict()))
    three = tmp_path / "space3.json"
    three.write_text(json.dumps(lt.ParameterSpace(["a", "b", "c"], [-1.0] * 3, [1.0] * 3)
                                .to_dict()))
    cases = [(("--vae", tmp_path / "nowhere"), "does not exist"),
             ((), "no latent space in"),
             (("--vae", src30, "--space", three), "maps to 4-dim θ"),
             (("--vae", src30, "--strategy", "plain", "--target-scores", "auto"),
              "--target-scores is an option of the transfer phase 3")]
    for i, (flags, says) in enumerate(cases):
        d = tmp_path / f"t{i}"
        line = error_line(*run_cli("ask", d, "--phase", "3", "--space", space, *flags)[::2])
        assert says in line, line
        assert not d.exists(), sorted(p.name for p in d.iterdir())
    d = tmp_path / "empty"
    d.mkdir()
    line = error_line(*run_cli("ask", d, "--phase", "1", "--space", space, "--vae", src30)[::2])
    assert "a latent space is an option of phase 3" in line and list(d.iterdir()) == [], line
    code, out, err = run_cli("ask", d, "--phase", "3", "--space", space, "--vae", src30)
    assert code == 0 and (d / "run.db").is_file() and (d / "phase3_vae.pt").is_file(), err


def whole_store(run_dir: Path) -> list[str]:
    """Every table, schema and row of a run store as SQL lines (read-only)."""
    con = sqlite3.connect(f"file:{Path(run_dir) / 'run.db'}?mode=ro", uri=True)
    try:
        return list(con.iterdump())
    finally:
        con.close()


def test_a_first_ask_that_fails_after_its_checks_leaves_no_files(run_cli, tmp_path, error_line):
    """``latentune ask DIR --space S --max-fall-prob 0.3 --fall-prior RUN`` with a RUN of
    3-dim θ for a 4-dim space passed the first ask's checks and failed building the critic:
    it said so in one line but left DIR/run.db and run.lock, and the next ask (without the
    prior) failed with the same line, the half-made run holding the bad prior. The failed
    first ask now leaves the directory as it was: none, or an existing one as it was."""
    space = tmp_path / "space.json"
    space.write_text(json.dumps(SPACE.to_dict()))
    s3 = lt.ParameterSpace(["a", "b", "c"], [-1.0] * 3, [1.0] * 3)
    with lt.Study(tmp_path / "prior3", seed=0) as p:
        p.phase1(lt.FunctionSystem(s3, lambda x: plant_fn(np.r_[x, 0.0])), 6)
    bad = ("--space", space, "--max-fall-prob", "0.3", "--fall-prior", tmp_path / "prior3")
    d = tmp_path / "new"
    line = error_line(*run_cli("ask", d, *bad)[::2])
    assert "fall prior" in line and "3 entries, not 4" in line, line
    assert not d.exists(), sorted(p.name for p in d.iterdir())
    kept = tmp_path / "kept"
    kept.mkdir()
    (kept / "notes.txt").write_text("mine")
    error_line(*run_cli("ask", kept, *bad)[::2])
    assert [p.name for p in kept.iterdir()] == ["notes.txt"]
    code, out, err = run_cli("ask", d, "--space", space)
    assert code == 0 and out.startswith("1\tphase 1"), (out, err)


def test_a_failing_first_ask_of_phase_3_leaves_the_run_as_it_was(tmp_path, src30, monkeypatch):
    """A first ``Study.ask(phase=3)`` whose critic failed while asking its first batch (here
    the transfer critic's ask raising) left its phase-3 options, the queued zero-shot
    suggestion and the copied latent space behind: in a new directory a run the next ask
    went on with; in the source run itself its options record had a phase 3 that never
    asked. The error now comes
    out as it was raised and the directory is as it was: no run in a new one, the source
    run's store unchanged (schema, meta and rows)."""
    from latentune.critic.transfer import Transfer

    shutil.copytree(src30, tmp_path / "src")
    src = tmp_path / "src"
    before = (whole_store(src), sorted(p.name for p in src.iterdir()))

    def broken(self, n):
        raise RuntimeError("the GP fit failed")

    monkeypatch.setattr(Transfer, "ask", broken)
    for d, latent in ((tmp_path / "t", src), (src, None)):
        with lt.Study(d, seed=0) as st, pytest.raises(RuntimeError, match="GP fit failed"):
            st.ask(2, system=plant(0.3), phase=3, latent=latent)
    assert not (tmp_path / "t").exists(), sorted(p.name for p in (tmp_path / "t").iterdir())
    assert (whole_store(src), sorted(p.name for p in src.iterdir())) == before
    monkeypatch.undo()
    with lt.Study(tmp_path / "t", seed=0) as st:
        assert [s.phase_name for s in st.ask(2, system=plant(0.3), phase=3, latent=src)] == \
            ["zero-shot", "phase 3"]


def test_a_writer_waiting_for_a_failed_first_write_holds_the_lock_it_gets(tmp_path,
                                                                         monkeypatch):
    """A failed first write removes DIR/run.lock while it holds it (and DIR it created). A
    writer that waited for it must not hold the removed file's lock (a third writer creating
    a new run.lock would write at the same time): the waiter takes the lock on the file
    there, and the third is refused. The first write fails only once the waiter has found the
    lock taken (its first ``flock`` refused), however slowly the waiter's thread starts."""
    import fcntl
    import threading

    from latentune.errors import LockError
    from latentune.pipeline.rundir import RunDir

    d = tmp_path / "run"
    first, waiter = RunDir(d), RunDir(d)
    holding, checked, refused = threading.Event(), threading.Event(), threading.Event()
    flock = fcntl.flock

    def watched_flock(fd, op):
        try:
            return flock(fd, op)
        except OSError:
            if threading.current_thread() is t:
                refused.set()
            raise

    monkeypatch.setattr(fcntl, "flock", watched_flock)

    def wait_for_it():
        with waiter.writing(wait=10):
            holding.set()
            checked.wait(10)

    t = threading.Thread(target=wait_for_it)
    with pytest.raises(RuntimeError, match="critic"):
        with first.writing(), first.as_before_on_error():
            t.start()
            assert refused.wait(10)     # the waiter is waiting for the lock
            raise RuntimeError("the critic failed")
    try:
        assert holding.wait(10)
        with pytest.raises(LockError):
            with RunDir(d).writing():
                pass
    finally:
        checked.set()
        t.join(10)
        waiter.close()
    assert sorted(p.name for p in d.iterdir() if "-" not in p.name) == ["run.db", "run.lock"]


def test_another_latent_space_after_the_zero_shot_trial_is_refused(run_cli, tmp_path, src30,
                                                                   error_line):
    """``latentune ask DIR --vae B`` after a first ask with ``--vae A`` had handed out (or
    told) the zero-shot trial, A's best θ, switched phase 3 to B's latent space and source
    run without a word (options are fixed by a phase-3 trial, and the zero-shot one is not);
    ``Study.phase3(latent=B)`` after a run that stopped after its zero-shot trial did the
    same. Both are refused now, naming A, and nothing is changed."""
    shutil.copytree(src30, tmp_path / "A")
    shutil.copytree(src30, tmp_path / "B")
    space = tmp_path / "space.json"
    space.write_text(json.dumps(SPACE.to_dict()))
    d = tmp_path / "t"
    code, out, err = run_cli("ask", d, "--space", space, "--phase", "3", "--vae", tmp_path / "A")
    assert code == 0 and "zero-shot" in out, err
    for told in (False, True):
        if told:
            with lt.Study(d) as st:
                st.tell(1, 0.3)
        before = whole_store(d)
        line = error_line(*run_cli("ask", d, "--vae", tmp_path / "B")[::2])
        # the zero-shot trial fixes phase 3's options: refused as another option is
        assert f"phase 3 was run with --vae {(tmp_path / 'A').resolve()} (stored), not --vae " \
            f"{(tmp_path / 'B').resolve()}" in line, line
        assert whole_store(d) == before
    with lt.Study(tmp_path / "run", seed=0) as st:
        assert st.phase3(plant(0.3), 4, latent=tmp_path / "A", max_new=0).n == 0
        assert st.store.count(Phase.ZERO_SHOT) == 1
        with pytest.raises(StoreError, match="phase3 was run with latent-source = .*A', not "):
            st.phase3(plant(0.3), 4, latent=tmp_path / "B")
        assert st.config()["phase3"]["latent_source"] == str((tmp_path / "A").resolve())


def test_an_ask_of_more_than_the_budget_leaves_says_how_many_it_handed_out(run_cli, tmp_path,
                                                                           caplog):
    """``latentune ask DIR --n 5`` with 3 suggestions left in the phase's budget handed out 3
    and said nothing. It now warns in one line how many it handed out and why (exit 0); the
    API logs the same warning."""
    space = tmp_path / "space.json"
    space.write_text(json.dumps(SPACE.to_dict()))
    code, out, err = run_cli("ask", tmp_path / "a", "--space", space, "--budget", "3",
                             "--n", "5")
    assert code == 0 and len(out.splitlines()) == 3, (out, err)
    assert err.splitlines() == [
        f"latentune: warning: {tmp_path / 'a'}: handed out 3 of the 5 suggestions asked: "
        "phase 1's budget of 3 trials has no more (0 told, 3 handed out); ask with a larger "
        "--budget for more"], err
    code, out, err = run_cli("ask", tmp_path / "a", "--n", "3")      # the same 3 again: quiet
    assert code == 0 and len(out.splitlines()) == 3 and err == "", err
    with lt.Study(tmp_path / "b", seed=0) as st, caplog.at_level(logging.WARNING):
        assert len(st.ask(4, space=SPACE, budget=2)) == 2
    assert [r.getMessage().split(": ", 1)[1] for r in caplog.records] == [
        "handed out 2 of the 4 suggestions asked: phase 1's budget of 2 trials has no more "
        "(0 told, 2 handed out); ask with a larger budget for more"]


def test_a_latent_space_file_given_for_its_run_directory_is_named_a_file(run_cli, tmp_path,
                                                                         src30, error_line):
    """``latent='run/vae.pt'`` (a file that exists) said "run directory run/vae.pt does not
    exist". Phase 3, ask and ``--vae`` now say it is a file and that latent is the run
    directory holding the latent space and run.db (naming it), before anything is stored."""
    from latentune.errors import LatentError

    f = src30 / "vae.pt"
    says = (f"latent: {f} is a file, not a run directory: give the run directory that holds "
            f"the latent space (vae.pt, vae.json) and run.db ({src30})")
    with lt.Study(tmp_path / "t", seed=0) as st:
        with pytest.raises(LatentError) as exc:
            st.phase3(plant(), 4, latent=f)
        assert str(exc.value) == says
        with pytest.raises(LatentError) as exc:
            st.ask(system=plant(), phase=3, latent=str(f))
        assert str(exc.value) == says
    assert not (tmp_path / "t").exists()
    space = tmp_path / "space.json"
    space.write_text(json.dumps(SPACE.to_dict()))
    line = error_line(*run_cli("ask", tmp_path / "u", "--space", space, "--vae", f)[::2])
    assert line.endswith(f"--vae: {says[len('latent: '):]}"), line


def test_an_ask_without_a_phase_goes_on_with_the_phase_3_a_phase_run_began(tmp_path, src30,
                                                                           run_cli):
    """A target run made by a phase run (``phase3 --vae SRC``), then ``latentune ask DIR``
    without ``--phase``: the ask handed out the manual θ as a *phase-1* suggestion of the
    target and fixed ask/tell there to phase 1, so ``ask --phase 3`` was then refused (with
    the hint to ask phase 3 'with --vae DIR', the target itself). It goes on with the run's
    phase 3 (as ``--phase 3`` does); a run that holds phase 1 alone still asks phase 1."""
    sys_ = plant()
    with lt.Study(tmp_path / "t", seed=0) as st:
        st.phase3(sys_, 4, latent=src30)
    with lt.Study(tmp_path / "t") as st:
        (s,) = st.ask(1, budget=6)
        assert s.phase_name == "phase 3"
        assert st.store.count(Phase.PHASE1) == 0
    code, out, err = run_cli("ask", tmp_path / "t")
    assert code == 0 and "\tphase 3 (again)\t" in out and "phase 1" not in out, (out, err)
    with lt.Study(tmp_path / "p1", seed=0) as st:
        st.phase1(sys_, 4)
    with lt.Study(tmp_path / "p1") as st:
        (s,) = st.ask(1, budget=6)
        assert s.phase_name == "phase 1"


def test_a_phase_of_one_evaluation_logs_1_evaluation(tmp_path, src30):
    """``Study.phase3(..., max_new=1)`` logged "phase 3: 1 evaluations"; phase 1's line had
    the same plural. Both now agree with the count."""
    lines: list[str] = []
    with lt.Study(tmp_path / "t", seed=0, log=lines.append) as t:
        t.phase3(plant(0.2), 5, latent=src30, max_new=1)
        t.phase1(plant(0.2), 3, max_new=1)
    said = [ln for ln in lines if ln.startswith("phase ")]
    assert said[0].startswith("phase 3: 1 evaluation, ") and said[1].startswith(
        "phase 1: 1 evaluation, "), lines


def test_ask_phase_3_in_a_phase_1_run_without_a_latent_space_says_to_train_one(run_cli,
                                                                                 tmp_path):
    """``ask DIR --phase 3`` where ask/tell runs phase 1 said "ask phase 3 in another
    directory, with --vae DIR" though DIR held no latent space (that --vae is refused: "holds
    no latent space"). It now says to train it first, with the command; once trained, the
    advice is --vae DIR alone."""
    d = tmp_path / "p1"
    sys_ = ("--system", "examples.lqr_chain:make_system")
    assert run_cli("ask", d, *sys_, "--n", "2", "--budget", "6")[0] == 0
    code, _, err = run_cli("ask", d, "--phase", "3")
    assert code == 2 and err.strip().splitlines()[-1] == (
        f"latentune: error: {d}: ask/tell runs with --phase 1 (stored), not --phase 3; {d} "
        f"holds no latent space yet: train one there first (latentune train-vae --out {d} "
        "--system examples.lqr_chain:make_system), "
        f"then ask phase 3 in another directory, with --vae {d}"), err
    with lt.Study(d) as st:
        for s in st.ask(2):
            st.tell(s.id, 1.0 + s.id)
        st.train_latent(latent_dim=2, epochs=5)
    code, _, err = run_cli("ask", d, "--phase", "3")
    assert code == 2 and err.strip().endswith(
        "not --phase 3; ask phase 3 in another directory, with --vae " + str(d)), err


def test_an_ask_that_fails_in_the_critic_hands_out_nothing(tmp_path, src30):
    """An ask that had leased queued suggestions and then failed building the next batch (here:
    its fall prior's run was moved away, refused before the critic is built) kept them leased: ``status`` showed them pending, and the same
    asker's next ask gave them back as handed out before. A failed ask now hands out nothing:
    its leases are undone."""
    prior = tmp_path / "prior"
    shutil.copytree(src30, prior)
    with lt.Study(tmp_path / "a", seed=0) as st:
        (first,) = st.ask(system=plant(), max_fall_prob=0.3, fall_prior=prior, budget=20)
        queued = [t.id for t in st.store.trials("queued")]
        assert queued                           # the rest of the first batch
    prior.rename(tmp_path / "gone")
    with lt.Study(tmp_path / "a") as st:
        with pytest.raises(LatentuneError, match=r"^fall_prior: the run at .*prior is not the "
                                                 r"run phase 1 began with: it does not exist"):
            st.ask(len(queued) + 2)
        assert [t.id for t in st.store.trials("pending")] == [first.id]
        assert [t.id for t in st.store.trials("queued")] == queued
        assert st.status()["pending"] == [first.id]
    (tmp_path / "gone").rename(prior)
    with lt.Study(tmp_path / "a") as st:
        got = st.ask(2)
        assert [(s.id, s.again) for s in got] == [(first.id, True), (queued[0], False)]


def test_the_zero_shot_trial_alone_fixes_phase_3s_options(tmp_path, src30, run_cli):
    """After only phase 3's zero-shot trial (asked and told), a phase-3 run or ask could still
    change phase 3's batch size and fall budget, and recorded the source run's size anew (its
    phase 1 had grown): the zero-shot trial was not counted as a trial of phase 3. It fixes
    them as a phase-3 trial does: another value is refused, the source's size stays."""
    src = tmp_path / "src"
    shutil.copytree(src30, src)
    d, target = tmp_path / "t", plant(0.2)
    with lt.Study(d, seed=0) as at:
        (z,) = at.ask(system=target, phase=3, latent=src, budget=10)
        assert z.phase == Phase.ZERO_SHOT
        out = evaluate(target, z.theta)
        at.tell(z.id, out.cost, failed=out.failed)
        stored = at.config()["phase3"]
    with lt.Study(src) as s:
        s.phase1(plant(), 32)                                     # the source grows
    with lt.Study(d, batch_size=2) as st:
        with pytest.raises(StoreError, match="batch-size = 4, not 2"):
            st.ask()
        with pytest.raises(StoreError, match="batch-size = 4, not 2"):
            st.phase3(target, 10, latent=src)
    with lt.Study(d) as st:
        with pytest.raises(StoreError, match="transfer-options = None, not {'fall_budget': 0.3}"):
            st.phase3(target, 10, latent=src, transfer_options={"fall_budget": 0.3})
        assert st.config()["phase3"] == stored
        st.phase3(target, 10, latent=src, max_new=1)
        assert st.config()["phase3"]["source_counts"] == stored["source_counts"]
        assert st.config()["phase3"]["batch_size"] == 4


def _spend_fall_budget_by_ask_tell(st: Any, target: Any, src: Any, opts: dict) -> None:
    """Phase 3 by ask/tell with a batch of 4 until its one allowed fall is spent: the zero-shot
    trial told, two of the batch handed out (one fell, one stood), two left queued."""
    (z,) = st.ask(system=target, phase=3, latent=src, budget=4, transfer_options=opts)
    st.tell(z.id, 0.2)
    a, b = st.ask(2)
    st.tell(a.id, None, failed=True)
    st.tell(b.id, 0.3)


def test_a_phase_run_where_ask_tell_spent_the_fall_budget_keeps_the_not_run_count(tmp_path,
                                                                                   src30):
    """``phase3`` (``latentune phase3 DIR``) in an ask/tell directory whose fall budget was
    spent with two suggestions of the last batch still queued withdrew them, and ``status``
    then said 0 asked not run (it had said 2). The run asks nothing (the budget is spent), so
    it leaves them: status and the run's result both say 2 not run."""
    shutil.copytree(src30, tmp_path / "src")
    d, target, opts = tmp_path / "t", plant(0.3), {"fall_budget": 0.25}
    with lt.Study(d, seed=0) as st:
        _spend_fall_budget_by_ask_tell(st, target, tmp_path / "src", opts)
        before = st.status()["fall_budget"]
        assert before["spent"] and before["not_run"] == 2, before
        res = st.phase3(target, 4, latent=tmp_path / "src", transfer_options=opts)
        assert (res.n_new, res.not_run) == (0, 2), res
        assert st.status()["fall_budget"] == before


def test_train_vae_trains_the_latent_space_of_an_ask_tell_run_with_a_space_file(run_cli,
                                                                                 tmp_path,
                                                                                 error_line):
    """``latentune train-vae --out DIR`` after a phase 1 by ``ask DIR --space S.yaml`` / ``tell``
    was refused ("holds a run of another system (kind: stored 'external', given 'task' ...)"),
    and train-vae had no ``--space``: such a run could not reach phase 3. train-vae now trains
    on the stored space (``--space`` the same file is taken; another space, or --robot/--system,
    is refused in one line) and phase 3 by ``ask T --phase 3 --vae DIR`` starts from it."""
    space = tmp_path / "S.json"
    space.write_text(json.dumps(SPACE.to_dict()))
    d = tmp_path / "src"
    for i in range(12):
        code, out, err = run_cli("ask", d, *(("--space", space) if i == 0 else ()))
        assert code == 0, err
        sid, _, path, _ = out.strip().split("\t")
        theta = json.loads(Path(path).read_text())
        out_ = evaluate(plant(), SPACE.parse(theta))
        tell = ("--failed",) if out_.failed else ("--cost", str(out_.cost))
        assert run_cli("tell", d, sid, *tell)[0] == 0
    vae = ("--latent-dim", "2", "--vae-epochs", "20")
    other = tmp_path / "S2.json"
    other.write_text(json.dumps({**SPACE.to_dict(), "high": [1.0, 2.0, 1.0, 1.0]}))
    line = error_line(*run_cli("train-vae", "--out", d, "--space", other, *vae)[::2])
    assert "another parameter space (b: [-1, 2] there, [-1, 1] here" in line, line
    line = error_line(*run_cli("train-vae", "--out", d, "--robot", "b1", *vae)[::2])
    assert "trials run elsewhere (ask --space)" in line and "leave --robot" in line, line
    line = error_line(*run_cli("train-vae", "--out", d, "--space", space, "--system", "m:f",
                               *vae)[::2])
    assert "--space replaces" in line, line
    assert not (d / "vae.pt").exists()
    code, out, err = run_cli("train-vae", "--out", d, *vae)
    assert code == 0 and "d_low 2" in out and (d / "vae.pt").is_file(), err
    code, out, err = run_cli("train-vae", "--out", d, "--space", space, *vae)
    assert code == 0 and "d_low 2" in out, err
    code, out, err = run_cli("ask", tmp_path / "t", "--phase", "3", "--vae", d, "--space", space)
    assert code == 0 and "\tzero-shot\t" in out, err


def test_a_phase_run_calls_ask_tells_queued_suggestions_asked_not_of_its_batch(tmp_path, src30,
                                                                               caplog):
    """``phase3`` in an ask/tell directory whose fall budget ask/tell had spent warned "(2
    trials of its last batch not run)": the run had no batch; the two were queued by ask/tell.
    The warning and the run's line now say "(2 trials asked, not run)"."""
    shutil.copytree(src30, tmp_path / "src")
    d, target, opts = tmp_path / "t", plant(0.3), {"fall_budget": 0.25}
    lines: list[str] = []
    with lt.Study(d, seed=0, log=lines.append) as st:
        _spend_fall_budget_by_ask_tell(st, target, tmp_path / "src", opts)
        with caplog.at_level(logging.WARNING):
            res = st.phase3(target, 4, latent=tmp_path / "src", transfer_options=opts)
    assert (res.not_run, res.asked) == (2, 2), res
    said = [r.getMessage() for r in caplog.records if "stopped after" in r.getMessage()]
    assert said == ["phase 3's fall budget is spent (1 fall allowed): stopped after 2 of 4 "
                    "trials (2 trials asked, not run); its best θ is the result"], said
    assert lines[-1].endswith("is spent (2 trials asked, not run)"), lines[-1]
    assert phases.not_run_note(3, 1) == " (2 trials of its last batch and 1 asked, not run)"


def test_a_phase_run_on_an_ask_tell_run_of_a_space_file_is_refused_in_words(run_cli, tmp_path,
                                                                            error_line):
    """``latentune phase1 --out DIR --resume`` (or ``tune``) on a run made by ``ask DIR --space
    FILE`` said "holds a run of another system (kind: stored 'external', given 'task'; space:
    stored {'names': ...", and ``phase3 --out DIR --resume`` "the latent space maps to 4-dim θ,
    but the system has 25-dim θ" (of the default A1 task nobody asked for). Both now say the
    run holds trials run elsewhere, with what to do instead."""
    space = tmp_path / "S.json"
    space.write_text(json.dumps(SPACE.to_dict()))
    d = tmp_path / "run"
    code, out, err = run_cli("ask", d, "--space", space)
    assert code == 0, err
    assert run_cli("tell", d, out.split("\t")[0], "--cost", "0.5")[0] == 0
    for cmd, more in (("phase1", ()), ("tune", ()), ("phase3", ("--vae", d)),
                      ("phase1", ("--robot", "b1"))):
        line = error_line(*run_cli(cmd, "--out", d, "--resume", *more)[::2])
        assert f"{d} holds trials run elsewhere (ask --space)" in line, line
        assert f"go on with latentune ask {d}" in line, line


def test_an_ask_with_another_space_file_names_the_difference(run_cli, tmp_path, error_line):
    """``latentune ask DIR --space OTHER.yaml`` on a study of another space said only "DIR
    holds a study of another parameter space"; it now names the first difference (a bound, a
    scale, a name, or the manual θ), as ``train-vae --space`` does."""
    space, other, manual = (tmp_path / f"{n}.json" for n in ("S", "S2", "S3"))
    space.write_text(json.dumps(SPACE.to_dict()))
    other.write_text(json.dumps({**SPACE.to_dict(), "high": [1.0, 2.0, 1.0, 1.0]}))
    manual.write_text(json.dumps({**SPACE.to_dict(), "manual": [0.1] * 4}))
    d = tmp_path / "run"
    code, out, err = run_cli("ask", d, "--space", space)
    assert code == 0, err
    line = error_line(*run_cli("ask", d, "--space", other)[::2])
    assert line.endswith("holds a study of another parameter space (b: [-1, 2] there, [-1, 1] "
                         "here; there: the space given, here: the stored one)"), line
    line = error_line(*run_cli("ask", d, "--space", manual)[::2])
    assert line.endswith("holds a study of another parameter space (another manual θ)"), line
    line = error_line(*run_cli("train-vae", "--out", d, "--space", manual)[::2])
    assert "in another parameter space (another manual θ); leave --space out" in line, line


def test_report_with_a_system_on_a_run_of_a_space_says_to_leave_it_out(run_cli, tmp_path,
                                                                       error_line):
    """``latentune report DIR --system M:F`` on a run started with ``ask DIR --space FILE``
    said "holds a run of another system (…): ask it without a system", advice for ``ask``:
    a report re-simulates with --system, and such a run has no system of its own, so the
    line says to leave --system out; report.md is not written."""
    space = tmp_path / "S.json"
    space.write_text(json.dumps(SPACE.to_dict()))
    d = tmp_path / "run"
    assert run_cli("ask", d, "--space", space)[0] == 0
    assert run_cli("tell", d, "1", "--cost", "1.0")[0] == 0
    line = error_line(*run_cli("report", d, "--system", "examples.toy_plant:make_system")[::2])
    assert line == (f"latentune: error: {d} holds trials run elsewhere, in the parameter space "
                    "its first ask was given: it has no system to re-simulate; leave --system "
                    "(and --system-arg) out"), line
    assert not (d / "report.md").exists()


def test_a_system_given_to_an_ask_tell_run_of_a_space_is_refused_in_words(run_cli, tmp_path,
                                                                          error_line):
    """``latentune ask DIR --robot a1`` (or ``Study.ask(system=...)``) on a study started with
    ``ask DIR --space FILE`` said "holds a run of another system (kind: stored 'external',
    given 'task'; space: stored {'names': ['a', ...", a dump of the records; it now says
    what the run holds and to ask it without a system."""
    space = tmp_path / "S.json"
    space.write_text(json.dumps(SPACE.to_dict()))
    d = tmp_path / "run"
    assert run_cli("ask", d, "--space", space)[0] == 0
    want = (f"{d} holds a run of another system (trials run elsewhere, in the parameter space "
            "its first ask was given): ask it without a system")
    line = error_line(*run_cli("ask", d, "--robot", "a1")[::2])
    assert line == f"latentune: error: {want}", line
    with lt.Study(d) as st, pytest.raises(StoreError) as exc:
        st.ask(system=plant())
    assert str(exc.value) == want


def test_an_ask_of_phase_1_in_an_imported_optuna_study_says_what_it_is(run_cli, tmp_path,
                                                                       error_line):
    """``latentune ask DIR`` after ``latentune import-optuna ... --out DIR`` said "unknown
    method 'optuna' (choose from turbo, cma, ...)", a method the user never gave. It now says
    phase 1 is an imported Optuna study that the import adds to, and a phase 3 may use it."""
    optuna = pytest.importorskip("optuna")
    from optuna.storages.journal import JournalFileBackend, JournalStorage

    db = tmp_path / "opt.log"            # a journal file: no database schema to create
    study = optuna.create_study(study_name="sim",
                                storage=JournalStorage(JournalFileBackend(str(db))))
    dists = {n: optuna.distributions.FloatDistribution(-1.0, 1.0) for n in SPACE.names}
    study.add_trials([optuna.trial.create_trial(params=dict(zip(SPACE.names, map(float, x))),
                                                distributions=dists, value=float(np.sum(x ** 2)))
                      for x in np.random.default_rng(0).uniform(-1, 1, (6, 4))])
    d = tmp_path / "O"
    assert run_cli("import-optuna", db, "--study", "sim", "--out", d)[0] == 0
    line = error_line(*run_cli("ask", d)[::2])
    assert line.endswith(f"{d}: phase 1 is an imported Optuna study: importing the study again "
                         "adds its new trials, nothing asks more of it; a phase 3 (here or in "
                         "another directory) can use it as its source"), line


SPACE_YAML = "names: [kp, kd]\nlow: [0.1, 0.0]\nhigh: [10, 1.0]\nmanual: [2.0, 0.5]\n"


@pytest.mark.parametrize("start", ["manual", "scratch"])
def test_an_ask_tell_report_takes_the_manual_theta_from_phase_1s_first_trial(run_cli, tmp_path,
                                                                             start):
    """`ask --space` hands out the manual θ as phase 1's trial 0, and summary.json and the
    report said manual_cost null and "evals to beat manual" "–" though trial 1 beat it: that
    trial's cost is the manual cost (a manual row, evals to beat 2), as in a phase-1 run; a
    first trial that is not the manual θ (--start scratch) is no manual trial."""
    sp = tmp_path / "S.yaml"
    sp.write_text(SPACE_YAML)
    d = tmp_path / "run"
    code, out, err = run_cli("ask", d, "--space", sp, "--n", "3", "--budget", "3",
                             "--start", start)
    assert code == 0, err
    assert ("kp=2, kd=0.5" in out.splitlines()[0]) == (start == "manual")
    for i, c in ((1, "1.0"), (2, "0.5"), (3, "2.0")):
        assert run_cli("tell", d, str(i), "--cost", c)[0] == 0
    code, table, err = run_cli("report", d, "--no-sim")
    assert code == 0, err
    s = json.loads((d / "summary.json").read_text())
    if start == "manual":
        assert s["manual_cost"] == 1.0 and s["manual_fell"] is False
        assert s["phase1_evals"] == 3 and s["phase1_evals_to_beat_manual"] == 2
        assert "| manual tuned | 1.000 | 1 | 1/1 | – |" in table
        assert "| phase 1 (θ, TuRBO-m) | 0.500 | 3 | 3/3 | 2 |" in table
    else:
        assert s["manual_cost"] is None and s["phase1_evals_to_beat_manual"] is None
        assert "manual tuned" not in table


def test_an_ask_tell_report_finds_the_manual_theta_told_after_other_trials(run_cli, tmp_path):
    """With suggestions run in parallel, the manual θ (the first suggestion) told after the
    others is not phase 1's trial 0: the report dropped its manual row and said "evals to
    beat manual" "–", and summary.json manual_cost null, as if the manual θ had never run.
    The manual trial is the first suggestion's, wherever its result was stored."""
    sp = tmp_path / "S.yaml"
    sp.write_text(SPACE_YAML)
    d = tmp_path / "run"
    assert run_cli("ask", d, "--space", sp, "--n", "3", "--budget", "3")[0] == 0
    for i, c in ((2, "0.5"), (3, "2.0"), (1, "1.0")):       # the manual θ's result comes last
        assert run_cli("tell", d, str(i), "--cost", c)[0] == 0
    code, table, err = run_cli("report", d, "--no-sim")
    assert code == 0, err
    s = json.loads((d / "summary.json").read_text())
    assert s["manual_cost"] == 1.0 and s["manual_fell"] is False
    assert s["phase1_evals_to_beat_manual"] == 1
    assert "| manual tuned | 1.000 | 1 | 1/1 | – |" in table
    assert "| phase 1 (θ, TuRBO-m) | 0.500 | 3 | 3/3 | 1 |" in table


def test_the_report_of_an_ask_space_run_is_titled_with_its_space_file(run_cli, tmp_path):
    """The report of a run asked with `--space S.yaml` was titled "user system": it is titled
    with the space file's name, kept from the first ask."""
    sp = tmp_path / "S.yaml"
    sp.write_text(SPACE_YAML)
    d = tmp_path / "run"
    assert run_cli("ask", d, "--space", sp, "--n", "1")[0] == 0
    assert run_cli("tell", d, "1", "--cost", "1.0")[0] == 0
    code, table, err = run_cli("report", d, "--no-sim")
    assert code == 0, err
    assert table.startswith("space S.yaml (trials run elsewhere)\n")
    assert (d / "report.md").read_text().startswith(
        "# latentune run: space S.yaml (trials run elsewhere)\n")


def test_the_report_of_an_api_ask_space_run_names_its_space(tmp_path):
    """``Study.ask(space=...)`` gave a report titled "user system", where ``latentune ask
    --space FILE`` titles it with the file: the title names the space, by its ``name`` (the
    file the command line read it from) or else its first names, recorded with the space."""
    spaces = {"named": lt.ParameterSpace.from_dict(SPACE.to_dict(), name="arm.yaml"),
              "anon": SPACE}
    titles = {}
    for key, sp in spaces.items():
        with lt.Study(tmp_path / key, seed=0) as st:
            (s,) = st.ask(space=sp)
            st.tell(s.id, 1.0)
            titles[key] = st.report(simulate=False).splitlines()[0]
    assert titles == {"named": "space arm.yaml (trials run elsewhere)",
                      "anon": "space of a, b, c, d (trials run elsewhere)"}
    assert spaces["named"] == SPACE and spaces["named"].to_dict() == SPACE.to_dict()
    with pytest.raises(UsageError, match="name must be text on one line"):
        lt.ParameterSpace(["a"], [0.0], [1.0], name="two\nlines")


def test_an_ask_that_rebuilds_the_critic_does_not_copy_the_store(tmp_path, src30, monkeypatch):
    """Every ask that built its critic (its options the stored ones, no prepared batch) copied
    the whole run store first (``RunStore.snapshot``, to put it back on an error), though it
    records nothing. It now copies it only when the ask records something (here an options
    record a run lacks), and that ask's failure still leaves the store as it was."""
    copies = []
    snapshot = RunStore.snapshot
    monkeypatch.setattr(RunStore, "snapshot", lambda self: copies.append(1) or snapshot(self))
    monkeypatch.setattr(asktell, "prepare", lambda study: False)   # every batch asks the critic
    with lt.Study(tmp_path / "one", seed=0) as st:
        person(st, plant(), 10, system=plant(), budget=20)
        three = lt.Study(tmp_path / "three", seed=0)
        person(three, plant(0.3), 7, system=plant(0.3), phase=3, latent=src30)
        three.close()
        assert copies == [] and st.store.count(Phase.PHASE1) == 10
        cfg = st.config()
        for key in ("asktell", "phase1"):   # as a run stored before "regions" was recorded
            cfg[key].pop("regions")
        st.store.set_meta("config", cfg)
        _settle(st)                         # the queued suggestions: nothing is recorded
        assert copies == []
        before = whole_store(tmp_path / "one")
        with monkeypatch.context() as m:
            m.setattr(asktell, "_critic_batch", lambda *a: (_ for _ in ()).throw(
                RuntimeError("the GP fit failed")))
            with pytest.raises(RuntimeError, match="GP fit"):
                st.ask()
        assert len(copies) == 1 and whole_store(tmp_path / "one") == before
        st.ask()
        assert len(copies) == 2 and st.config()["phase1"]["regions"] is not None


def test_a_cost_that_is_not_a_number_is_refused_as_what_tell_got(tmp_path):
    """``tell(id, cost="abc")`` (or a list, an array, a bool) said "evaluate (its cost)
    returned str 'abc'" though no evaluate ran; it says what tell got now, the store untouched."""
    with lt.Study(tmp_path / "s") as st:
        st.ask(1, space=SPACE)
        for bad, what in (("abc", "got str 'abc'"), ("3.2", "got str '3.2'"),
                          ([1.0], "got list"), (np.array([1.0, 2.0]), "got an array of shape"),
                          (True, "got a bool"), (1e301, "got 1e\\+301")):
            with pytest.raises(UsageError, match=f"bad result for suggestion 1: {what}") as ei:
                st.tell(1, cost=bad)
            assert "evaluate" not in str(ei.value)
        assert st.store.count(Phase.PHASE1) == 0
        assert st.tell(1, cost=3.2).cost == 3.2


FALL_HINT = ("; to record a fall, mark the trial failed (tell --failed, or failed=True), or "
             "give a finite penalty")
"""What a non-finite cost's message says after the value."""


def test_a_non_finite_cost_says_how_to_record_a_fall(run_cli, tmp_path, error_line):
    """``tell --cost inf`` (and an evaluate returning inf) said only "got a non-finite cost
    (inf)", not how to record the fall it probably was; the line says to mark it failed, as the
    too-large cost's does, and a failed trial's inf is then taken."""
    d = tmp_path / "s"
    assert run_cli("ask", d, "--system", "examples.lqr_chain:make_system", "--n", "1")[0] == 0
    line = error_line(*run_cli("tell", d, "1", "--cost", "inf")[::2])
    assert line.endswith(f"bad result for suggestion 1: got a non-finite cost (inf){FALL_HINT}")
    assert run_cli("tell", d, "1", "--cost", "inf", "--failed")[0] == 0
    with pytest.raises(LatentuneError, match=re.escape(f"(inf){FALL_HINT} at θ a=")):
        evaluate(lt.FunctionSystem(SPACE, lambda x: float("inf")), np.zeros(4))


def test_tell_and_evaluate_word_each_bad_cost_in_their_own_terms(tmp_path):
    """tell rewrote system.as_outcome's "evaluate returned ..." into "got ..." with a regex, so
    a reworded message there would have made tell say "evaluate" though none ran; tell passes
    its own opening now. Each bad cost, as tell gives it and as an evaluate returning the same
    value does, word for word."""
    from latentune.system import EvaluationError, as_outcome

    cases = (  # (value, what tell says after "got", what evaluate's check says)
        ("abc", "got str 'abc'; expected a float cost",
         "evaluate returned str 'abc'; expected a cost (float), (cost, failed) or an Outcome"),
        ([1.0], "got list [1.0]; expected a float cost",
         "evaluate returned list [1.0]; expected a cost (float), (cost, failed) or an Outcome"),
        (np.array([1.0, 2.0]), "got an array of shape (2,); expected one float (e.g. float(y[0]) "
         "or y.sum())", "evaluate returned an array of shape (2,); expected one float (e.g. "
         "float(y[0]) or y.sum())"),
        (True, "got a bool (True); expected a float cost",
         "evaluate returned bool True; expected a cost (float), (cost, failed) or an Outcome"),
        (float("nan"), f"got a non-finite cost (nan){FALL_HINT}",
         f"evaluate returned a non-finite cost (nan){FALL_HINT}"),
        (float("inf"), f"got a non-finite cost (inf){FALL_HINT}",
         f"evaluate returned a non-finite cost (inf){FALL_HINT}"),
        ({"cost": 1.0, "fell": True}, "got dict {'cost': 1.0, 'fell': True}; expected a float "
         "cost", "evaluate returned a dict with the key(s) fell; an outcome has cost, failed, "
         "info, wall_s (details go in info)"),
        ((1.0, "no"), "got tuple (1.0, 'no'); expected a float cost",
         "evaluate returned failed = 'no'; expected True or False"),
        (lt.Outcome("abc"), "got str 'abc'; expected a float cost",
         "evaluate (its cost) returned str 'abc'; expected a float cost"),
        (lt.Outcome(1.0, "no"), "got failed = 'no'; expected True or False",
         "evaluate returned failed = 'no'; expected True or False"),
        (lt.Outcome(None, True, {"fall_step": 2.5}), "got fall_step 2.5; expected a whole number "
         "of steps >= 0", "evaluate reported fall_step 2.5; expected a whole number of steps >= 0"),
    )
    with lt.Study(tmp_path / "s") as st:
        st.ask(1, space=SPACE)
        for bad, told, returned in cases:
            with pytest.raises(UsageError) as ei:
                st.tell(1, cost=bad)
            assert str(ei.value) == f"bad result for suggestion 1: {told}"
            with pytest.raises(EvaluationError) as ei:
                as_outcome(bad)
            assert str(ei.value) == returned
        with pytest.raises(UsageError) as ei:
            st.tell(1, 1.0, failed="no")
        assert str(ei.value) == ("bad result for suggestion 1: got failed = 'no'; expected True "
                                 "or False")
        assert st.store.count(Phase.PHASE1) == 0


def test_tell_writes_the_summary_status_shows(tmp_path: Path, run_cli) -> None:
    """``phase1`` (4 trials), ``ask --budget 5`` and ``tell 1 --cost 1.5``: status showed 5
    trials, best 1.5, while summary.json still said 4 trials, best 28.02 (tell never wrote it);
    tell (and ``tell --amend``) now writes it after the result is stored."""
    d = tmp_path / "run"
    sys_ = ("--system", "examples.toy_plant:make_system")
    assert run_cli("phase1", *sys_, "--backend", "serial", "--quiet", "--out", d,
                   "--phase1-evals", "4")[0] == 0
    assert run_cli("ask", d, "--budget", "5", "--quiet")[0] == 0
    for flags, best in ((("--cost", "1.5"), 1.5), (("--cost", "2.5", "--amend"), None)):
        code, _, err = run_cli("tell", d, "1", *flags)
        assert code == 0, err
        summary = json.loads((d / "summary.json").read_text())
        with lt.Study(d) as st:
            row = st.best(1)
            assert (summary["phase1_evals"], summary["phase1_best"]) == (st.store.count(1), row.cost)
        assert summary["phase1_evals"] == 5 and (best is None or row.cost == best)
    assert summary["phase1_best"] != 1.5                  # the amended cost replaced it


def test_a_space_file_with_a_key_given_twice_is_refused(run_cli, tmp_path, error_line):
    """A space YAML edited by hand with ``manual:`` written twice started a study at the last
    one without a word (YAML's loader keeps the last key): it is one line naming the key and
    its lines, and no store is made; a merge key's fields overridden below it stay allowed."""
    from latentune import yamltext

    space = tmp_path / "space.yaml"
    space.write_text("names: [a, b]\nlow: [0, 0]\nhigh: [1, 1]\nmanual: [0.2, 0.2]\n"
                     "log: [false, false]\nmanual: [0.7, 0.7]\n")
    d = tmp_path / "run"
    line = error_line(*run_cli("ask", d, "--space", space)[::2])
    assert "the key manual is given twice (lines 4 and 6)" in line, line
    assert not (d / "run.db").exists()
    assert yamltext.load("base: &b {x: 1, y: 2}\nover:\n  <<: *b\n  y: 3\n") == {
        "base": {"x": 1, "y": 2}, "over": {"x": 1, "y": 3}}


def test_a_smaller_budget_says_budgets_only_grow(run_cli, tmp_path, error_line):
    """``ask --budget 5`` on a study asked with --budget 10 said only "runs with --budget 10
    (stored), not --budget 5", as if the budget were pinned like the method; it says a budget
    only grows, and a larger one is taken."""
    d = tmp_path / "s"
    assert run_cli("ask", d, "--system", "examples.lqr_chain:make_system", "--budget", "10")[0] \
        == 0
    line = error_line(*run_cli("ask", d, "--budget", "5")[::2])
    assert line.endswith("phase 1 runs with --budget 10 (stored), not --budget 5; a budget can "
                         "only grow: give 10 or more, or leave it out"), line
    with lt.Study(d) as st:
        with pytest.raises(StoreError, match=r"budget = 10 \(stored\), not 9; a budget can only "
                                             r"grow: give 10 or more"):
            st.ask(1, budget=9)
    assert run_cli("ask", d, "--budget", "12")[0] == 0


def test_a_transfer_option_on_a_stored_plain_phase_3_says_it_is_the_transfer_ones(
        run_cli, tmp_path, src30, error_line):
    """``ask DIR --record-walk 2`` on a plain phase 3 said "runs with no --record-walk (stored),
    not --record-walk 2", as if the option could have been given when it started; it says the
    option is the transfer phase 3's and this one is plain, as --handover on a stored transfer
    phase 3 does."""
    d = tmp_path / "p"
    with lt.Study(d, seed=0) as st:
        st.ask(2, system=plant(0.1), phase=3, latent=src30, strategy="plain", budget=6)
        with pytest.raises(StoreError, match=r"transfer_options are options of the transfer "
                                             r"phase 3, and this phase 3 runs with strategy "
                                             r"plain \(stored\)"):
            st.ask(1, transfer_options={"record_walk": 2})
    line = error_line(*run_cli("ask", d, "--record-walk", "2")[::2])
    assert line.endswith(f"{d}: --record-walk is an option of the transfer phase 3, and this "
                         "phase 3 runs with --strategy plain (stored): leave --record-walk out "
                         "to go on with it, or start a transfer phase 3 in another directory"), \
        line


def test_a_transfer_flag_at_its_default_is_the_option_left_out(run_cli, tmp_path, src30,
                                                                 error_line):
    """A later ``ask DIR --fall-budget 0`` (the help's "default 0: never stop") on a transfer
    phase 3 begun without it said "runs with no --fall-budget (stored), not --fall-budget 0.0",
    and so did ``--record-walk 0``, ``--escape-falls 0`` and ``--target-scores ranks``; and a
    ``phase3 --resume --fall-budget 0`` recorded the option, after which ``--target-scores
    ranks`` was refused. Found running the README's ask/tell commands with each flag repeated
    at its default. A flag given at its default is the option left out; another value is
    still refused."""
    d = tmp_path / "a"
    with lt.Study(d, seed=0) as st:
        person(st, plant(0.1), 2, system=plant(0.1), phase=3, latent=src30, budget=8)
        st.ask(1, transfer_options={"fall_budget": 0.0})     # the Python API alike
        st.release(3)
    for flags in (("--fall-budget", "0"), ("--record-walk", "0"), ("--escape-falls", "0"),
                  ("--target-scores", "ranks", "--fall-budget", "0")):
        code, out, err = run_cli("ask", d, *flags)
        assert code == 0, err
        assert run_cli("release", d, out.split()[0])[0] == 0
    line = error_line(*run_cli("ask", d, "--fall-budget", "0.2")[::2])
    assert line.endswith("phase 3 runs with no --fall-budget (stored), not --fall-budget 0.2"), \
        line
    r = tmp_path / "r"
    with lt.Study(r, seed=0) as st:
        st.phase3(plant(0.1), 3, latent=src30)
        st.phase3(plant(0.1), 3, latent=src30, transfer_options={"fall_budget": 0.0})
        st.phase3(plant(0.1), 3, latent=src30,
                  transfer_options={"fall_budget": 0.0, "target_scores": "ranks"})
        assert "transfer_options" not in st.config()["phase3"]    # the record as it began
        with pytest.raises(StoreError, match="fall_budget = 0.0, not 0.1"):
            st.phase3(plant(0.1), 3, latent=src30, transfer_options={"fall_budget": 0.1})


def test_a_phase_3_run_given_as_the_latent_space_names_its_source(run_cli, tmp_path, src30,
                                                                   error_line):
    """``ask NEW --phase 3 --vae T`` where T is itself a phase 3 (on the latent space of S)
    said "T holds no latent space: train one there first (latentune train-vae --out T)", which
    fails there (T has no phase-1 trial); it names S, whose latent space T searched."""
    t = tmp_path / "t"
    with lt.Study(t, seed=0) as st:
        st.ask(1, system=plant(0.1), phase=3, latent=src30, budget=4)
    space_file = tmp_path / "space.json"
    space_file.write_text(json.dumps(SPACE.to_dict()))
    with pytest.raises(LatentuneError, match=re.escape(
            f"latent: {t} holds no latent space of its own: it is a phase 3 on the latent "
            f"space of {src30.resolve()}; give that run instead (latent)")):
        lt.Study(tmp_path / "n").ask(1, system=plant(0.2), phase=3, latent=t)
    assert not (tmp_path / "n").exists()
    line = error_line(*run_cli("ask", tmp_path / "n", "--phase", "3", "--vae", t, "--space",
                               space_file)[::2])
    assert line.endswith(f"--vae: {t} holds no latent space of its own: it is a phase 3 on the "
                         f"latent space of {src30.resolve()}; give that run instead (--vae)"), line


def test_an_ask_start_that_names_no_file_lists_what_start_takes(run_cli, tmp_path, error_line):
    """``ask --start scrach`` (a typo of scratch) said "--start scrach: params file not found:
    scrach", as if only a file were meant; it now lists what --start takes, and no store is
    made."""
    sp = tmp_path / "S.yaml"
    sp.write_text(SPACE_YAML)
    d = tmp_path / "run"
    line = error_line(*run_cli("ask", d, "--space", sp, "--start", "scrach")[::2])
    assert line.endswith("--start scrach: no such file; give manual, scratch or a --params "
                         "file"), line
    assert not (d / "run.db").exists()
    (tmp_path / "today.json").write_text(json.dumps({"kp": 3.0, "kd": 0.5}))
    code, out, err = run_cli("ask", d, "--space", sp, "--start", tmp_path / "today.json")
    assert code == 0 and "kp=3, kd=0.5" in out, err
