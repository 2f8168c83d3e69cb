"""The command line's small edges: no abbreviated flags, defaults in ``--help``, a closed stdout,
progress bars only on a terminal, diagnostics through ``logging`` (``-v``, ``--quiet``), a full
disk as one line."""
from __future__ import annotations

import argparse
import errno
import fcntl
import logging
import os
import pty
import re
import resource
import struct
import subprocess
import sys
import termios
import textwrap
import warnings
from pathlib import Path

import pytest

import latentune.cli as cli_mod
from latentune.cli import build_parser, main
from latentune.pipeline.store import RunStore

from conftest import CLI_ENV, one_line_error

PLANT = textwrap.dedent('''
    import numpy as np
    import latentune as lt

    def make(dim=4):
        space = lt.ParameterSpace([f"w{i}" for i in range(dim)], [-1.0] * dim, [1.0] * dim,
                                  manual=[0.5] * dim)
        return lt.FunctionSystem(space, lambda x: float(np.sum((x - 0.2) ** 2)))
''')


@pytest.fixture
def plant(tmp_path, monkeypatch):
    d = tmp_path / "plant"
    d.mkdir()
    (d / "edgeplant.py").write_text(PLANT)
    monkeypatch.chdir(d)
    monkeypatch.syspath_prepend(str(d))
    yield d
    sys.modules.pop("edgeplant", None)


SYS = ["--system", "edgeplant:make", "--backend", "serial"]
VAE_SYS = SYS[:2]          # train-vae runs no rollout: --backend/--workers are refused


def _rows(run: Path) -> list[tuple]:
    with RunStore(run) as st:
        return [(r.phase, r.idx, r.cost) for ph in (0, 1, 3) for r in st.rows(ph)]


# ---------------------------------------------------------------------------- the parser
@pytest.mark.parametrize("argv", [     # flags before the abbreviation make a run fail at once
    ["tune", "--out", "x", "--workers", "0", "--phase1-eval", "10"],
    ["phase1", "--out", "x", "--phase1-evals", "0", "--work", "2"],
    ["phase3", "--out", "x", "--workers", "0", "--va", "y"], ["rollout", "--steps", "0", "--jso"],
    ["ask", "d", "--n", "0", "--jso"], ["report", "d", "--no-s"],
    ["paper", "--report-only", "--sca", "0.1"],
], ids=lambda a: " ".join(a))
def test_abbreviated_flags_are_refused(run_cli, tmp_path, argv, monkeypatch):
    monkeypatch.chdir(tmp_path)
    line = one_line_error(*run_cli(*argv)[::2])
    abbreviated = [a for a in argv if a.startswith("--")][-1]
    assert line.endswith("unrecognized arguments: " + " ".join(argv[argv.index(abbreviated):]))
    assert not Path("x").exists()


@pytest.mark.parametrize("value", ["-1.5e-3", "-1e299", "-2E+3", "-.5", "-3", "-inf"])
def test_a_negative_number_in_any_notation_is_a_value_not_a_flag(value):
    """argparse 3.11 took ``--cost -1.5e-3`` for a flag: "expected one argument"."""
    args = build_parser().parse_args(["tell", "d", "3", "--cost", value])
    assert args.cost == float(value)
    assert build_parser().parse_args(["rollout", "--v-des", value]).v_des == float(value)


def _help(capsys, *argv: str) -> str:
    with pytest.raises(SystemExit) as info:
        main([*argv, "--help"])
    assert info.value.code == 0
    return " ".join(capsys.readouterr().out.split())


def test_help_shows_the_defaults(capsys):
    text = _help(capsys, "tune")
    for needle in ("parallel rollouts (default 2)", "seed (terrain, critic, VAE); default: the run's stored one, else 0",
                   "(default process)", "critic (turbo = TuRBO-m, the default; a resume keeps the stored one)",
                   "phase-1 evaluations (default: the run's stored budget, else 400"):
        assert needle in text, needle
    assert "number of suggestions (default 1)" in _help(capsys, "ask")
    assert "rollout steps (default 2000)" in _help(capsys, "bench")
    assert "noise and pushes (default 0)" in _help(capsys, "rollout")
    # every option with a default says so, in every command
    todo, seen = [("latentune", build_parser())], 0
    while todo:
        name, p = todo.pop()
        fmt = p._get_formatter()
        for a in p._actions:
            if isinstance(a, argparse._SubParsersAction):
                todo += [(f"{name} {k}", v) for k, v in a.choices.items()]
            elif a.option_strings and a.default not in (None, False, [], argparse.SUPPRESS):
                assert "default" in fmt._get_help_string(a), (name, a.option_strings)
                seen += 1
    assert seen >= 20           # --workers, --phase1-evals, --phase3-evals of the run
    #                             commands: None (2, or 1 when serial; the stored budget)


def test_help_says_what_each_command_and_option_does(capsys):
    """latentune --help cut its description mid-list ("… | ask | tell |"), named phase 3
    "TuRBO-m in the latent space" (the paper's, no longer the default) and left status --json,
    paper --seed/--v-des and robot init's URDF without a word."""
    text = _help(capsys)
    assert "phase 3 on the target" in text and "|" not in text.split("positional")[0]
    assert "(transfer, the default) or TuRBO-m in its latent space (--strategy plain)" in text
    todo = [("latentune", build_parser())]
    while todo:
        name, p = todo.pop()
        for a in p._actions:
            if isinstance(a, argparse._SubParsersAction):
                todo += [(f"{name} {k}", v) for k, v in a.choices.items()]
            else:
                assert a.help, (name, a.option_strings or a.dest)


@pytest.mark.parametrize("cmd", sorted(cli_mod.UNUSED_FLAGS))
def test_help_does_not_offer_the_flags_a_command_refuses(capsys, cmd):
    """``phase1 --help`` listed --phase3-evals, --latent-dim, --vae-kind and --vae-epochs (and
    train-vae's --method, --workers, --backend, ...), which the command then refused."""
    text = _help(capsys, cmd)
    refused = ["--" + dest.replace("_", "-") for dest in cli_mod.UNUSED_FLAGS[cmd]]
    assert refused and not [f for f in refused if re.search(re.escape(f) + r"\b", text)], text
    assert "--out" in text and "--resume" in text


def test_verbose_and_quiet_exclude_each_other(run_cli):
    assert "not allowed with argument" in one_line_error(*run_cli("status", "d", "-v",
                                                                  "--quiet")[::2])


# ---------------------------------------------------------------------------- output streams
def test_a_closed_stdout_ends_without_a_traceback(tmp_path):
    space = tmp_path / "space.yaml"
    space.write_text("names: [a, b]\nlow: [0, 0]\nhigh: [1, 1]\n")
    assert main(["ask", str(tmp_path / "at"), "--space", str(space), "--quiet"]) == 0
    p = subprocess.Popen([sys.executable, "-m", "latentune.cli", "ask", str(tmp_path / "at"),
                          "--json"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         env=CLI_ENV, text=True)
    p.stdout.close()                            # the reader is gone before anything is written
    err = p.stderr.read()
    assert p.wait(timeout=120) == 141, err
    assert err == ""


def test_no_progress_bar_on_a_redirected_stderr(run_cli, plant, tmp_path):
    code, out, err = run_cli("phase1", *SYS, "--out", tmp_path / "r", "--phase1-evals", "6")
    assert code == 0
    assert err == ""                            # no bar, and no info lines by default
    assert out.startswith("phase 1: 6 evaluations (6 new), best cost")


def test_a_progress_bar_on_a_terminal(plant, tmp_path):
    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 100, 0, 0))   # 100 columns
    p = subprocess.Popen([sys.executable, "-m", "latentune.cli", "phase1", *SYS, "--out",
                          str(tmp_path / "r"), "--phase1-evals", "6"], stdout=subprocess.PIPE,
                         stderr=slave, env=CLI_ENV, cwd=plant, text=True)
    os.close(slave)
    chunks = []
    while True:
        try:
            b = os.read(master, 4096)
        except OSError:                          # EIO: the child closed the terminal
            break
        if not b:
            break
        chunks.append(b)
    os.close(master)
    assert p.wait(timeout=120) == 0
    assert "phase 1" in b"".join(chunks).decode(errors="replace")


# ---------------------------------------------------------------------------- logging
def _chatty(args):
    log = logging.getLogger("latentune.somewhere")
    log.info("an informational line")
    log.warning("a warning\nspread over lines")
    warnings.warn("a Python warning", UserWarning)
    log.error("an error line")
    print("the result")
    return 0


@pytest.mark.parametrize("flag, expect", [
    ([], ["latentune: warning: a warning spread over lines",
          "latentune: warning: a Python warning", "latentune: error: an error line"]),
    (["-v"], ["latentune: an informational line", "latentune: warning: a warning spread over "
              "lines", "latentune: warning: a Python warning", "latentune: error: an error line"]),
    (["--quiet"], ["latentune: error: an error line"]),
], ids=["default", "verbose", "quiet"])
def test_logging_levels(run_cli, monkeypatch, flag, expect):
    monkeypatch.setattr(cli_mod, "cmd_status", _chatty)
    logger = logging.getLogger("latentune")
    handlers, showwarning = list(logger.handlers), warnings.showwarning
    with warnings.catch_warnings():
        warnings.simplefilter("always")
        code, out, err = run_cli("status", "d", *flag)
    assert code == 0 and out == "the result\n"
    assert err.splitlines() == expect
    assert logger.handlers == handlers and warnings.showwarning is showwarning   # restored


# ---------------------------------------------------------------------------- a full disk
@pytest.fixture
def small_run(run_cli, plant, tmp_path):
    out = tmp_path / "run"
    code, _, err = run_cli("phase1", *SYS, "--out", out, "--phase1-evals", "6", "--quiet")
    assert code == 0, err
    return out


@pytest.mark.parametrize("name", ["phase1_best.json", "vae.json", "summary.json"])
def test_a_full_disk_is_one_line(run_cli, monkeypatch, small_run, name):
    """The disk fills up when the run writes ``name`` (a file of the run directory), or the
    temporary file it is written to first (``.NAME.XXXX.tmp``, opened by its descriptor)."""
    import builtins
    import io

    real_open = io.open

    def full_open(file, mode="r", *a, **k):
        path = os.readlink(f"/proc/self/fd/{file}") if isinstance(file, int) else str(file)
        if Path(path).name.lstrip(".").startswith(name) and any(c in mode for c in "wax"):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), path)
        return real_open(file, mode, *a, **k)

    before = _rows(small_run)
    monkeypatch.setattr(io, "open", full_open)
    monkeypatch.setattr(builtins, "open", full_open)
    line = one_line_error(*run_cli("tune", *SYS, "--out", small_run, "--resume", "--quiet",
                                   "--phase1-evals", "8", "--phase3-evals", "3",
                                   "--vae-epochs", "5")[::2])
    monkeypatch.undo()
    assert "No space left on device" in line and name in line, line
    after = _rows(small_run)
    assert after[:len(before)] == before                     # nothing stored was lost
    n1 = [r for r in after if r[0] == 1]
    assert [r[1] for r in n1] == list(range(len(n1))) and len(n1) == 8


def test_a_full_disk_during_resume_in_a_real_process(plant, small_run):
    """RLIMIT_FSIZE makes every file stop growing at a size (the store's WAL first)."""
    before = _rows(small_run)

    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (48_000, 48_000))

    p = subprocess.run([sys.executable, "-m", "latentune.cli", "phase1", *SYS, "--out",
                        str(small_run), "--resume", "--phase1-evals", "400"],
                       capture_output=True, text=True, env=CLI_ENV, cwd=plant, preexec_fn=limit,
                       timeout=300)
    line = one_line_error(p.returncode, p.stderr)
    assert re.search(r"disk I/O error|full|No space|too large", line), line
    after = _rows(small_run)
    assert after[:len(before)] == before and len(after) < 400


@pytest.mark.parametrize("cmd, flags, expect", [
    ("train-vae", ["--method", "cma"], "--method is not an option of train-vae"),
    ("train-vae", ["--regions", "2"], "--regions is not an option of train-vae"),
    ("train-vae", ["--max-fall-prob", "0.3"], "--max-fall-prob is not an option of train-vae"),
    ("train-vae", ["--phase3-evals", "5"], "--phase3-evals is not an option of train-vae"),
    ("train-vae", ["--batch-size", "3"], "--batch-size is not an option of train-vae"),
    ("train-vae", ["--workers", "3"], "--workers is not an option of train-vae"),
    ("train-vae", ["--backend", "serial"], "--backend is not an option of train-vae"),
    ("train-vae", ["--backend", "ray", "--ray-address", "auto"],
     "--backend is not an option of train-vae"),
    ("train-vae", ["--resume", "--latent-dim", "1"],
     "--latent-dim 1: the latent space of {run} has size 2 (kept with --resume"),
    ("train-vae", ["--resume", "--vae-kind", "vae"],
     "--vae-kind vae: the latent space of {run} is det (kept with --resume"),
    ("train-vae", ["--resume", "--vae-epochs", "7"],
     "--vae-epochs 7: the latent space of {run} was trained for 5 epochs (kept with --resume"),
    ("tune", ["--resume", "--phase1-evals", "6", "--phase3-evals", "2", "--latent-dim", "1"],
     "--latent-dim 1: the latent space of {run} has size 2 (kept with --resume"),
    ("tune", ["--resume", "--phase1-evals", "6", "--phase3-evals", "2", "--vae-kind", "vae"],
     "--vae-kind vae: the latent space of {run} is det (kept with --resume"),
    ("phase3", ["--phase1-evals", "9"], "--phase1-evals is not an option of phase3"),
    ("phase3", ["--vae-epochs", "5"], "--vae-epochs is not an option of phase3"),
    ("phase3", ["--vae-kind", "vae"], "--vae-kind vae: the latent space of {run} is det"),
    ("phase1", ["--phase3-evals", "5"], "--phase3-evals is not an option of phase1"),
    ("phase1", ["--latent-dim", "2"], "--latent-dim is not an option of phase1"),
    ("phase1", ["--vae-epochs", "5"], "--vae-epochs is not an option of phase1"),
    ("phase1", ["--vae-kind", "vae"], "--vae-kind is not an option of phase1"),
])
def test_flags_a_command_would_ignore_are_refused(run_cli, small_run, cmd, flags, expect):
    """train-vae ran without --method/--regions/..., phase3 without --phase1-evals/--vae-*,
    phase1 without --phase3-evals/--latent-dim/--vae-*; train-vae --resume and tune --resume
    kept a latent space of another size, kind or epochs: all without a word."""
    code, _, err = run_cli("train-vae", *VAE_SYS, "--out", small_run, "--latent-dim", "2",
                           "--vae-epochs", "5", "--quiet")
    assert code == 0, err
    before = _rows(small_run)
    line = one_line_error(*run_cli(cmd, *SYS, "--out", small_run, "--phase3-evals", "3",
                                   "--quiet", *flags)[::2]
                          if cmd == "phase3" else
                          run_cli(cmd, *(VAE_SYS if cmd == "train-vae" else SYS), "--out",
                                  small_run, "--quiet", *flags)[::2])
    assert expect.format(run=small_run) in line, line
    assert _rows(small_run) == before
    code, out, err = run_cli("train-vae", *VAE_SYS, "--out", small_run, "--latent-dim", "2",
                             "--resume", "--quiet")
    assert code == 0 and "already trained" in out, err


def test_phase3_resume_keeps_its_stored_fall_and_handover_options(run_cli, small_run):
    """A plain phase 3 run with --max-fall-prob and --handover: --resume without them was
    refused ("was run with max-fall-prob = 0.5, not None"); it now resumes with them."""
    assert run_cli("train-vae", *VAE_SYS, "--out", small_run, "--latent-dim", "2", "--vae-epochs",
                   "5", "--quiet")[0] == 0
    flags = ["--strategy", "plain", "--handover", "patience=2", "--max-fall-prob", "0.5"]
    code, _, err = run_cli("phase3", *SYS, "--out", small_run, "--phase3-evals", "4", "--quiet",
                           *flags)
    assert code == 0, err
    code, _, err = run_cli("phase3", *SYS, "--out", small_run, "--phase3-evals", "8", "--quiet",
                           "--resume")
    assert code == 0, err
    with RunStore(small_run) as st:
        assert st.count(3) == 8
    line = one_line_error(*run_cli("phase3", *SYS, "--out", small_run, "--phase3-evals", "9",
                                   "--quiet", "--resume", "--max-fall-prob", "0.4")[::2])
    assert "--max-fall-prob 0.5 (stored), not --max-fall-prob 0.4" in line


def test_a_run_with_a_seed_reopens_without_it(run_cli, plant, tmp_path, error_line):
    """``phase1 --seed 3 --out R`` then ``train-vae --out R`` (or ``phase1 --resume``, or
    ``phase3``) without --seed was refused with 'the study was run with seed = 3, not 0
    (leave the seed out to reopen it)', though it was left out: --seed defaults to the
    stored seed; another one is still refused."""
    out = tmp_path / "run"
    base = ("--out", out, "--quiet")
    assert run_cli("phase1", *SYS, *base, "--phase1-evals", "6", "--seed", "3")[0] == 0
    code, _, err = run_cli("phase1", *SYS, *base, "--phase1-evals", "7", "--resume")
    assert code == 0, err
    code, _, err = run_cli("train-vae", *VAE_SYS, *base, "--latent-dim", "1", "--vae-epochs", "5")
    assert code == 0, err
    assert "--seed 3 (stored), not --seed 0" in error_line(
        *run_cli("train-vae", *VAE_SYS, *base, "--seed", "0", "--latent-dim", "1")[::2])
    with RunStore(out) as st:
        assert st.count(1) == 7


def test_status_does_not_name_the_asker_of_an_ask_without_asker(tmp_path, run_cli):
    """status said "1 held by default" for a suggestion asked without --asker (the asker's
    stored name is "default"), which reads as held by a default setting; and "free again:
    default's lease expired". It now says "1 held" and "free again: its lease expired"; a
    named asker is still named. Each is named as a suggestion ("2 (1 held, 2 held)" read as
    counts)."""
    import time

    d = tmp_path / "s"
    assert run_cli("ask", d, "--system", "examples.lqr_chain:make_system")[0] == 0
    assert run_cli("ask", d, "--asker", "rig2")[0] == 0
    out = run_cli("status", d)[1]
    assert "pending suggestions: 2 (suggestion 1 held, suggestion 2 held by rig2)" in out, out
    assert run_cli("ask", d, "--lease", "0.2")[0] == 0        # 1 again, on a short lease
    time.sleep(0.3)
    out = run_cli("status", d)[1]
    assert ("pending suggestions: 2 (suggestion 1 free again: its lease expired, suggestion 2 "
            "held by rig2)") in out, out
    assert "default" not in out, out
