"""``latentune phase3`` / ``tune`` and their phase-3 flags: refusals name the flags, a flag phase 3
cannot honour is refused before phase 1 runs, a resume keeps what it was run with, and the
warning of a streak of failed trials suggests only what the run does not do already."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

import latentune as lt

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
