"""A phase 3's source run is known by the trials it began with: a source run directory that was
moved is followed to its new place (``--vae NEW``) when it holds that run, and refused when it
holds another; a source replaced in place by another run is refused, however many trials that
run holds. Runs recorded before the trials' fingerprint existed are known by their counts."""
from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import pytest

import latentune as lt

SYSTEM = ("--system", "examples.toy_plant:make_real_system", "--backend", "serial",
          "--workers", "1", "--seed", "0")


def _run(d: Path, seed: int, n: int) -> Path:
    """A source run of the toy chain at ``d``: ``n`` phase-1 trials of ``seed``, a latent
    space."""
    from examples.toy_plant import make_system

    with lt.Study(d, seed=seed) as study:
        study.phase1(make_system(), n)
        study.train_latent(4, epochs=20)
    return d


def _asked(d: Path) -> Path:
    """A source run of the toy chain at ``d`` whose 24 phase-1 trials were asked and told
    (ids 1 to 24: ``tell --amend`` can correct them), with a latent space."""
    from examples.toy_plant import make_system
    from latentune.system import evaluate

    system = make_system()
    with lt.Study(d, seed=0) as study:
        for _ in range(6):
            for s in study.ask(4, system=system, phase=1, budget=24):
                out = evaluate(system, s.theta)
                study.tell(s.id, out.cost, failed=out.failed)
        study.train_latent(4, epochs=20)
    return d


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The source run (24 trials), another run of the same system (30 trials, more) and a
    source run of 24 trials asked and told (its results can be amended)."""
    base = tmp_path_factory.mktemp("p3id")
    return {"source": _run(base / "source", 0, 24), "other": _run(base / "other", 1, 30),
            "asked": _asked(base / "asked")}


def _phase3(run_cli, vae: Path | None, out: Path, evals: int, *flags: str):
    return run_cli("phase3", *SYSTEM, *(("--vae", vae) if vae is not None else ()),
                   "--out", out, "--phase3-evals", str(evals), *flags)


def _started(run_cli, runs: dict[str, Path], tmp_path: Path) -> tuple[Path, Path]:
    """(the source run copied to tmp_path/src, a phase 3 of 4 trials from it at tmp_path/t)."""
    src, t = tmp_path / "src", tmp_path / "t"
    shutil.copytree(runs["source"], src)
    code, _, err = _phase3(run_cli, src, t, 4)
    assert code == 0, err
    return src, t


def test_a_moved_source_run_given_at_its_new_place_goes_on(tmp_path, run_cli, runs):
    """``mv runs/src runs/archive/src`` and ``phase3 --resume --vae runs/archive/src`` was
    refused ("phase 3 was run with --vae …/src (stored), not --vae …/archive/src"); the run
    there is the one phase 3 began with, so the phase goes on, the new place is recorded and
    logged once."""
    src, t = _started(run_cli, runs, tmp_path)
    new = tmp_path / "archive" / "src"
    new.parent.mkdir()
    shutil.move(src, new)
    code, _, err = _phase3(run_cli, new, t, 6, "--resume")
    assert code == 0, err
    moved = [ln for ln in err.splitlines() if "moved from" in ln]
    assert len(moved) == 1 and f"source run moved from {src.resolve()} to {new.resolve()}" \
        in moved[0], err
    cfg = lt.Study(t).config()
    assert cfg["phase3"]["latent_source"] == cfg["phase3_vae_source"] == str(new.resolve())
    assert lt.Study(t).store.count(3) == 6
    code, _, err = _phase3(run_cli, None, t, 7, "--resume")      # recorded: no --vae needed
    assert code == 0 and "moved from" not in err, err
    assert lt.Study(t).store.count(3) == 7


def test_a_moved_source_run_pointed_at_another_run_is_refused(tmp_path, run_cli, runs,
                                                              error_line):
    """The source run gone and ``--vae`` naming another run of the same system: one line says
    the run there is not the one phase 3 began with; nothing is recorded."""
    src, t = _started(run_cli, runs, tmp_path)
    shutil.rmtree(src)
    line = error_line(*_phase3(run_cli, runs["other"], t, 6, "--resume")[::2])
    assert line.startswith(f"latentune: error: --vae: {runs['other'].resolve()} is not the run "
                           "phase 3 began with"), line
    assert "holds other trials than" in line, line
    cfg = lt.Study(t).config()
    assert cfg["phase3"]["latent_source"] == str(src.resolve())
    assert lt.Study(t).store.count(3) == 4


def test_a_source_run_replaced_by_a_larger_one_is_refused(tmp_path, run_cli, runs, error_line):
    """The source directory replaced by another run with more trials than phase 3 began with
    went on silently with that run's trials (only a run with fewer was noticed); it is refused
    in one line, from the command line and from Python. The source run found elsewhere goes
    on from there."""
    from latentune.errors import LatentError
    from latentune.system import load_system

    src, t = _started(run_cli, runs, tmp_path)
    shutil.rmtree(src)
    shutil.copytree(runs["other"], src)
    line = error_line(*_phase3(run_cli, None, t, 6, "--resume")[::2])
    assert f"the source run at {src.resolve()} is not the run phase 3 began with" in line, line
    with lt.Study(t) as study:
        with pytest.raises(LatentError, match="is not the run phase 3 began with") as exc:
            study.phase3(load_system("examples.toy_plant:make_real_system"), 6)
        assert "\n" not in str(exc.value) and study.store.count(3) == 4
    orig = tmp_path / "orig"            # the source run, moved there before src was replaced
    shutil.copytree(runs["source"], orig)
    code, _, err = _phase3(run_cli, orig, t, 6, "--resume")
    assert code == 0 and f"moved from {src.resolve()} to {orig.resolve()}" in err, err
    assert lt.Study(t).store.count(3) == 6


def test_a_run_recorded_without_the_fingerprint_is_known_by_its_counts(tmp_path, run_cli, runs,
                                                                       error_line):
    """A phase 3 recorded before the source trials' fingerprint existed: its moved source is
    followed to its new place on the counts and the latent space phase 3 copied from it (the
    counts alone would take another run with as many trials), and its resume goes on."""
    src, t = _started(run_cli, runs, tmp_path)
    with lt.Study(t) as study, study.run.writing():
        pc = dict(study.config()["phase3"])
        pc.pop("source_fingerprint", None)
        study.manifest.update(phase3=pc)
    new = tmp_path / "moved"
    shutil.move(src, new)
    line = error_line(*_phase3(run_cli, runs["other"], t, 6, "--resume")[::2])
    assert "is not the run phase 3 began with" in line and "holds another latent space" in line
    code, _, err = _phase3(run_cli, new, t, 6, "--resume")
    assert code == 0, err
    cfg = lt.Study(t).config()
    assert cfg["phase3"]["latent_source"] == str(new.resolve())
    assert "source_fingerprint" not in cfg["phase3"]
    assert lt.Study(t).store.count(3) == 6


def test_an_ask_tell_phase_3_follows_its_moved_source_run(tmp_path, runs):
    """``Study.ask(latent=NEW)`` for an ask/tell phase 3 whose source run was moved to NEW was
    refused ("phase3 was run with latent-source = '…/src', not '…/moved'"); it goes on,
    with the new place recorded in the phase's and ask/tell's records."""
    from latentune.system import evaluate, load_system

    system = load_system("examples.toy_plant:make_real_system")
    src, new = tmp_path / "src", tmp_path / "moved"
    shutil.copytree(runs["source"], src)
    with lt.Study(tmp_path / "t", seed=0) as study:
        for s in study.ask(2, system=system, phase=3, latent=src, budget=6):
            out = evaluate(system, s.theta)
            study.tell(s.id, out.cost, failed=out.failed)
    shutil.move(src, new)
    with lt.Study(tmp_path / "t", seed=0) as study:
        (s,) = study.ask(latent=new)
        cfg = study.config()
        assert cfg["phase3"]["latent_source"] == cfg["asktell"]["latent_source"] \
            == cfg["phase3_vae_source"] == str(new.resolve())


def _amended_lines(err: str) -> list[str]:
    return [ln for ln in err.splitlines() if "amended since" in ln]


def test_an_amended_source_run_goes_on_with_one_warning(tmp_path, run_cli, runs):
    """``latentune tell SRC 7 --cost 9 --amend`` on the source run of a phase 3 under way made
    its resume fail: "the source run at SRC is not the run phase 3 began with: it holds other
    trials than the 24 phase-1 trials phase 3 began with (replaced since?)". The run is the
    same (the same θ, in the same order), one result of it was corrected: phase 3 goes on with
    one warning naming the amended trial and what phase 3 goes on with."""
    src, t = tmp_path / "src", tmp_path / "t"
    shutil.copytree(runs["asked"], src)
    code, _, err = _phase3(run_cli, src, t, 4)
    assert code == 0, err
    code, _, err = run_cli("tell", src, "7", "--cost", "9.0", "--amend")
    assert code == 0, err
    code, _, err = _phase3(run_cli, None, t, 6, "--resume")
    assert code == 0, err
    (line,) = _amended_lines(err)
    assert f"the source run at {src.resolve()}: trial 7 was amended since phase 3 began " \
           "(--amend: a cost or fall flag corrected); phase 3 goes on with the latent space it " \
           "copied when it began and the amended results" in line, line
    assert "is not the run" not in err
    assert lt.Study(t).store.count(3) == 6


def test_an_amended_source_run_pinned_the_old_way_goes_on(tmp_path, runs, caplog):
    """The pin is the sha256 of the pinned trials' θ, cost and fell flag as it always was (the
    value computed here by hand), so a store pinned before amendments were told apart resumes:
    a plain fall-aware phase 3 from Python whose source had trial 5 amended before it began
    (part of the pin) and trials 2 and 9 (twice) since goes on with one warning naming 2 and
    9; trial 12 amended to the value it had names nothing."""
    import hashlib
    import logging

    import numpy as np

    from latentune.pipeline.store import RunStore
    from latentune.system import load_system

    real = load_system("examples.toy_plant:make_real_system")
    src = tmp_path / "src"
    shutil.copytree(runs["asked"], src)
    with lt.Study(src) as s:
        s.tell(5, 3.5, amend=True)
        twelve = next(r.cost for r in s.store.rows(1) if r.info.get("trial") == 12)
    with lt.Study(tmp_path / "t", seed=0) as study:
        study.phase3(real, 4, latent=src, strategy="plain", max_fall_prob=0.5)
        pc = study.config()["phase3"]
    h = hashlib.sha256()
    with RunStore(src) as st:
        for ph in (1, 3):
            n = int(pc["source_counts"][str(ph)])
            h.update(f"phase {ph}: {n} trials\n".encode())
            for r in st.rows(ph)[:n]:
                h.update(np.asarray(r.theta, dtype="<f8").tobytes())
                h.update(np.array([r.cost], dtype="<f8").tobytes())
                h.update(b"\x01" if r.fell else b"\x00")
    assert pc["source_fingerprint"] == h.hexdigest()
    with lt.Study(src) as s:
        s.tell(9, 4.0, amend=True)
        s.tell(2, 1.25, amend=True)
        s.tell(9, 4.5, amend=True)
        s.tell(12, twelve + 1.0, amend=True)
        s.tell(12, twelve, amend=True)
    caplog.set_level(logging.WARNING)
    with lt.Study(tmp_path / "t", seed=0) as study:
        study.phase3(real, 6, strategy="plain", max_fall_prob=0.5)
        assert study.store.count(3) == 6
    (line,) = _amended_lines(caplog.text)
    assert "trials 2, 9 were amended since phase 3 began (amend=True" in line, line


@pytest.mark.parametrize("strategy", ["transfer", "plain"])
def test_a_phase_3_start_reads_its_source_trials_once(tmp_path, runs, source_reads, strategy):
    """The sha256 of the source's pinned trials (0.13 s on a 10,000-trial source) was computed
    two or three times per phase-3 start: for the options record even on a resume, where the
    pinned value stands, and in each check. A first start computes it once (to pin it), a
    resume once (to check it), in Python and in ask/tell."""
    from latentune.system import evaluate, load_system

    reads = source_reads
    real = load_system("examples.toy_plant:make_real_system")
    kw = {"strategy": strategy, "max_fall_prob": 0.5}
    with lt.Study(tmp_path / "t", seed=0) as study:
        study.phase3(real, 3, latent=runs["source"], **kw)
        assert reads == ["run_fingerprint"]
        reads.clear()
        study.phase3(real, 4, **kw)
        assert reads == ["amended_since"]
    reads.clear()
    with lt.Study(tmp_path / "a", seed=0) as study:
        (s,) = study.ask(system=real, phase=3, latent=runs["source"], budget=6, **kw)
        assert reads == ["run_fingerprint"]
        reads.clear()
        study.tell(s.id, evaluate(real, s.theta).cost)      # prepares the next batch: a check
        assert reads == ["amended_since"]


def test_a_plain_phase_3_follows_its_moved_source_run(tmp_path, run_cli, runs, error_line):
    """A plain phase 3 without a fall prediction pinned nothing of its source run, so after
    ``mv src moved`` its resume with ``--vae moved`` was refused ("phase3 was run with
    latent-source = '…/src', not '…/moved'"). It pins the source's trials as the transfer
    phase 3 does: the moved run is followed (one warning, the new place recorded), another run
    named in its place is refused in one line."""
    src, t = tmp_path / "src", tmp_path / "t"
    shutil.copytree(runs["source"], src)
    code, _, err = _phase3(run_cli, src, t, 4, "--strategy", "plain")
    assert code == 0, err
    new = tmp_path / "moved"
    shutil.move(src, new)
    line = error_line(*_phase3(run_cli, runs["other"], t, 6, "--resume", "--strategy",
                               "plain")[::2])
    assert "is not the run phase 3 began with" in line and "holds other trials" in line, line
    code, _, err = _phase3(run_cli, new, t, 6, "--resume", "--strategy", "plain")
    assert code == 0, err
    assert f"source run moved from {src.resolve()} to {new.resolve()}" in err, err
    cfg = lt.Study(t).config()
    assert cfg["phase3"]["latent_source"] == cfg["phase3_vae_source"] == str(new.resolve())
    assert lt.Study(t).store.count(3) == 6


def test_a_plain_phase_3_needs_its_source_run_only_where_it_reads_it(tmp_path, run_cli, runs,
                                                                    error_line):
    """A plain phase 3 without a fall prediction searches the latent space it copied: its
    resume goes on when the source directory was deleted or holds another run, as long as it
    is not named; named (``--vae SRC``, whose latent space would be searched), another run
    there is refused in one line."""
    src, t = tmp_path / "src", tmp_path / "t"
    shutil.copytree(runs["source"], src)
    assert _phase3(run_cli, src, t, 4, "--strategy", "plain")[0] == 0
    shutil.rmtree(src)
    code, _, err = _phase3(run_cli, None, t, 5, "--resume", "--strategy", "plain")
    assert code == 0, err
    shutil.copytree(runs["other"], src)
    code, _, err = _phase3(run_cli, None, t, 6, "--resume", "--strategy", "plain")
    assert code == 0, err
    line = error_line(*_phase3(run_cli, src, t, 7, "--resume", "--strategy", "plain")[::2])
    assert f"the source run at {src.resolve()} is not the run phase 3 began with" in line, line
    assert lt.Study(t).store.count(3) == 6


def _codes(d: Path) -> set[int]:
    """The lengths of the latent codes of the phase-3 trials stored at ``d``."""
    return {len(r.z) for r in lt.Study(d).store.rows(3) if r.z is not None}


def _retrained(src: Path) -> None:
    """The source run's latent space trained again on the same trials, of another size."""
    with lt.Study(src) as s:
        s.train_latent(3, epochs=20, retrain=True)


def _copied(t: Path) -> str:
    with lt.Study(t) as study:
        return study.latent().fingerprint()


@pytest.mark.parametrize("strategy", ["transfer", "plain"])
def test_a_retrained_source_latent_space_named_again_goes_on_with_the_copy(
        tmp_path, run_cli, runs, strategy):
    """``latentune phase2`` run again on the source (another latent dimension, the same trials)
    and ``phase3 --resume --vae SRC`` went on with the retrained 3-dim space instead of the
    4-dim copy phase 3 began with: its new trials carried codes of another space than the
    stored ones. Phase 3 goes on with its copy and one warning naming the cause."""
    src, t = tmp_path / "src", tmp_path / "t"
    shutil.copytree(runs["source"], src)
    flags = ("--strategy", strategy)
    code, _, err = _phase3(run_cli, src, t, 4, *flags)
    assert code == 0, err
    before = _copied(t)
    _retrained(src)
    code, _, err = _phase3(run_cli, src, t, 6, "--resume", *flags)
    assert code == 0, err
    lines = [ln for ln in err.splitlines() if "retrained since" in ln]
    assert len(lines) == 1 and f"{src.resolve()} holds another latent space than the one " \
        "phase 3 began with" in lines[0] and "goes on with its copy" in lines[0], err
    assert lt.Study(t).store.count(3) == 6 and _copied(t) == before
    if strategy == "plain":
        assert _codes(t) == {4}, _codes(t)


def test_a_retrained_source_is_reported_once_per_retraining(tmp_path, run_cli, runs):
    """Each call that named a retrained source again (``phase3 --resume --vae SRC``, each
    ``ask``) warned again that it holds another latent space than phase 3's copy: one
    retraining, a warning per call. It is reported once per retraining, recorded in the run's
    manifest (``phase3_retrained_reported``: the source latent space reported); a second
    retraining is reported again."""
    from latentune.pipeline.loop import RETRAINED_KEY

    src, t = _started(run_cli, runs, tmp_path)
    warned = []
    for evals in (5, 6):
        _retrained(src) if evals == 5 else None
        code, _, err = _phase3(run_cli, src, t, evals, "--resume")
        assert code == 0, err
        warned.append(sum("retrained since" in ln for ln in err.splitlines()))
    with lt.Study(src) as s:
        now = s.latent().fingerprint()
    assert warned == [1, 0] and lt.Study(t).manifest.config()[RETRAINED_KEY] == {
        "latent_fingerprint": now}
    with lt.Study(src) as s:
        s.train_latent(2, epochs=20, retrain=True)
    code, _, err = _phase3(run_cli, src, t, 7, "--resume")
    assert code == 0 and sum("retrained since" in ln for ln in err.splitlines()) == 1, err
    assert lt.Study(t).store.count(3) == 7


@pytest.mark.parametrize("strategy", ["transfer", "plain"])
def test_a_retrained_source_latent_space_given_to_python_and_ask_goes_on_with_the_copy(
        tmp_path, runs, caplog, strategy):
    """``Study.phase3(latent=SRC)`` and ``Study.ask(latent=SRC)`` on a resume after SRC's
    latent space was retrained go on with phase 3's copy, with one warning each."""
    import logging

    from latentune.system import evaluate, load_system

    real = load_system("examples.toy_plant:make_real_system")
    src = tmp_path / "src"
    shutil.copytree(runs["source"], src)
    with lt.Study(tmp_path / "t", seed=0) as study:
        study.phase3(real, 3, latent=src, strategy=strategy)
    with lt.Study(tmp_path / "a", seed=0) as study:
        for s in study.ask(2, system=real, phase=3, latent=src, budget=6, strategy=strategy):
            study.tell(s.id, evaluate(real, s.theta).cost)
    before = {k: _copied(tmp_path / k) for k in "ta"}
    _retrained(src)
    caplog.set_level(logging.WARNING)
    with lt.Study(tmp_path / "t", seed=0) as study:
        study.phase3(real, 5, latent=src, strategy=strategy)
        assert study.store.count(3) == 5
    with lt.Study(tmp_path / "a", seed=0) as study:
        for s in study.ask(4, latent=src):      # more than the batch the last tell prepared
            study.tell(s.id, evaluate(real, s.theta).cost)
    lines = [r.getMessage() for r in caplog.records if "retrained since" in r.getMessage()]
    assert len(lines) == 2, lines
    assert {k: _copied(tmp_path / k) for k in "ta"} == before
    if strategy == "plain":
        assert _codes(tmp_path / "t") == _codes(tmp_path / "a") == {4}


def test_a_first_phase_3_takes_the_retrained_latent_space(tmp_path, runs):
    """A phase 3 with no trial yet copies the source's latent space as it is now."""
    from latentune.system import load_system

    src = tmp_path / "src"
    shutil.copytree(runs["source"], src)
    _retrained(src)
    real = load_system("examples.toy_plant:make_real_system")
    with lt.Study(tmp_path / "t", seed=0) as study:
        study.phase3(real, 3, latent=src, strategy="plain")
        assert study.latent().d_low == 3


def _sample(study: Any, where: Path, n: int, **kw: Any) -> None:
    """``n`` more trials of the Optuna ``study``, sampled by a new LatentSampler of the source
    run at ``where`` (seed 0, budget 20, ``kw``), of the sum of squares of θ."""
    from latentune.integrations.optuna import LatentSampler

    def objective(trial: Any) -> float:
        return float(sum(v * v for v in trial.study.sampler.suggest_all(trial).values()))

    study.sampler = LatentSampler(where, seed=0, budget=20, **kw)
    study.optimize(objective, n_trials=n)


@pytest.mark.parametrize("strategy", ["transfer", "plain"])
def test_an_optuna_study_under_way_refuses_a_retrained_latent_space(tmp_path, runs, strategy):
    """A LatentSampler made for a study under way after its source's latent space was trained
    again searched the retrained space (its trials told as outside points, the transfer
    strategy's source trials pinned again as the run holds them now): the study switched
    latent spaces silently. The study pins the latent space of its first sample; a sampler with
    another is refused in one line (the study holds no copy of the old one to go on with); the
    same latent space from a moved source goes on."""
    optuna = pytest.importorskip("optuna")
    from latentune.errors import LatentError

    src = tmp_path / "src"
    shutil.copytree(runs["source"], src)
    optuna.logging.set_verbosity(optuna.logging.WARNING)

    def more(study, where, n):
        _sample(study, where, n, strategy=strategy)

    study = optuna.create_study()
    more(study, src, 3)
    moved = tmp_path / "moved"
    shutil.move(src, moved)
    more(study, moved, 1)                  # the same latent space at another place
    _retrained(moved)
    with pytest.raises(LatentError, match=r"^LatentSampler: .*moved holds another latent space "
                                          r"than the one the study began with \(retrained "
                                          r"since\?\)") as exc:
        more(study, moved, 1)
    assert "\n" not in str(exc.value)
    with pytest.raises(LatentError, match=r"the study began with the latent space of .*moved, "
                                          r"and .*other holds another"):
        more(study, runs["other"], 1)
    from latentune.integrations.optuna import LATENT_ATTR

    study._storage.set_study_system_attr(study._study_id, LATENT_ATTR, None)  # pinned before
    with pytest.raises(LatentError, match=r"moved holds another latent space than the one the "
                                          r"study began with \(retrained since\?\)"):
        more(study, moved, 1)           # known by its first sampled trial's key
    assert len([t for t in study.trials if t.state == optuna.trial.TrialState.COMPLETE]) == 4


def test_an_amendment_of_the_source_is_reported_once(tmp_path, run_cli, runs, caplog):
    """The warning that a pinned source trial was amended since phase 3 began was repeated at
    every start: every ask, and every tell that prepared the next batch, of an ask/tell phase
    3, and every resume. It is said once per amendment: a later amendment is reported alone."""
    import logging

    from latentune.system import evaluate, load_system

    real = load_system("examples.toy_plant:make_real_system")
    src = tmp_path / "src"
    shutil.copytree(runs["asked"], src)
    kw = {"strategy": "plain", "max_fall_prob": 0.5}
    with lt.Study(tmp_path / "a", seed=0) as study:
        for s in study.ask(2, system=real, phase=3, latent=src, budget=40, **kw):
            study.tell(s.id, evaluate(real, s.theta).cost)
    with lt.Study(src) as s:
        s.tell(7, 9.0, amend=True)
    caplog.set_level(logging.WARNING)

    def rounds(n: int) -> list[str]:
        caplog.clear()
        for _ in range(n):
            with lt.Study(tmp_path / "a", seed=0) as study:
                for s in study.ask(4):      # a batch each: a start of the critic
                    study.tell(s.id, evaluate(real, s.theta).cost)
        return [r.getMessage() for r in caplog.records if "amended since" in r.getMessage()]

    (line,) = rounds(3)
    assert "trial 7 was amended since phase 3 began" in line, line
    with lt.Study(src) as s:
        s.tell(9, 4.0, amend=True)
    (line,) = rounds(2)
    assert "trial 9 was amended since phase 3 began" in line and "7" not in line.split(
        "began")[0].split("trial")[-1], line
    t = tmp_path / "t"                  # a phase run, resumed from the command line
    code, _, err = _phase3(run_cli, src, t, 3)
    assert code == 0, err
    with lt.Study(src) as s:
        s.tell(3, 2.0, amend=True)
    code, _, err = _phase3(run_cli, None, t, 4, "--resume")
    assert code == 0 and len(_amended_lines(err)) == 1, err
    code, _, err = _phase3(run_cli, None, t, 5, "--resume")
    assert code == 0 and not _amended_lines(err), err


def test_an_optuna_study_reports_an_amendment_of_its_source_once(tmp_path, runs, caplog):
    """Each new LatentSampler of a study under way repeated the warning that a pinned source
    trial was amended; the study records the amendments reported and says each once."""
    import logging

    optuna = pytest.importorskip("optuna")

    src = tmp_path / "src"
    shutil.copytree(runs["asked"], src)
    optuna.logging.set_verbosity(optuna.logging.WARNING)

    def more(study) -> list[str]:
        caplog.clear()
        _sample(study, src, 1)
        return [r.getMessage() for r in caplog.records if "amended since" in r.getMessage()]

    study = optuna.create_study()
    more(study)
    more(study)
    with lt.Study(src) as s:
        s.tell(7, 9.0, amend=True)
    caplog.set_level(logging.WARNING)
    (line,) = more(study)
    assert "trial 7 was amended since the study began" in line, line
    assert more(study) == []
    with lt.Study(src) as s:
        s.tell(9, 4.0, amend=True)
    (line,) = more(study)
    assert "trial 9 was amended" in line, line


def test_a_phase_1_refuses_a_fall_prior_or_source_run_replaced_since(tmp_path, run_cli, runs,
                                                                     error_line):
    """Phase 1's fall prior (``--fall-prior``) and optuna-cmaes's ``source_run`` were pinned
    by their counts alone: a directory replaced by another run of as many trials or more went
    on, its first trials seeding the resumed critic in place of the ones phase 1 began with,
    without a word. Their trials are fingerprinted as phase 3's source is, and a resume on
    another run is refused in one line naming the option, at the command line and in
    Python."""
    from examples.toy_plant import make_real_system
    from latentune.errors import LatentError

    prior, t = tmp_path / "prior", tmp_path / "t"
    shutil.copytree(runs["source"], prior)
    flags = ("--phase1-evals", "4", "--max-fall-prob", "0.5", "--fall-prior", prior)
    code, _, err = run_cli("phase1", *SYSTEM, "--out", t, *flags)
    assert code == 0, err
    shutil.rmtree(prior)
    shutil.copytree(runs["other"], prior)           # 30 trials: more than the 24 pinned
    line = error_line(*run_cli("phase1", *SYSTEM, "--out", t, *flags, "--resume")[::2])
    assert line.startswith(f"latentune: error: --fall-prior: the run at {prior.resolve()} is "
                           "not the run phase 1 began with: it holds other trials than the 24 "
                           "phase-1 trials phase 1 began with"), line
    src = tmp_path / "src"
    shutil.copytree(runs["source"], src)
    with lt.Study(tmp_path / "c", seed=0) as study:
        study.phase1(make_real_system(), 4, method="optuna-cmaes", source_run=src)
    shutil.rmtree(src)
    shutil.copytree(runs["other"], src)
    with lt.Study(tmp_path / "c", seed=0) as study, \
            pytest.raises(LatentError, match=r"^source_run: the run at .*src is not the run "
                                             r"phase 1 began with") as exc:
        study.phase1(make_real_system(), 6, method="optuna-cmaes", source_run=src)
    assert "\n" not in str(exc.value)


def test_a_fall_prior_amended_since_goes_on_and_is_reported_once(tmp_path, runs, caplog):
    """A fall prior whose pinned trials were amended since (``tell --amend``) is the same run:
    ask/tell's phase 1 goes on with one warning naming the amended trial, and says it once,
    not at every ask."""
    import logging

    from examples.toy_plant import make_real_system
    from latentune.system import evaluate

    prior = tmp_path / "prior"
    shutil.copytree(runs["asked"], prior)
    real = make_real_system()
    kw = {"max_fall_prob": 0.5, "fall_prior": prior}
    with lt.Study(tmp_path / "a", seed=0) as study:
        for s in study.ask(2, system=real, phase=1, budget=40, **kw):
            study.tell(s.id, evaluate(real, s.theta).cost)
    with lt.Study(prior) as s:
        s.tell(5, 9.0, amend=True)
    caplog.set_level(logging.WARNING)
    said = []
    for _ in range(3):
        caplog.clear()
        with lt.Study(tmp_path / "a", seed=0) as study:
            for s in study.ask(4):
                study.tell(s.id, evaluate(real, s.theta).cost)
        said.append([r.getMessage() for r in caplog.records
                     if "amended since" in r.getMessage()])
    assert [len(x) for x in said] == [1, 0, 0], said
    assert "trial 5 was amended since phase 1 began" in said[0][0], said[0]


def test_a_phase_1_reads_its_fall_prior_once_per_start(tmp_path, runs, source_reads):
    """Phase 1 fingerprinted its fall prior's trials at every start (for an options record
    whose stored pin then stood) and read them again to check them on a resume: two reads of
    the prior where one does. A first start reads them once (to pin), a resume once (to
    check), in Python and in ask/tell."""
    from examples.toy_plant import make_real_system
    from latentune.system import evaluate

    real = make_real_system()
    kw = {"max_fall_prob": 0.5, "fall_prior": runs["source"]}
    with lt.Study(tmp_path / "p", seed=0) as study:
        study.phase1(real, 3, **kw)
        assert source_reads == ["run_fingerprint"]
        source_reads.clear()
        study.phase1(real, 4, **kw)
        assert source_reads == ["amended_since"]
        assert study.config()["phase1"]["prior_fingerprint"]
    source_reads.clear()
    with lt.Study(tmp_path / "a", seed=0) as study:
        for s in study.ask(1, system=real, phase=1, budget=20, **kw):
            study.tell(s.id, evaluate(real, s.theta).cost)
        assert source_reads == ["run_fingerprint"]
        source_reads.clear()
        study.ask(8)                    # past the queued batch: the critic is built again
        assert source_reads == ["amended_since"]
