"""``latentune phase3`` / ``tune`` and their phase-3 flags: refusals name the flags, a flag phase 3
cannot honour is refused before phase 1 runs, a resume keeps what it was run with, and the
warning of a streak of failed trials suggests only what the run does not do already."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

import latentune as lt
from latentune.errors import StoreError

SYSTEM = ("--system", "examples.toy_plant:make_real_system", "--backend", "serial",
          "--workers", "1", "--seed", "0")

API_NAMES = re.compile(r"transfer[_-]options|max_fall_prob|walk_pick|record_walk|fall_budget|"
                       r"escape_falls|batch_size|\(strategy |^\w+ (is|are|must) |"
                       r"^latent: |with [a-z][\w-]* = ")


@pytest.fixture(scope="module")
def source(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small source run of the toy chain with its latent space."""
    from examples.toy_plant import make_system

    d = tmp_path_factory.mktemp("p3src") / "src"
    study = lt.Study(d, seed=0)
    study.phase1(make_system(), 24)
    study.train_latent(4, epochs=20)
    return d


def _phase3(run_cli, source: Path, out: Path, *flags: str, evals: int = 4):
    return run_cli("phase3", *SYSTEM, "--vae", source, "--out", out,
                   "--phase3-evals", str(evals), *flags)


def test_phase3_refusals_name_the_flags_not_the_python_arguments(tmp_path, run_cli, source,
                                                                 error_line):
    """phase3's refusals named Study.phase3's arguments ('transfer_options are options of the
    transfer phase 3 (strategy transfer)' for --fall-budget, 'method is an option … (given
    method = 'cma')', 'phase3 was run with transfer-options = {…}, not {…}', 'latent: run
    directory … does not exist' for --vae), and a resume with --strategy plain of a transfer run
    with stored options blamed options the user never gave; they now name the flags."""
    d = tmp_path / "t"
    code, _, err = _phase3(run_cli, source, d, "--fall-budget", "0.3", "--escape-falls", "2")
    assert code == 0, err
    cases = [
        ((tmp_path / "n1", "--strategy", "plain", "--fall-budget", "0.2"),
         "--fall-budget is an option of the transfer phase 3 (--strategy transfer)"),
        ((tmp_path / "n2", "--handover", "--record-walk", "2", "--escape-falls", "3"),
         "--record-walk and --escape-falls are options of the transfer phase 3"),
        ((tmp_path / "n3", "--method", "cma"),
         "--method is an option of the plain phase 3 (--strategy plain), not of the transfer "
         "phase 3 (given --method = 'cma')"),
        ((tmp_path / "n4", "--regions", "2"), "--regions is an option of the plain phase 3"),
        ((d, "--resume", "--fall-budget", "0.2"),
         "phase 3 was run with --fall-budget 0.3 (stored), not --fall-budget 0.2"),
        ((d, "--resume", "--escape-falls", "4"),
         "phase 3 was run with --escape-falls 2 (stored), not --escape-falls 4"),
        ((d, "--resume", "--strategy", "plain"),
         "phase 3 runs with --strategy transfer (stored), not --strategy plain: leave "
         "--strategy out to go on with the transfer phase 3, or start a plain phase 3 in "
         "another directory"),
        ((d, "--resume", "--max-fall-prob", "0.2"),
         "phase 3 was run with no --max-fall-prob (stored), not --max-fall-prob 0.2"),
        ((d, "--resume", "--batch-size", "2"),
         "phase 3 was run with --batch-size 4 (stored), not --batch-size 2"),
        ((d, "--resume", "--handover"),
         "--handover is an option of the plain phase 3, and this phase 3 runs with --strategy "
         "transfer (stored), which moves to the full θ box on its own: leave --handover out to "
         "go on with it, or start a plain phase 3 in another directory"),
    ]
    for (out, *flags), expect in cases:
        line = error_line(*_phase3(run_cli, source, out, *flags, evals=6)[::2])
        line = line.removeprefix("latentune: error: ")
        assert expect in line and not API_NAMES.search(line), (flags, line)
    line = error_line(*run_cli("phase3", *SYSTEM, "--vae", tmp_path / "nowhere", "--out",
                               tmp_path / "n5", "--phase3-evals", "4")[::2])
    assert "--vae: run directory" in line and not API_NAMES.search(line), line


@pytest.mark.parametrize("flags, expect", [
    (("--strategy", "plain", "--fall-budget", "0.2"),
     "--fall-budget is an option of the transfer phase 3"),
    (("--handover", "--escape-falls", "2"), "--escape-falls is an option of the transfer phase 3"),
])
def test_tune_refuses_phase_3_flags_it_cannot_honour_before_phase_1(tmp_path, run_cli,
                                                                     error_line, flags, expect):
    """``tune --strategy plain --fall-budget 0.2`` ran phase 1 and trained the VAE before phase
    3 refused the transfer option; it is now refused before anything runs."""
    out = tmp_path / "t"
    line = error_line(*run_cli("tune", "--system", "examples.toy_plant:make_system",
                               "--backend", "serial", "--workers", "1", "--out", out,
                               "--phase1-evals", "6", "--phase3-evals", "4", *flags)[::2])
    assert expect in line
    assert not (out / "run.db").exists() or lt.Study(out).store.count(1) == 0


def test_tune_resume_keeps_the_stored_handover_as_phase3_resume_does(tmp_path, run_cli):
    """``tune --handover`` resumed without --handover was refused ('phase3 was run with
    handover = {…}, not None') while ``phase3 --resume`` keeps it: tune keeps it now too."""
    out = tmp_path / "t"
    common = ("tune", "--system", "examples.toy_plant:make_system", "--backend", "serial",
              "--workers", "1", "--out", out, "--phase1-evals", "12", "--vae-epochs", "5")
    code, _, err = run_cli(*common, "--phase3-evals", "4", "--handover", "patience=3")
    assert code == 0, err
    code, _, err = run_cli(*common, "--phase3-evals", "8", "--resume")
    assert code == 0, err
    study = lt.Study(out)
    assert study.store.count(3) == 8
    assert study.config()["phase3"]["handover"]["patience"] == 3


def _all_fall() -> lt.FunctionSystem:
    """A 24-gain system of the toy chain's box whose every trial fails."""
    from examples.toy_plant import chain_space

    return lt.FunctionSystem(chain_space(), lambda x: lt.Outcome(1.0, failed=True))


@pytest.mark.parametrize("kw, said, unsaid", [
    ({}, ["transfer_options={'escape_falls': 8}", "it screens at 0.3 unless told",
          "a lower max_fall_prob"], []),
    ({"transfer_options": {"escape_falls": 4}}, ["it screens at 0.3 unless told"],
     ["escape_falls"]),
    ({"max_fall_prob": 0.1}, ["it screens at 0.1)", "transfer_options={'escape_falls': 8}"],
     ["unless told"]),
    ({"strategy": "plain"}, ["the hand-over (handover)", "max_fall_prob=0.3"], []),
    ({"handover": {"patience": 3}, "max_fall_prob": 0.2}, ["it screens at 0.2)"],
     ["handover", "max_fall_prob=0.3"]),
])
def test_the_failing_warning_suggests_only_what_phase_3_does_not_do(tmp_path, source, caplog,
                                                                    kw, said, unsaid):
    """After 8 falls in a row phase 3 warned 'try … --escape-falls 8' to a run with
    escape_falls on, 'it screens at 0.3 unless told' to one told 0.1, and '--handover',
    '--max-fall-prob 0.3' to a plain run with both: the line now suggests what it does not do
    (once, at the 8th fall), in the words of the Python API that ran it (it named the command
    line's flags, which a Python caller cannot give)."""
    import logging

    with caplog.at_level(logging.WARNING, logger="latentune"):
        lt.Study(tmp_path / "t", seed=0).phase3(_all_fall(), 12, latent=source, **kw)
    warned = [r.getMessage() for r in caplog.records if "trials all failed" in r.getMessage()]
    assert len(warned) == 1 and warned[0].startswith("phase 3: the last 8 trials"), warned
    assert all(s in warned[0] for s in said) and not any(s in warned[0] for s in unsaid), \
        warned[0]
    assert "--" not in warned[0], warned[0]


def test_the_failing_warning_names_the_flags_at_the_command_line(tmp_path, source, run_cli,
                                                                 monkeypatch):
    """The same warning of a phase 3 run by ``latentune phase3`` names the flags."""
    (tmp_path / "allfall_plant.py").write_text(
        "import latentune as lt\nfrom examples.toy_plant import chain_space\n\n\n"
        "def make():\n"
        "    return lt.FunctionSystem(chain_space(), lambda x: lt.Outcome(1.0, failed=True))\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    code, _, err = run_cli("phase3", "--system", "allfall_plant:make", "--vae", source,
                           "--out", tmp_path / "t", "--phase3-evals", "9", "--seed", "0")
    (warned,) = [ln for ln in err.splitlines() if "trials all failed" in ln] or [(code, err)]
    assert "a lower --max-fall-prob (it screens at 0.3 unless told)" in warned, warned
    assert "--escape-falls 8 if the target falls" in warned and "transfer_options" not in warned


@pytest.mark.parametrize("opts", [{"walk_pick": "fall"}, {"walk_pick": "band", "record_walk": 0}])
def test_walk_pick_without_a_record_walk_is_refused_by_the_api(tmp_path, source, opts):
    """``Study.phase3(transfer_options={"walk_pick": "fall"})`` ran and ignored walk_pick (there
    is no walk to choose steps for; the CLI refuses --walk-pick without --record-walk): it is
    refused before anything is stored."""
    from examples.toy_plant import make_real_system

    study = lt.Study(tmp_path / "t", seed=0)
    with pytest.raises(ValueError, match="walk_pick chooses the steps of a record walk"):
        study.phase3(make_real_system(), 4, latent=source, transfer_options=opts)
    assert not study.exists or study.store.count(3) == 0
    assert lt.Study(tmp_path / "u", seed=0).phase3(
        make_real_system(), 4, latent=source,
        transfer_options={**opts, "record_walk": 2}).n == 4


def test_a_latent_space_copied_without_its_run_store_is_named_as_such(tmp_path, run_cli, source,
                                                                      error_line):
    """``--vae DIR`` with DIR the VAE files copied out of a run (vae.pt, vae.json, no run.db):
    phase3 and ask said "no run store in DIR (expected run.db)" and left the target directory
    with a copied latent space (ask's wording was the API's, ``latent: …``); now one line names
    what is missing, why the search needs it and what to do, before anything is written. The
    plain phase 3 without a fall prediction needs the latent space alone, and runs."""
    import shutil

    copy = tmp_path / "vaecopy"
    copy.mkdir()
    for f in ("vae.pt", "vae.json"):
        shutil.copy(source / f, copy / f)
    missing = f"--vae: {copy} holds a latent space but no run store (run.db): "
    for out, flags, why in [
            (tmp_path / "t", (), "the transfer phase 3 learns from the source run's trials; "
             "copy the run directory with its run.db, or search the latent space alone "
             "(--strategy plain)"),
            (tmp_path / "m", ("--strategy", "plain", "--max-fall-prob", "0.3"),
             "the fall prediction (--max-fall-prob) starts from the source run's trials")]:
        line = error_line(*_phase3(run_cli, copy, out, *flags)[::2])
        assert line.startswith(f"latentune: error: {missing}{why}"), line
        assert not out.exists()
        line = error_line(*run_cli("ask", out, *SYSTEM[:2], "--seed", "0", "--vae", copy,
                                   "--phase", "3", *flags)[::2])
        assert line.startswith(f"latentune: error: {missing}{why}"), line
    from examples.toy_plant import make_real_system
    from latentune.errors import LatentError

    with pytest.raises(LatentError, match=r"^latent: .* no run store \(run\.db\): the "
                       r"transfer phase 3 learns"):
        lt.Study(tmp_path / "api").phase3(make_real_system(), 4, latent=copy)
    assert not (tmp_path / "api").exists()
    code, _, err = _phase3(run_cli, copy, tmp_path / "p", "--strategy", "plain", evals=3)
    assert code == 0, err


def test_asking_another_strategy_of_a_stored_phase3_says_the_stored_one_and_what_to_do(
        tmp_path, source):
    """``Study.ask(strategy="plain")`` (or ``phase3``) on a phase 3 asked with the default
    transfer strategy said "phase3 was run with strategy = 'transfer', not 'plain'", a
    hand-over "phase 3 runs with handover = None (stored), not {…}" and ``method="cma"``
    "runs with method = 'turbo' (stored)", an option the transfer phase 3 has not; now one
    line each names the stored strategy and how to go on."""
    from examples.toy_plant import make_real_system
    from latentune.errors import StoreError, UsageError

    system = make_real_system()
    study = lt.Study(tmp_path / "t", seed=0)
    for s in study.ask(2, system=system, latent=source, phase=3):
        study.tell(s.id, cost=1.0 + s.id)
    go_on = (r"phase 3 runs with strategy transfer \(stored\), not plain: leave strategy out "
             r"to go on with the transfer phase 3, or start a plain phase 3 in another "
             r"directory$")
    with pytest.raises(StoreError, match=go_on):
        study.ask(1, system=system, strategy="plain")
    with pytest.raises(StoreError, match=go_on):
        study.phase3(system, 6, strategy="plain")
    with pytest.raises(StoreError, match=r": handover is an option of the plain phase 3, and "
                       r"this phase 3 runs with strategy='transfer' \(stored\), .*: leave "
                       r"handover out to go on with it"):
        study.ask(1, system=system, handover=True)
    with pytest.raises(UsageError, match=r"^method is an option of the plain phase 3"):
        study.ask(1, system=system, method="cma")
    assert len(study.ask(1, system=system, strategy="transfer")) == 1
    plain = lt.Study(tmp_path / "p", seed=0)
    for s in plain.ask(2, system=system, latent=source, phase=3, strategy="plain"):
        plain.tell(s.id, cost=2.0)
    with pytest.raises(StoreError, match=r"runs with strategy plain \(stored\), not transfer: "
                       r"leave strategy out"):
        plain.ask(1, system=system, strategy="transfer")


def test_target_scores_is_recorded_changes_the_search_and_is_refused_where_it_cannot_act(
        tmp_path, run_cli, source, error_line):
    """``--target-scores warped``: the transfer phase 3 stores it in its options and its
    asks differ from the ranks' run on the same source and seed; a resume with another value,
    an unknown value and the plain strategy are refused in one line naming the flag."""
    base, warped = tmp_path / "ranks", tmp_path / "warped"
    for out, flags in ((base, ()), (warped, ("--target-scores", "warped"))):
        code, _, err = _phase3(run_cli, source, out, *flags, evals=14)
        assert code == 0, err
    assert lt.Study(warped).config()["phase3"]["transfer_options"] == {"target_scores": "warped"}
    t_b, t_w = lt.Study(base).trials(3), lt.Study(warped).trials(3)
    assert len(t_b) == len(t_w) == 14
    assert [list(t.theta) for t in t_b] != [list(t.theta) for t in t_w]
    line = error_line(*_phase3(run_cli, source, warped, "--resume", "--target-scores",
                               "values", evals=16)[::2])
    assert "--target-scores warped (stored), not --target-scores values" in line, line
    assert "invalid choice" in error_line(*_phase3(run_cli, source, tmp_path / "x",
                                                   "--target-scores", "raw")[::2])
    line = error_line(*_phase3(run_cli, source, tmp_path / "p", "--strategy", "plain",
                               "--target-scores", "warped")[::2])
    assert "--target-scores is an option of the transfer phase 3" in line, line
    assert not API_NAMES.search(line.removeprefix("latentune: error: ")), line


def test_auto_target_scores_show_their_choice_in_status_and_report(tmp_path, run_cli, source):
    """``--target-scores auto``: stored in the options; every ask's decision records which
    model it chose and both leave-one-out ranking losses, and ``status`` and the report say
    so; ranks until six target trials stood."""
    out = tmp_path / "auto"
    code, _, err = _phase3(run_cli, source, out, "--target-scores", "auto", evals=12)
    assert code == 0, err
    assert lt.Study(out).config()["phase3"]["transfer_options"] == {"target_scores": "auto"}
    from latentune.pipeline.results import decision_scores, decisions
    from latentune.pipeline.store import RunStore

    with RunStore(out) as store:
        ds = decisions(store)
    chosen = [d["auto_scores"]["cost"] for d in ds if "auto_scores" in d]
    assert chosen and chosen[0] == ["ranks", None, None]
    assert any(c[1] is not None for c in chosen), chosen
    last = decision_scores(ds[-1])
    code, text, err = run_cli("status", out)
    assert code == 0, err
    assert f"scores: {last}" in text, text
    assert "loo ranking loss" in last or "too few standing" in last
    code, _, err = run_cli("report", out, "--no-sim")
    assert code == 0, err
    assert "loo ranking loss" in (out / "report.md").read_text()


def test_a_source_without_a_latent_space_says_to_train_one(tmp_path, run_cli, error_line):
    """``phase3 --vae P1`` (and ``ask --phase 3 --vae P1``) with P1 a run that has phase 1 but
    no latent space yet (train-vae skipped) said "no latent space at P1/vae (expected vae.pt
    and vae.json)", a path the user never gave; phase 3 with no --vae in a run without one
    said "... or pass another study's", the sentence cut off. Both now say what to do: train
    one (train_latent / train-vae), or name another study's (--vae); the command line names
    its command alone (``latentune train-vae --out P1``), not the API's train_latent."""
    p1 = tmp_path / "p1"
    assert run_cli("phase1", *SYSTEM, "--out", p1, "--phase1-evals", "6", "--quiet")[0] == 0
    for argv in [("phase3", *SYSTEM, "--vae", p1, "--out", tmp_path / "t", "--phase3-evals",
                  "4"),
                 ("ask", tmp_path / "a", *SYSTEM[:2], "--phase", "3", "--vae", p1)]:
        line = error_line(*run_cli(*argv)[::2])
        assert line == (f"latentune: error: --vae: {p1} holds no latent space: train one there "
                        f"first (latentune train-vae --out {p1} --system "
                        "examples.toy_plant:make_real_system)"), line
    assert not (tmp_path / "t").exists()
    line = error_line(*run_cli("phase3", *SYSTEM, "--out", p1, "--phase3-evals", "4")[::2])
    assert line == (f"latentune: error: no latent space in {p1}: train one first (latentune "
                    f"train-vae --out {p1} --system examples.toy_plant:make_real_system), or "
                    "name another study's (--vae)"), line
    from examples.toy_plant import make_real_system
    from latentune.errors import LatentError

    with pytest.raises(LatentError, match=r"^latent: .* holds no latent space: train one there "
                       r"first \(train_latent / train-vae\)$"):
        lt.Study(tmp_path / "api").phase3(make_real_system(), 4, latent=p1)
    with pytest.raises(LatentError, match=r"no latent space in .*: train one first "
                       r"\(train_latent / train-vae\), or name another study's \(latent\)$"):
        lt.Study(p1).phase3(make_real_system(), 4)


def _one_weight():
    """A system of one weight (the factory of :func:`test_phase_3_of_one_weight_…`)."""
    space = lt.ParameterSpace(names=["a"], low=[-1.0], high=[1.0], manual=[0.5])
    return lt.FunctionSystem(space, lambda x: float((x[0] - 0.2) ** 2))


def test_phase_3_of_one_weight_says_there_is_no_latent_space(tmp_path, run_cli, error_line):
    """``phase3`` / ``ask --phase 3`` on a system of one weight (whose phase 1 ran: tune and
    train-vae refuse it) said "no latent space at RUN/vae …" or "train one first", which
    train-vae refuses; they now say what tune says: a 1-dim θ has no smaller latent space."""
    import sys
    import types

    mod = types.ModuleType("one_weight_mod")
    mod.make = _one_weight
    sys.modules["one_weight_mod"] = mod
    try:
        sysargs = ("--system", "one_weight_mod:make", "--backend", "serial", "--seed", "0")
        p1 = tmp_path / "p1"
        assert run_cli("phase1", *sysargs, "--out", p1, "--phase1-evals", "5", "--quiet")[0] == 0
        for argv in [("phase3", *sysargs, "--vae", p1, "--out", tmp_path / "t",
                      "--phase3-evals", "3"),
                     ("phase3", *sysargs, "--out", p1, "--phase3-evals", "3", "--resume"),
                     ("ask", tmp_path / "a", *sysargs[:2], "--phase", "3", "--vae", p1)]:
            line = error_line(*run_cli(*argv)[::2])
            assert "a 1-dim θ has no smaller latent space" in line and "train" not in line, line
        assert not (tmp_path / "t").exists()
    finally:
        del sys.modules["one_weight_mod"]


def test_a_resume_with_another_vae_names_the_vae_flag(tmp_path, run_cli, source, error_line):
    """``phase3 --resume --vae OTHER`` said "phase 3 was run with latent-source = '/a', not
    '/b'" (and "latent-source = 'self'" for a phase 3 in the run's own latent space): a name
    no flag has. The line now names --vae."""
    import shutil

    other = tmp_path / "other"
    shutil.copytree(source, other)
    d = tmp_path / "t"
    code, _, err = _phase3(run_cli, source, d)
    assert code == 0, err
    line = error_line(*_phase3(run_cli, other, d, "--resume", evals=6)[::2])
    assert line.endswith(f"phase 3 was run with --vae {source} (stored), not --vae {other}"), line
    own = tmp_path / "own"
    code, _, err = run_cli("tune", *SYSTEM, "--out", own, "--phase1-evals", "16",
                           "--phase3-evals", "2", "--latent-dim", "2", "--vae-epochs", "20")
    assert code == 0, err
    line = error_line(*_phase3(run_cli, other, own, "--resume", evals=6)[::2])
    assert line.endswith("phase 3 was run in its own latent space (without --vae), not with "
                         f"--vae {other}"), line
    assert not API_NAMES.search(line), line


def test_latent_flags_that_differ_from_the_vae_runs_latent_space_are_refused(tmp_path, run_cli,
                                                                             source, error_line):
    """``phase3 --vae RUN --latent-dim 3`` (or ``--vae-kind vae``) ran in RUN's latent space of
    size 4 (det) and ignored the flag, and so did ``phase3 --resume --latent-dim 3`` of that run;
    both are now refused before anything is stored, as the same flags are against the run's own
    latent space."""
    for flags, expect in ((("--latent-dim", "3"), f"--latent-dim 3: the latent space of {source} "
                                                  "has size 4"),
                          (("--vae-kind", "vae"), f"--vae-kind vae: the latent space of {source} "
                                                  "is det")):
        out = tmp_path / flags[0].strip("-")
        line = error_line(*_phase3(run_cli, source, out, *flags)[::2])
        assert line.startswith(f"latentune: error: {expect} (--vae's, used as it is; leave the "
                               "flag out)"), line
        assert not (out / "run.db").exists()
    code, _, err = _phase3(run_cli, source, tmp_path / "same", "--latent-dim", "4")
    assert code == 0, err
    line = error_line(*run_cli("phase3", *SYSTEM, "--out", tmp_path / "same", "--phase3-evals",
                               "6", "--resume", "--latent-dim", "3")[::2])     # --vae kept
    assert line.endswith(f"--latent-dim 3: the latent space phase 3 of {tmp_path / 'same'} was "
                         "run in has size 4 (kept with --resume; leave the flag out)"), line


def test_tune_resumed_with_more_phase1_trials_does_not_keep_a_stale_latent_space(tmp_path,
                                                                                 run_cli,
                                                                                 error_line):
    """``tune --resume --phase1-evals N`` with N above the phase-1 trials the stored latent
    space was trained on ran the new phase-1 trials and kept that latent space as it was
    (trained on the first ones; phase 3 searched from those alone): the new trials were run
    for nothing, without a word. Before phase 3 began the latent space is now trained again on
    every phase-1 trial, as a tune never stopped would have; once phase 3 ran in it the larger
    --phase1-evals is refused before any trial, the store untouched."""
    from latentune.constants import Phase
    from latentune.pipeline.phases import training_set

    sys_ = ("--system", "examples.toy_plant:make_system", "--backend", "serial", "--workers", "1")
    a = tmp_path / "a"
    assert run_cli("phase1", *sys_, "--out", a, "--phase1-evals", "8")[0] == 0
    assert run_cli("train-vae", *sys_[:2], "--out", a, "--vae-epochs", "5")[0] == 0
    code, _, err = run_cli("tune", *sys_, "--out", a, "--phase1-evals", "12", "--phase3-evals",
                           "4", "--vae-epochs", "5", "--resume")
    assert code == 0, err
    with lt.Study(a) as st:
        assert st.store.count(Phase.PHASE1) == 12 and st.store.count(Phase.PHASE3) == 4
        assert st.config()["vae"]["n_train"] == len(training_set(st.store, Phase.PHASE1))
        assert st.latent().meta["n_phase1"] == 12
    before = lt.Study(a).store.count(Phase.PHASE1)
    line = error_line(*run_cli("tune", *sys_, "--out", a, "--phase1-evals", "16",
                               "--phase3-evals", "4", "--resume")[::2])
    assert "--phase1-evals 16" in line and "12" in line, line
    assert lt.Study(a).store.count(Phase.PHASE1) == before
    code, _, err = run_cli("tune", *sys_, "--out", a, "--phase1-evals", "12", "--phase3-evals",
                           "6", "--resume")
    assert code == 0, err


def test_a_resume_without_budget_flags_goes_on_to_the_stored_budgets(tmp_path, run_cli):
    """``phase1 --phase1-evals 6``, stopped, then ``phase1 --resume`` without the flag ran
    phase 1 on to the default 400 trials (394 more than the run was started for; ``tune`` and
    ``phase3`` alike with 400 and 220). A resume without the flag goes on to the budget the run
    was started with (as --seed and --trial-timeout do); a flag given still grows it."""
    from latentune.constants import Phase

    sys_ = ("--system", "examples.toy_plant:make_system", "--backend", "serial", "--workers", "1")
    a = tmp_path / "a"
    assert run_cli("phase1", *sys_, "--out", a, "--phase1-evals", "6")[0] == 0
    code, _, err = run_cli("phase1", *sys_, "--out", a, "--resume")
    assert code == 0, err
    assert lt.Study(a).store.count(Phase.PHASE1) == 6
    code, _, err = run_cli("phase1", *sys_, "--out", a, "--resume", "--phase1-evals", "8")
    assert code == 0, err
    assert lt.Study(a).store.count(Phase.PHASE1) == 8
    t = tmp_path / "t"
    code, _, err = run_cli("tune", *sys_, "--out", t, "--phase1-evals", "8", "--phase3-evals",
                           "3", "--vae-epochs", "5")
    assert code == 0, err
    code, _, err = run_cli("tune", *sys_, "--out", t, "--resume")
    assert code == 0, err
    with lt.Study(t) as st:
        assert (st.store.count(Phase.PHASE1), st.store.count(Phase.PHASE3)) == (8, 3)
    code, _, err = run_cli("phase3", *sys_, "--out", t, "--resume")
    assert code == 0, err
    assert lt.Study(t).store.count(Phase.PHASE3) == 3


def test_ask_phase_3_with_a_vae_in_a_phase_1_run_names_the_vae_given(tmp_path, run_cli, source,
                                                                     error_line):
    """``ask R --phase 3 --vae MINE`` where R's ask/tell runs phase 1 said to train a latent
    space in R and ask phase 3 "with --vae R", though the user had named the latent space
    MINE; ``ask R --vae MINE`` said "use another directory" alone. Both now say to ask phase 3
    in another directory with the --vae given."""
    r = tmp_path / "R"
    assert run_cli("ask", r, *SYSTEM[:2], "--budget", "6")[0] == 0
    for phase in (("--phase", "3"), ()):
        line = error_line(*run_cli("ask", r, *phase, "--vae", source)[::2])
        assert line.endswith(f"in another directory, with --vae {source}"), line
        assert f"--out {r}" not in line and f"--vae {r}" not in line, line


def test_ask_phase_1_with_a_vae_where_no_phase_is_stored_says_to_ask_phase_3(tmp_path, run_cli,
                                                                              source,
                                                                              error_line):
    """``ask NEW --phase 1 --vae MINE`` (a new directory, or a phase1 run's, where ask/tell
    has no phase yet) said "ask/tell runs phase 1 here; ... use another directory", though the
    same ask without --phase 1 asks phase 3 right there. It now says the two flags conflict
    and to ask --phase 3 (or leave --phase 1 out)."""
    new = tmp_path / "new"
    line = error_line(*run_cli("ask", new, *SYSTEM[:2], "--phase", "1", "--vae", source)[::2])
    assert line == (f"latentune: error: {new}: --phase 1 with --vae: a latent space is an "
                    "option of phase 3: ask --phase 3 (or leave --phase 1 out)"), line
    assert not new.exists()
    code, out, err = run_cli("ask", new, *SYSTEM[:2], "--phase", "3", "--vae", source)
    assert code == 0, err


def test_a_tune_stopped_in_phase_1_resumes_to_the_phase_3_it_was_started_with(
        tmp_path, run_cli, monkeypatch, error_line):
    """``tune … --phase3-evals 2 --latent-dim 2 --vae-epochs 20 --fall-budget 0.3`` stopped
    (Ctrl-C, SIGTERM) in phase 1 stored only what a ``phase1`` run does, so ``tune --resume``
    without those flags trained the default latent space and ran phase 3 for the default 220
    trials without the fall budget, and its report named both ``tune`` and ``phase1`` to go
    on. tune now records its plan before phase 1 runs: the resume runs the phase 3 it was
    started with, a flag given to a later resume replaces the planned value (as a larger
    --phase3-evals does), and the report names ``tune`` alone (a stopped ``phase1`` run:
    ``phase1`` alone)."""
    import shlex

    from latentune.study import Study

    phase1 = Study.phase1

    def stopped(self, *a, **kw):             # Ctrl-C after 3 new phase-1 trials
        phase1(self, *a, **{**kw, "max_new": 3})
        raise KeyboardInterrupt

    sys_ = ("--system", "examples.toy_plant:make_system", "--backend", "serial", "--quiet")
    d, p1 = tmp_path / "t", tmp_path / "p1"
    monkeypatch.setattr(Study, "phase1", stopped)
    code, _, err = run_cli("tune", *sys_, "--out", d, "--phase1-evals", "8", "--phase3-evals",
                           "2", "--latent-dim", "2", "--vae-epochs", "20", "--fall-budget", "0.3")
    assert code == 130, err
    assert run_cli("phase1", *sys_, "--out", p1, "--phase1-evals", "8")[0] == 130
    monkeypatch.setattr(Study, "phase1", phase1)
    for run, cmd in ((d, "tune"), (p1, "phase1")):
        code, _, err = run_cli("report", run, "--no-sim", "--quiet")
        assert code == 0, err
        then = " (it then trains the latent space and runs phase 3)" if cmd == "tune" else ""
        assert ("holds 3 trials of its budget of 8. If it stopped, the command that ran it goes "
                f"on: `latentune {cmd} … --out {shlex.quote(str(run))} --resume`{then}.") \
            in (run / "report.md").read_text()
    code, _, err = run_cli("tune", *sys_, "--out", d, "--resume")
    assert code == 0, err
    with Study(d) as st:
        cfg = st.config()
        assert st.store.count(1) == 8 and st.store.count(3) == 2
    assert (cfg["phase3"]["budget"], cfg["vae"]["d_low"], cfg["vae"]["epochs"]) == (2, 2, 20)
    assert cfg["phase3"]["transfer_options"] == {"fall_budget": 0.3}
    code, _, err = run_cli("tune", *sys_, "--out", d, "--resume", "--phase3-evals", "3")
    assert code == 0, err
    with Study(d) as st:
        assert st.store.count(3) == 3 and st.config()["tune"]["phase3_evals"] == 3
    line = error_line(*run_cli("tune", *sys_, "--out", d, "--resume", "--latent-dim", "3")[::2])
    assert "--latent-dim 3: the latent space of" in line, line


def test_phase_3_where_no_phase_1_ran_says_to_run_phase_1_first(tmp_path, run_cli, error_line):
    """``ask NEW --system X --phase 3`` (NEW a new directory, no --vae) said "no latent space
    in NEW: train one first (latentune train-vae --out NEW), or name another study's (--vae)",
    but train-vae there fails (no run store: run phase1 or tune first), as it would in a run
    without phase-1 trials. Where the run holds no phase-1 trial the advice is now to run phase
    1 there first (``ask --phase 1`` for ask, ``phase1`` for phase3), then train the latent
    space, or give --vae; the API names its methods."""
    from examples.toy_plant import make_real_system
    from latentune.errors import LatentError

    new = tmp_path / "NEW"
    line = error_line(*run_cli("ask", new, *SYSTEM[:2], "--phase", "3")[::2])
    assert line == (f"latentune: error: no latent space in {new} and no phase-1 trial to train "
                    f"one on: run phase 1 there first (latentune ask {new} --phase 1 … and tell "
                    f"its trials, then latentune train-vae --out {new}), or name another "
                    "study's (--vae)"), line
    assert not new.exists()
    assert run_cli("ask", new, *SYSTEM[:2], "--phase", "1", "--budget", "4")[0] == 0
    line = error_line(*run_cli("phase3", *SYSTEM, "--out", new, "--phase3-evals", "4")[::2])
    assert line.endswith(f"run phase 1 there first (latentune phase1 … --out {new}, then "
                         f"latentune train-vae --out {new}), or name another study's (--vae)")
    with pytest.raises(LatentError, match=r"no latent space in .* and no phase-1 trial to train "
                       r"one on: run phase 1 there first \(phase1, then train_latent\), or name "
                       r"another study's \(latent\)$"):
        lt.Study(tmp_path / "api").phase3(make_real_system(), 4)


def test_a_phase3_vae_run_goes_on_with_phase3_not_tune(tmp_path, run_cli, source, monkeypatch,
                                                       error_line, dump_store):
    """A ``phase3 --vae SRC`` run stopped short of its budget: its report said the command that
    ran it goes on with ``latentune tune … --resume`` or ``phase3 … --resume``, and ``tune
    --resume`` there ran a whole phase 1 (its default budget) on the target, trained a latent
    space of its own, and only then failed (the source moved) or was refused (phase 3 runs in
    another latent space). The report names ``phase3`` alone, and tune is refused before any
    trial, naming the command that goes on."""
    import shlex

    from latentune.study import Study

    phase3 = Study.phase3

    def stopped(self, *a, **kw):             # Ctrl-C after 2 phase-3 trials
        phase3(self, *a, **{**kw, "max_new": 2})
        raise KeyboardInterrupt

    d = tmp_path / "t"
    monkeypatch.setattr(Study, "phase3", stopped)
    assert _phase3(run_cli, source, d, "--quiet", evals=6)[0] == 130
    monkeypatch.setattr(Study, "phase3", phase3)
    code, _, err = run_cli("report", d, "--no-sim", "--quiet")
    assert code == 0, err
    where = shlex.quote(str(d))
    assert ("If it stopped, the command that ran it goes on: `latentune phase3 … --out "
            f"{where} --resume`.") in (d / "report.md").read_text()
    before = dump_store(d)
    line = error_line(*run_cli("tune", *SYSTEM, "--out", d, "--resume", "--phase1-evals", "8",
                               "--vae-epochs", "20")[::2])
    assert line == (f"latentune: error: {d}: its phase 3 runs in the latent space of "
                    f"{source.resolve()} "
                    "(phase3 --vae), and tune would run a phase 1 here first: go on with "
                    f"`latentune phase3 … --out {where} --resume`"), line
    assert dump_store(d) == before
    with Study(d) as st:
        assert st.store.count(1) == 0 and st.store.artifact("vae") is None


def test_resume_of_a_hand_over_run_with_strategy_transfer_names_the_stored_strategy(
        tmp_path, run_cli, source, error_line):
    """A plain phase 3 with --handover resumed (phase3 --resume, ask) with --strategy transfer
    and no --handover was told 'the hand-over is an option of the plain phase 3', a flag the
    command did not give; it names the stored strategy, as without a hand-over."""
    d = tmp_path / "h"
    code, _, err = _phase3(run_cli, source, d, "--handover", "patience=2")
    assert code == 0, err
    line = error_line(*_phase3(run_cli, source, d, "--resume", "--strategy", "transfer",
                               evals=6)[::2])
    assert "phase 3 runs with --strategy plain (stored), not --strategy transfer" in line, line
    line = error_line(*run_cli("ask", d, *SYSTEM[:2], "--strategy", "transfer")[::2])
    assert "phase 3 runs with --strategy plain (stored), not --strategy transfer" in line, line


def test_the_train_vae_hint_for_a_source_without_latent_space_runs(tmp_path, run_cli,
                                                                     error_line):
    """phase3 --vae on a phase-1-only run of a --system said 'train one there first
    (latentune train-vae --out SRC)', and that command stopped with 'SRC holds a run of the
    user system …: pass --system …'; the hint carries the source's --system and its
    --system-arg values, and runs."""
    import shlex

    src = tmp_path / "p1"
    code, _, err = run_cli("phase1", "--system", "examples.toy_plant:make_system",
                           "--system-arg", "steps=60", "--backend", "serial", "--workers", "1",
                           "--out", src, "--phase1-evals", "6", "--quiet")
    assert code == 0, err
    line = error_line(*_phase3(run_cli, src, tmp_path / "t")[::2])
    hint = re.search(r"\((latentune train-vae [^)]*)\)", line)
    assert hint and "--system examples.toy_plant:make_system --system-arg steps=60" in hint[1], line
    code, _, err = run_cli(*shlex.split(hint[1])[1:], "--vae-epochs", "5", "--latent-dim", "2")
    assert code == 0, err


def _fall_record(d: Path) -> dict:
    """The fall-aware entries of phase 3's options record (what the phase began with)."""
    pc = lt.Study(d).config()["phase3"]
    return {k: pc[k] for k in ("max_fall_prob", "fall_prior", "prior_counts",
                               "prior_fingerprint") if k in pc}


@pytest.mark.parametrize("how", ["ask", "phase3", "api"])
def test_max_fall_prob_at_the_transfer_default_is_the_option_left_out(tmp_path, run_cli, source,
                                                                     error_line, how):
    """``ask D --max-fall-prob 0.3`` (and ``phase3 --resume --max-fall-prob 0.3``, and
    ``Study.phase3(max_fall_prob=0.3)``) on a transfer phase 3 begun without it was refused:
    'runs with no --max-fall-prob (stored), not --max-fall-prob 0.3', although 0.3 is the
    transfer phase 3's screen unless told. Found by a colleague running the README's ask/tell
    commands. It is the option left out: accepted, and the record keeps what the phase began
    with (no fall prior added); another value is still refused in one line, which said 'runs
    with no --max-fall-prob' as if the phase screened nothing: it says it screens at 0.3."""
    d = tmp_path / "t"
    if how == "ask":
        code, _, err = run_cli("ask", d, *SYSTEM[:2], "--vae", source, "--n", "2",
                               "--budget", "8")
        assert code == 0, err
        before = _fall_record(d)
        code, _, err = run_cli("ask", d, "--max-fall-prob", "0.3")
        assert code == 0, err
        again = ("ask", d, "--max-fall-prob", "0.4")
    elif how == "phase3":
        assert _phase3(run_cli, source, d)[0] == 0
        before = _fall_record(d)
        code, _, err = _phase3(run_cli, source, d, "--resume", "--max-fall-prob", "0.3",
                               evals=6)
        assert code == 0, err
        assert lt.Study(d).store.count(3) == 6
        again = ("phase3", *SYSTEM, "--vae", source, "--out", d, "--phase3-evals", "8",
                 "--resume", "--max-fall-prob", "0.4")
    else:
        from examples.toy_plant import make_real_system

        with lt.Study(d, seed=0) as st:
            st.phase3(make_real_system(), 4, latent=source)
            before = _fall_record(d)
            st.phase3(make_real_system(), 6, max_fall_prob=0.3)
            assert st.store.count(3) == 6
            with pytest.raises(StoreError, match=r"max-fall-prob = None, not 0.4; without "
                               r"it the transfer phase 3 screens at 0.3: leave it out \(or give "
                               r"max_fall_prob=0.3\)"):
                st.phase3(make_real_system(), 8, max_fall_prob=0.4)
    assert before == {"max_fall_prob": None} == _fall_record(d)
    if how != "api":
        line = error_line(*run_cli(*again)[::2])
        assert line.endswith("no --max-fall-prob (stored), not --max-fall-prob 0.4; without "
                             "it the transfer phase 3 screens at 0.3: leave it out (or give "
                             "--max-fall-prob 0.3) to go on with it"), line


def test_max_fall_prob_left_out_of_a_transfer_phase_3_begun_at_its_default_keeps_it(
        tmp_path, source):
    """The converse in Python: a transfer phase 3 begun with ``max_fall_prob=0.3`` resumed
    without it (None: the transfer default, the same screen) goes on, its record as it began;
    where the default is off (the plain phase 3) giving 0.3 is still refused."""
    from examples.toy_plant import make_real_system

    d = tmp_path / "t"
    with lt.Study(d, seed=0) as st:
        st.phase3(make_real_system(), 4, latent=source, max_fall_prob=0.3)
        began = _fall_record(d)
        assert began["max_fall_prob"] == 0.3 and began["fall_prior"] == "latent source"
        st.phase3(make_real_system(), 6)
    assert _fall_record(d) == began and lt.Study(d).store.count(3) == 6
    p = tmp_path / "p"
    with lt.Study(p, seed=0) as st:
        st.phase3(make_real_system(), 4, latent=source, strategy="plain")
        with pytest.raises(StoreError, match="max-fall-prob = None, not 0.3"):
            st.phase3(make_real_system(), 6, max_fall_prob=0.3)


@pytest.mark.parametrize("flags", [("--fall-budget", "0"), ("--target-scores", "ranks"),
                                   ("--record-walk", "0", "--escape-falls", "0")])
def test_a_resume_given_transfer_flags_at_their_defaults_keeps_the_record(tmp_path, run_cli,
                                                                         source, error_line,
                                                                         flags):
    """``phase3 --resume --fall-budget 0`` (a default every stored run resumes with) on a
    transfer phase 3 begun without transfer options went on, but recorded
    ``transfer_options = {'fall_budget': 0.0}`` in the phase's record, which then said it was
    run with the option (a later --fall-budget 0.2: 'was run with --fall-budget 0.0 (stored)');
    Study.phase3 alike. Found giving each flag of phase3 --resume at its documented default
    and reading the record. The record keeps what the phase began with."""
    d = tmp_path / "t"
    assert _phase3(run_cli, source, d)[0] == 0
    before = lt.Study(d).config()["phase3"]
    assert "transfer_options" not in before
    code, _, err = _phase3(run_cli, source, d, "--resume", *flags, evals=5)
    assert code == 0, err
    after = lt.Study(d).config()["phase3"]
    assert after == {**before, "budget": 5}
    line = error_line(*_phase3(run_cli, source, d, "--resume", "--fall-budget", "0.2",
                               evals=6)[::2])
    assert line.endswith("phase 3's transfer critic was run with --fall-budget 0.0 (stored), "
                         "not --fall-budget 0.2"), line


@pytest.mark.parametrize("how", ["ask", "phase3"])
def test_walk_pick_at_its_default_without_a_walk_is_the_option_left_out(tmp_path, run_cli,
                                                                        source, error_line, how):
    """``ask D --walk-pick rank`` and ``phase3 --resume --walk-pick rank`` (the help's "rank,
    the default") on a transfer phase 3 without a record walk were refused: '--walk-pick
    chooses the steps of a walk: give --record-walk K > 0', while the transfer critic (and
    Study.phase3's ``walk_pick="rank"``) takes the default without a walk. Found giving each
    flag of ask and phase3 --resume at its documented default. It is the option left out;
    another pick without a walk is still refused in one line."""
    d = tmp_path / "t"
    if how == "ask":
        code, _, err = run_cli("ask", d, *SYSTEM[:2], "--vae", source, "--n", "2",
                               "--budget", "8")
        cmd: tuple = ("ask", d)
    else:
        code, _, err = _phase3(run_cli, source, d)
        cmd = ("phase3", *SYSTEM, "--vae", source, "--out", d, "--phase3-evals", "4",
               "--resume")
    assert code == 0, err
    before = lt.Study(d).config()["phase3"]
    for flags in (("--walk-pick", "rank"), ("--walk-pick", "rank", "--record-walk", "0")):
        code, _, err = run_cli(*cmd, *flags)
        assert code == 0, (flags, err)
    assert lt.Study(d).config()["phase3"] == before
    line = error_line(*run_cli(*cmd, "--walk-pick", "fall")[::2])
    assert line == "latentune: error: --walk-pick chooses the steps of a walk: give " \
                   "--record-walk K > 0", line


@pytest.mark.parametrize("cmd", ["phase3", "tune"])
def test_a_resume_given_walk_pick_goes_by_the_stored_record_walk(tmp_path, run_cli, source,
                                                                 error_line, cmd):
    """``phase3 --resume --walk-pick band`` (and ``tune --resume``) of a phase 3 run with
    --record-walk 2 was refused: '--walk-pick chooses the steps of a walk: give --record-walk K
    > 0', though the run has its walk (ask reads it from the store, as a resume keeps it); a
    user who then gave --record-walk 2 was refused another way. Found giving each flag of
    phase3 --resume on a run begun with transfer options. The stored walk counts: the default
    pick is accepted, another one refused as a change of the stored option."""
    d = tmp_path / "t"
    if cmd == "phase3":
        assert _phase3(run_cli, source, d, "--record-walk", "2")[0] == 0
        again: tuple = ("phase3", *SYSTEM, "--vae", source, "--out", d, "--phase3-evals", "4",
                        "--resume")
    else:
        again = ("tune", "--system", "examples.toy_plant:make_system", *SYSTEM[2:], "--out", d,
                 "--phase1-evals", "8", "--phase3-evals", "2", "--vae-epochs", "5")
        code, _, err = run_cli(*again, "--record-walk", "2")
        assert code == 0, err
        again = (*again, "--resume")
    before = lt.Study(d).config()["phase3"]
    assert before["transfer_options"] == {"record_walk": 2}
    code, _, err = run_cli(*again, "--walk-pick", "rank")
    assert code == 0, err
    assert lt.Study(d).config()["phase3"] == before
    line = error_line(*run_cli(*again, "--walk-pick", "band")[::2])
    assert line.endswith("was run with no --walk-pick (stored), not --walk-pick band"), line


def test_a_transfer_flag_on_a_resumed_plain_phase_3_says_it_runs_plain(tmp_path, run_cli,
                                                                        source, error_line):
    """``phase3 --resume --fall-budget 0.1`` of a plain phase 3 said '--fall-budget is an option
    of the transfer phase 3 (--strategy transfer), not of the plain one (the strategy given, or
    the stored one, or plain where a hand-over is given)', leaving the reader to work out which;
    ``ask`` says the stored phase 3 runs plain and what to do. The resume says it too. Found
    giving each transfer flag of phase3 --resume on a plain run."""
    d = tmp_path / "p"
    assert _phase3(run_cli, source, d, "--strategy", "plain")[0] == 0
    for flags in (("--fall-budget", "0.1"), ("--target-scores", "values")):
        line = error_line(*_phase3(run_cli, source, d, "--resume", *flags, evals=6)[::2])
        assert line == (f"latentune: error: {d}: {flags[0]} is an option of the transfer phase 3,"
                        f" and this phase 3 runs with --strategy plain (stored): leave "
                        f"{flags[0]} out to go on with it, or start a transfer phase 3 in "
                        "another directory"), line
    line = error_line(*_phase3(run_cli, source, tmp_path / "n", "--strategy", "plain",
                               "--fall-budget", "0.1")[::2])
    assert "--fall-budget is an option of the transfer phase 3 (--strategy transfer)" in line


def test_a_transfer_flag_on_a_resumed_plain_tune_says_it_runs_plain(tmp_path, run_cli,
                                                                     error_line):
    """``tune --resume --fall-budget 0.1`` of a tune whose phase 3 runs plain said the vague
    '… not of the plain one (the strategy given, or the stored one, or plain where a hand-over
    is given)', as phase3 --resume did; it says the stored phase 3 runs plain, before phase 1
    runs. Found giving each transfer flag of tune --resume on a plain run."""
    d = tmp_path / "t"
    run = ("tune", "--system", "examples.toy_plant:make_system", *SYSTEM[2:], "--out", d,
           "--phase3-evals", "2", "--vae-epochs", "5")
    code, _, err = run_cli(*run, "--phase1-evals", "8", "--strategy", "plain")
    assert code == 0, err
    line = error_line(*run_cli(*run, "--phase1-evals", "10", "--resume", "--fall-budget",
                               "0.1")[::2])
    assert line == (f"latentune: error: {d}: --fall-budget is an option of the transfer phase "
                    "3, and this phase 3 runs with --strategy plain (stored): leave "
                    "--fall-budget out to go on with it, or start a transfer phase 3 in "
                    "another directory"), line
    assert lt.Study(d).store.count(1) == 8


def test_a_tune_resume_given_transfer_defaults_keeps_its_plan(tmp_path, run_cli):
    """``tune --resume --fall-budget 0`` (and --record-walk 0, --target-scores ranks: defaults
    every stored run resumes with) of a tune begun without them stored them in its ``tune``
    plan (fall_budget: 0.0) although the run began without; the plan now records what the run
    began with, as the phase records do. Found reading the plan after such a resume."""
    d = tmp_path / "t"
    run = ("tune", "--system", "examples.toy_plant:make_system", *SYSTEM[2:], "--out", d,
           "--phase1-evals", "8", "--vae-epochs", "5")
    code, _, err = run_cli(*run, "--phase3-evals", "2")
    assert code == 0, err
    code, _, err = run_cli(*run, "--phase3-evals", "3", "--resume", "--fall-budget", "0",
                           "--record-walk", "0", "--target-scores", "ranks")
    assert code == 0, err
    with lt.Study(d) as st:
        plan = st.config()["tune"]
        assert st.store.count(3) == 3 and plan["phase3_evals"] == 3
        assert [plan.get(k) for k in ("fall_budget", "record_walk", "target_scores")] \
            == [None] * 3, plan
        assert "transfer_options" not in st.config()["phase3"]
