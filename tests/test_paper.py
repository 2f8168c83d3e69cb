"""``latentune paper`` end to end at a tiny scale, its report against the stored runs, resume,
``latentune report DIR`` on a paper directory, and bad input.

The end-to-end run (a tiny scale: 12 phase-1 and 4 phase-3 evaluations per study, 60-step
rollouts, one worker) runs in a subprocess, as a user runs it, and so does the ``--seeds`` run
that is killed; the runs that resume, ``report`` and bad input are checked in-process
(:func:`latentune.cli.main`).
"""
from __future__ import annotations

import json
import math
import os
import re
import shutil
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from latentune.experiments.paper import BASELINE_ROWS, budgets, plan
from latentune.pipeline.store import RunStore
from latentune.reporting.metrics import paper_results

TINY = ["--robot", "a1", "--scale", "1e-6", "--steps", "60", "--workers", "1", "--vae-epochs", "100"]


def test_budget_mapping():
    b = budgets(1.0)
    assert (b["phase1"], b["phase3"], b["baselines"]) == (10000, 220, 220)
    b = budgets(0.03)
    assert (b["phase1"], b["phase3"], b["preservation"]) == (300, 92, 150)
    b = budgets(1e-6)
    assert (b["phase1"], b["phase3"]) == (12, 8)
    assert budgets(0.5, phase3=40)["phase3"] == 40
    for bad in (0.0, -1.0, math.nan, math.inf):
        with pytest.raises(ValueError):
            budgets(bad)
    keys = [s.key for s in plan("a1", budgets(0.01))]
    assert {"a1-trot", "a1-jump-hills", "a1-trot-cross", "b1-jump-transfer",
            "a1-trot-preservation", "a1-jump-cma"} <= set(keys)
    assert not any(k.startswith("b1") for k in (s.key for s in plan("solo12", budgets(0.01))))


def test_plan_runs_the_claims_first():
    """The sources first, phase 3 on the claim rows over every seed before any baseline, the
    preservation run after every phase-3 row and before the baselines no claim rests on (the
    last tier); every study once."""
    st = plan("a1", budgets(0.01), seeds=3)
    keys = [s.key for s in st]
    assert len(keys) == len(set(keys))
    assert keys[:2] == ["a1-trot", "a1-jump"]
    i_pres = keys.index("a1-trot-preservation")
    extra = [i for i, s in enumerate(st) if s.kind == "baseline" and s.row not in BASELINE_ROWS]
    assert extra and i_pres == min(extra) - 1 and max(extra) == len(keys) - 1
    assert max(i for i, s in enumerate(st) if s.kind == "phase3") < i_pres
    first_baseline = next(i for i, s in enumerate(st) if s.kind == "baseline")
    claims = [i for i, s in enumerate(st) if s.kind == "phase3" and s.row in ("jump", "trot")]
    assert len(claims) == 3 * 2 * 2 - 2 and max(claims) < first_baseline   # seed 0's plain: tune
    assert keys.index("a1-jump-cross-default-s2") < keys.index("a1-jump-turbo")
    assert keys.index("b1-jump-transfer-tpe-s2") < keys.index("a1-jump-hills")


def _table_row(md: str, label: str) -> list[str]:
    for line in md.splitlines():
        if line.startswith(f"| {label} |"):
            return [c.strip() for c in line.strip("|").split("|")]
    raise AssertionError(f"no row {label!r} in the report")


def _num(cell: str) -> float:
    m = re.match(r"^(-?\d+\.\d+)", cell)
    assert m, cell
    return float(m.group(1))


REPO = Path(__file__).resolve().parents[1]


def test_paper_numbers_are_packaged():
    """The paper's numbers come from the package (latentune/data/paper_results.json), so these
    checks run in any clone; nothing reads a results file outside the repository."""
    from importlib import resources

    assert resources.files("latentune").joinpath("data", "paper_results.json").is_file()
    p = paper_results()
    assert "High-Dimensional Controller Tuning through Latent Representations" in \
        p["source"]["paper"]
    assert p["path_cost"]["A1"]["trot"]["manual"] == 8.96
    assert p["path_cost"]["Solo12"]["jump"]["phase3_cross_task"] == 10.17
    assert p["vae_stable_preservation"] == {"stable_in_original_space": 677,
                                            "stable_after_encode_decode": 658}
    for f in (REPO / "src" / "latentune").rglob("*.py"):
        text = f.read_text()
        assert "shared/paper" not in text and '/ "shared"' not in text, f


@pytest.mark.parametrize("robot, table, name", [("a1", "II", "A1"), ("solo12", "III", "Solo12")])
def test_committed_report_paper_column(robot: str, table: str, name: str):
    """The paper column of the committed Table II / III equals the packaged numbers."""
    md = (REPO / "results" / robot / "report.md").read_text()
    assert f"## Table {table}" in md
    vals = paper_results()["path_cost"][name]
    for label, key in (("Manual Tuned", "manual"), ("Phase 1", "phase1"),
                       ("Phase 3 even", "phase3_even"), ("Phase 3 uneven", "phase3_uneven"),
                       ("Phase 3 cross-task", "phase3_cross_task")):
        cells = _table_row(md, label)
        assert (float(cells[2]), float(cells[4])) == (vals["trot"][key], vals["jump"][key]), label


def test_report_of_a_paper_directory_refuses_system(tmp_path: Path, run_cli, error_line):
    """``report PAPER_DIR --system M:F`` ignored --system (a paper's studies are built-in
    robots); it is refused in one line."""
    (tmp_path / "paper.json").write_text("{}")
    line = error_line(*run_cli("report", tmp_path, "--no-sim", "--system", "x:y")[::2])
    assert "--system is for a run directory" in line and "paper directory" in line
    assert not (tmp_path / "report.md").exists()


def test_paper_commands_quote_a_directory_with_a_space(tmp_path: Path, run_cli):
    """A paper run in ``papers/my run`` recorded ``--out papers/my run`` in paper.json's
    command, and its report.md and paper_summary.json named ``latentune paper --robot a1
    --out papers/my run --report-only`` and ``latentune report papers/my run``: pasted into a
    shell, those named another directory. The directory is quoted for a shell."""
    import shlex

    from latentune.experiments.paper import PaperOptions, command_line

    out = tmp_path / "my run é"
    q = shlex.quote(str(out))
    assert f" --out {q} " in command_line(PaperOptions(out=str(out)))
    out.mkdir()
    b = budgets(1e-6)
    (out / "paper.json").write_text(json.dumps({
        "format": "latentune-paper", "robot": "a1", "actor": "convex", "steps": 60, "seed": 0,
        "v_des": 0.5, "workers": 1, "budgets": b, "command": "latentune paper", "seeds": 1,
        "vae_epochs": 100, "studies": {}, "invocations": [], "wall_s_total": 1.0}))
    code, _, err = run_cli("report", out, "--no-sim")
    assert code == 0, err
    md = (out / "report.md").read_text()
    assert (f"`latentune paper --robot a1 --out {q} --report-only` (or `latentune report "
            f"{q}`)") in md, md[:2000]
    summary = json.loads((out / "paper_summary.json").read_text())
    assert summary["report_command"] == f"latentune paper --robot a1 --out {q} --report-only"


@pytest.mark.parametrize("argv", [["report", "{d}", "--no-sim"],
                                  ["paper", "--out", "{d}", "--report-only", "--no-sim"]])
def test_report_of_a_read_only_paper_directory_is_one_line(tmp_path: Path, run_cli, error_line,
                                                           argv: list[str]):
    """``report PAPER_DIR`` (and ``paper --report-only``) on a paper directory on read-only
    media ended in a traceback (PermissionError writing the first figure): it says in one
    line that the directory cannot be written and what to do, before writing anything."""
    d = tmp_path / "ro"
    d.mkdir()
    (d / "paper.json").write_text(json.dumps({
        "format": "latentune-paper", "robot": "a1", "actor": "convex", "steps": 60, "seed": 0,
        "v_des": 0.5, "workers": 1, "budgets": budgets(1e-6), "command": "latentune paper",
        "seeds": 1, "vae_epochs": 100, "studies": {}, "invocations": [], "wall_s_total": 1.0}))
    if os.geteuid() != 0:
        d.chmod(0o555)
    elif subprocess.run(["chattr", "+i", str(d)], capture_output=True).returncode != 0:
        pytest.skip("cannot make a directory read-only here (chattr)")
    try:
        line = error_line(*run_cli(*[a.format(d=d) for a in argv])[::2])
    finally:
        if os.geteuid() != 0:
            d.chmod(0o755)
        else:
            subprocess.run(["chattr", "-i", str(d)], check=True)
    assert line == (f"latentune: error: {d} cannot be written (read-only): copy the paper "
                    "directory to a writable directory and report the copy"), line
    assert sorted(p.name for p in d.iterdir()) == ["paper.json"]


@pytest.mark.parametrize("simulate, gifs", [(False, True), (True, False)])
def test_a_report_without_gifs_removes_an_earlier_reports(tmp_path: Path, simulate: bool,
                                                          gifs: bool):
    """``report PAPER_DIR --no-sim`` (or ``paper --report-only --no-sim/--no-gif``) after a
    report with the re-simulated figures left the earlier GIFs and CoM figures beside the new
    report.md, which no longer refers to them; they are removed (other files are kept)."""
    from latentune.reporting.paper_report import make_figures

    stale = ["a1_trot_phase3_best.gif", "a1_trot_hills_phase3_best.gif",
             "b1_jump_transfer_best.gif", "com_velocity_trot.png", "best_so_far_jump.png"]
    for f in [*stale, "mine.gif", "notes.png"]:
        (tmp_path / f).write_bytes(b"old")
    nums = {"root": tmp_path, "robot": "a1", "R": "A1", "studies": {}, "transfer": {},
            "seeded": {}, "budgets": {"phase1": 1, "phase3": 1},
            "table": {g: {"manual": {"ours": 1.0}} for g in ("trot", "jump")}}
    fig = make_figures(nums, simulate=simulate, gifs=gifs)
    assert fig["figs"] == [] and fig["gifs"] == []
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mine.gif", "notes.png"]


@pytest.fixture(scope="module")
def paper_dir(tmp_path_factory, cli) -> Path:
    out = tmp_path_factory.mktemp("paper") / "a1"
    r = cli("paper", *TINY, "--phase3-evals", "4", "--out", out, "--quiet", timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    return out


def test_paper_end_to_end(paper_dir: Path):
    out = paper_dir
    md = (out / "report.md").read_text()
    summary = json.loads((out / "paper_summary.json").read_text())
    meta = json.loads((out / "paper.json").read_text())
    assert meta["budgets"]["phase1"] == 12 and meta["budgets"]["phase3"] == 4
    assert meta["budgets"]["overridden"]["phase3"] is True
    assert meta["vae_epochs"] == 100 and "--vae-epochs 100" in meta["command"]
    for heading in ("## Table II", "A1 → B1 transfer", "stable-region preservation",
                    "Baselines at the phase-3 budget", "Does the paper's shape hold",
                    "--report-only", "Wall time", "Scale S = 1e-06"):
        assert heading in md, heading
    # every study ran with its budget
    for key, info in meta["studies"].items():
        with RunStore(out / key) as st:
            kind = info["kind"]
            if kind == "tune":
                assert (st.count(1), st.count(3)) == (12, 4), key
                assert st.artifact("vae") is not None
                assert json.loads((out / key / "vae.json").read_text())["epochs"] == 100, key
            elif kind == "phase3":
                assert (st.count(1), st.count(3)) == (0, 4), key
            elif kind == "baseline":
                assert (st.count(1), st.count(3)) == (4, 0), key
            else:
                assert (st.count(1), st.count(3)) == (12, 0), key
            # the transfer phase 3 on another study's source runs no separate manual trial
            assert st.count(0) == (0 if info["strategy"] == "transfer" else 1), key
    # Table II cells equal the stores' bests (manual, phase 1, phase 3 even/uneven/cross-task)
    paper_vals = paper_results()["path_cost"]["A1"]
    rows = {"Manual Tuned": ("{g}", 0), "Phase 1": ("{g}", 1), "Phase 3 even": ("{g}", 3),
            "Phase 3 uneven": ("{g}-hills", 3), "Phase 3 cross-task": ("{g}-cross", 3)}
    pkey = {"Manual Tuned": "manual", "Phase 1": "phase1", "Phase 3 even": "phase3_even",
            "Phase 3 uneven": "phase3_uneven", "Phase 3 cross-task": "phase3_cross_task"}
    for label, (pattern, phase) in rows.items():
        cells = _table_row(md, label)
        for j, g in enumerate(("trot", "jump")):
            with RunStore(out / f"a1-{pattern.format(g=g)}") as st:
                best = float(np.min(st.costs(phase)))
            assert _num(cells[1 + 2 * j]) == pytest.approx(round(best, 3), abs=1e-9), (label, g)
            assert summary["table"][g][pkey[label]]["ours"] == pytest.approx(best, rel=1e-12)
            assert float(cells[2 + 2 * j]) == paper_vals[g][pkey[label]]
    # transfer
    for g in ("trot", "jump"):
        with RunStore(out / f"b1-{g}-transfer") as st:
            best = float(np.min(st.costs(3)))
            cfg = st.get_meta("config")
        assert cfg["task"]["robot"] == "b1"
        assert cfg["phase3_vae_source"] == str((out / "a1-trot").resolve())
        cells = _table_row(md, f"B1 {g}")
        assert _num(cells[2]) == pytest.approx(round(best, 3), abs=1e-9)
        assert summary["transfer"][g]["ours"] == pytest.approx(best, rel=1e-12)
    # preservation: phase-5 rows = one per stable θ of the separate run
    with RunStore(out / "a1-trot-preservation") as st:
        stable = int(np.sum(st.costs(1) < 100))
        kept = int(np.sum(st.costs(5) < 100))
        assert st.count(5) == stable
        assert st.get_meta("config")["task"]["seed"] == 1
    p = summary["preservation"]
    assert (p["n_stable"], p["n_kept"]) == (stable, kept)
    assert f"| latentune | {stable} | {kept} |" in md
    # baselines
    for g in ("trot", "jump"):
        for m in ("turbo", "cma", "random"):
            with RunStore(out / f"a1-{g}-{m}") as st:
                best = float(np.min(st.costs(1)))
                assert (st.get_meta("config")["phase1"]["method"]) == m
            assert summary["baselines"][g]["rows"][m]["best"] == pytest.approx(best, rel=1e-12)
    # figures and GIFs
    for f in ("best_so_far_trot.png", "best_so_far_jump.png", "com_velocity_trot.png",
              "com_velocity_jump.png", "a1_trot_phase3_best.gif", "b1_trot_transfer_best.gif"):
        assert (out / f).is_file() and (out / f).stat().st_size > 1000, f
        assert f"]({f})" in md


@pytest.mark.parametrize("extra, expect", [
    (["--robot", "atlas"], "unknown robot 'atlas'"),
    (["--scale", "0"], "--scale"),
    (["--scale", "-1"], "--scale"),
    (["--scale", "nan"], "--scale"),
    (["--scale", "inf"], "--scale"),
    (["--scale", "1e307"], "--scale must be a finite number > 0 (a finite budget)"),
    (["--scale", "abc"], "--scale"),
    (["--workers", "0"], "--workers must be >= 1, got 0"),
    (["--workers", "5000"],
     "--workers must be at most 4096 (one process or Ray actor each), got 5000"),
    (["--vae-epochs", "0"], "--vae-epochs must be >= 1, got 0"),
    (["--studies", "a1-trot", "no-such"], "--studies: no-such not in this plan"),
    (["--report-only", "--studies", "a1-trot"], "--studies does not apply to --report-only"),
    # refused by the studies' tasks: before anything is written (paper.json blocked the fix)
    (["--actor", "foo"], "unknown actor 'foo' (choose from convex, kinodynamic)"),
    (["--v-des", "5"], "--v-des must be a velocity of at most 3 m/s in size, got 5"),
])
def test_paper_bad_input(tmp_path: Path, run_cli, error_line, extra: list[str], expect: str):
    code, _, err = run_cli("paper", "--out", tmp_path / "o", *extra)
    assert expect in error_line(code, err)
    assert not (tmp_path / "o" / "paper.json").exists()
    assert not (tmp_path / "o").exists()           # refused before --out was made


def test_paper_bad_actor_leaves_nothing_to_block_the_fix(tmp_path: Path, run_cli, error_line):
    code, _, err = run_cli("paper", "--robot", "a1", "--actor", "foo", "--out", tmp_path / "o",
                           "--scale", "0.001", "--steps", "100", "--workers", "1", "--no-sim")
    assert "unknown actor 'foo'" in error_line(code, err)
    code, out, err = run_cli("paper", "--robot", "a1", "--out", tmp_path / "o", "--scale", "0.001",
                             "--steps", "100", "--workers", "1", "--sources-only")
    assert code == 0, err
    assert json.loads((tmp_path / "o" / "paper.json").read_text())["actor"] == "convex"


def test_paper_unwritable_out(tmp_path: Path, run_cli, error_line):
    f = tmp_path / "file"
    f.write_text("x")
    for out, expect in ((f / "sub", f"cannot create --out {f / 'sub'}: {f} is a file, not a "
                                    "directory"),
                        (f, f"--out {f} is a file, not a directory"),
                        ("/proc/latentune-paper-test", "cannot create --out")):
        code, _, err = run_cli("paper", "--out", out, "--scale", "1e-6")
        assert expect in error_line(code, err), out


def test_report_only_without_run(tmp_path: Path, run_cli, error_line):
    code, _, err = run_cli("paper", "--out", tmp_path, "--report-only")
    assert "holds no paper run" in error_line(code, err)
    code, _, err = run_cli("paper", "--out", tmp_path / "no" / "such", "--report-only")
    assert "holds no paper run" in error_line(code, err)
    assert not (tmp_path / "no").exists()                  # it was made, empty


def test_report_only_takes_the_stored_options(tmp_path: Path, run_cli, error_line, monkeypatch):
    """--report-only reports the runs on disk: an option left out takes the stored value (the
    report's own command, without --steps, was refused for a --steps 60 run), one given must be
    the stored one, and --sources-only (which wrote no report and said 'sources done') is
    refused."""
    from latentune.reporting import paper_report

    monkeypatch.setattr(paper_report, "write_paper_report", lambda root, **k: f"report {root}")
    out = tmp_path / "p"
    out.mkdir()
    meta = {"robot": "a1", "actor": "convex", "steps": 60, "seed": 3, "workers": 1,
            "v_des": 0.5, "seeds": 1, "vae_epochs": 100, "studies": {},
            "budgets": {**budgets(1e-6, phase3=4)}}
    (out / "paper.json").write_text(json.dumps(meta))
    for extra in ([], ["--steps", "60", "--seed", "3", "--scale", "1e-6", "--phase3-evals", "4",
                       "--workers", "1", "--vae-epochs", "100"]):
        code, text, err = run_cli("paper", "--out", out, "--report-only", *extra)
        assert (code, text.strip()) == (0, f"report {out}"), err
    for extra, expect in ((["--steps", "300"], "--steps 300: "), (["--seed", "1"], "--seed 1: "),
                          (["--robot", "solo12"], "--robot solo12: "),
                          (["--seeds", "3"], "--seeds 3: "),
                          (["--phase1-evals", "99"], "--phase1-evals 99: "),
                          (["--sources-only"], "--sources-only does not apply to --report-only")):
        code, _, err = run_cli("paper", "--out", out, "--report-only", *extra)
        assert expect in error_line(code, err), extra


# ---------------------------------------------------------------------------- --seeds
def _rows(run_dir: Path) -> int:
    try:
        con = sqlite3.connect(f"file:{run_dir / 'run.db'}?mode=ro", uri=True, timeout=1)
        try:
            return int(con.execute("SELECT COUNT(*) FROM evaluations "
                                   "WHERE phase IN (1, 3)").fetchone()[0])
        finally:
            con.close()
    except sqlite3.Error:
        return 0


def _bests(out: Path, keys: list[str], phase: int) -> list[float]:
    res = []
    for k in keys:
        with RunStore(out / k) as st:
            res.append(float(np.min(st.costs(phase))))
    return res


@pytest.fixture
def only_seed_band_figures(monkeypatch: pytest.MonkeyPatch) -> None:
    """The report draws its seed-band figures; its best-so-far and cost-transform figures (the
    end-to-end test checks those) are placeholder files, not laid out and rasterised."""
    from latentune.reporting import plots

    def placeholder(_data: object, path: str | Path, *a: object, **kw: object) -> None:
        Path(path).write_bytes(b"x")

    monkeypatch.setattr(plots, "plot_best_so_far", placeholder)
    monkeypatch.setattr(plots, "plot_cost_transform", placeholder)


def test_paper_seeds_end_to_end_with_a_kill(paper_dir: Path, run_cli, cli_env, dump_store,
                                            tmp_path: Path, only_seed_band_figures):
    """``paper --seeds 2`` on a copy of the finished seed-0 directory: killed mid-way and run
    again, it reuses the sources (their rows unchanged), keeps the killed study's rows, and its
    report gives median [IQR] cells equal to the stores' and band curves. (Defined before the
    resume test, which grows the shared directory's budget: the copy is of the smaller run.)"""
    out = tmp_path / "a1"
    shutil.copytree(paper_dir, out)
    B = json.loads((out / "paper.json").read_text())["budgets"]["phase3"]
    args = ["paper", *TINY, "--phase3-evals", str(B), "--seeds", "2", "--out", str(out),
            "--no-sim", "--quiet"]
    sources = ("a1-trot", "a1-jump", "a1-trot-preservation")
    before = {k: dump_store(out / k)[0] for k in sources}
    proc = subprocess.Popen([sys.executable, "-m", "latentune.cli", *args], env=cli_env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            start_new_session=True)
    killed, t0 = None, time.monotonic()
    try:
        while killed is None and proc.poll() is None and time.monotonic() - t0 < 600:
            for d in sorted(out.glob("*-s1")):
                if (d / "run.db").is_file() and _rows(d) >= 2:
                    killed = d
                    break
            time.sleep(0.2)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=60)
    assert killed is not None, proc.stderr.read().decode()[-2000:]
    partial = set(dump_store(killed)[0])
    code, _, err = run_cli(*args)
    assert code == 0, err[-2000:]
    for k in sources:                       # the sources are reused as they are
        assert dump_store(out / k)[0] == before[k], k
    assert partial <= set(dump_store(killed)[0])   # the killed study resumed from its rows
    meta = json.loads((out / "paper.json").read_text())
    assert meta["seeds"] == 2 and "--seeds 2" in meta["command"]
    s1 = {k: v for k, v in meta["studies"].items() if v["seed_index"] == 1}
    assert {v["arm"] for v in s1.values()} == {"phase3-plain", "phase3-transfer", "turbo", "cma",
                                               "random", "tpe", "cmaes-src"}
    for key, info in s1.items():
        assert key.endswith("-s1")
        with RunStore(out / key) as st:
            cfg = st.get_meta("config")
            assert cfg["seed"] == 1 and cfg["task"]["seed"] == 0, key
            if info["kind"] == "phase3":
                assert st.count(3) == B, key
                assert cfg["phase3_vae_source"] == str((out / info["vae_from"]).resolve())
                assert cfg["phase3"]["strategy"] == info["strategy"], key
            else:
                assert st.count(1) == B, key
                if info["arm"] in ("tpe", "cmaes-src"):
                    assert cfg["phase1"]["method"] == {"tpe": "optuna-tpe",
                                                       "cmaes-src": "optuna-cmaes"}[info["arm"]]
    # the report: every seeded cell is median [IQR] of the stores' values
    md = (out / "report.md").read_text()
    summary = json.loads((out / "paper_summary.json").read_text())
    assert "## Over the seeds (median [interquartile range], 2 seed(s))" in md
    for row, r in summary["seeded"].items():
        for arm, a in r["arms"].items():
            keys = [k for k, v in meta["studies"].items() if v["row"] == row and v["arm"] == arm]
            assert len(keys) == 2 and sorted(a["studies"]) == sorted(keys), (row, arm)
            phase = 1 if meta["studies"][keys[0]]["kind"] == "baseline" else 3
            bests = _bests(out, keys, phase)
            assert a["best"]["median"] == pytest.approx(float(np.median(bests)), rel=1e-12)
            assert (a["best"]["q25"], a["best"]["q75"]) == pytest.approx(
                tuple(np.percentile(bests, [25, 75])), rel=1e-12)
            if arm == "phase3-plain":
                txt = f"{float(np.median(bests)):.3f} [{np.percentile(bests, 25):.3f}–" \
                      f"{np.percentile(bests, 75):.3f}]"
                assert f"| {a['label']} | 2 | {B} [{B}–{B}] | {txt} |" in md, (row, txt)
        assert (out / f"seeds_{row}.png").stat().st_size > 1000, row
        assert f"](seeds_{row}.png)" in md
    _imported_as_rungs(out, tmp_path / "ladder", meta, B)
    jump = _bests(out, ["a1-jump", "a1-jump-flat-s1"], 3)
    cell = _table_row(md, "Phase 3 even")[3]
    assert cell.startswith(f"{np.median(jump):.3f} [") and "2 seeds" in cell, cell
    cross = summary["seeded"]["jump-cross"]
    with RunStore(out / "a1-jump-cross") as st:
        assert cross["zero_shot"] == pytest.approx(float(st.costs(4)[0]), rel=1e-12)
    with RunStore(out / "a1-jump-cross") as st:  # the cross-task baselines start at its row's
        zs = st.rows(4)[0].theta                   # zero-shot θ (the source's best back then)
    for m in ("turbo", "cma", "tpe", "cmaes-src"):
        with RunStore(out / f"a1-jump-cross-{m}-s1") as st:
            if m == "cma":      # pycma's bound handling moves entries on the box's faces inward
                assert np.allclose(st.rows(1)[0].theta, zs, atol=0.05), m
                continue
            assert np.array_equal(st.rows(1)[0].theta, zs), m
            assert float(st.costs(1)[0]) == pytest.approx(cross["zero_shot"], rel=1e-9), m


# ---------------------------------------------------------------------------- resume, report
@pytest.fixture
def unrendered_figures(monkeypatch: pytest.MonkeyPatch) -> None:
    """matplotlib lays out and rasterises no figure: ``savefig`` writes a placeholder file and
    ``tight_layout`` does nothing. For a test that checks the tables of a report, not its
    figures (rendering them is most of an in-process report's time; the end-to-end and
    ``--seeds`` tests check the real figures)."""
    from matplotlib.figure import Figure

    monkeypatch.setattr(Figure, "savefig", lambda self, path, **kw: Path(path).write_bytes(b"x"))
    monkeypatch.setattr(Figure, "tight_layout", lambda self, *a, **kw: None)


def test_paper_resume_and_report_command(paper_dir: Path, run_cli, error_line,
                                         unrendered_figures):
    """On the shared seed-0 directory (after the --seeds test copied it): the same command
    evaluates nothing again, ``report DIR`` gives the same tables, a larger budget resumes
    every study, another configuration is refused."""
    out = paper_dir

    def counts():
        res = {}
        for d in sorted(out.iterdir()):
            if (d / "run.db").is_file():
                with RunStore(d) as st:
                    res[d.name] = tuple(st.count(ph) for ph in (0, 1, 3, 5))
        return res

    before = counts()
    table_before = (out / "report.md").read_text().split("## A1 → B1")[0]
    # re-running the same command: every study is finished, nothing is evaluated again
    code, _, err = run_cli("paper", *TINY, "--phase3-evals", "4", "--out", out, "--no-sim", "-v")
    assert code == 0, err[-2000:]
    assert counts() == before
    assert err.count("done (skipped)") == len(json.loads((out / "paper.json").read_text())
                                              ["studies"])
    # `latentune report DIR` on a paper directory regenerates the same tables from the stores
    (out / "report.md").unlink()
    code, _, err = run_cli("report", out, "--no-sim", "--quiet")
    assert code == 0, err[-2000:]
    assert (out / "report.md").read_text().split("## A1 → B1")[0].split("## Table II")[1] == \
        table_before.split("## Table II")[1]
    # a larger budget resumes every unfinished study: stored rows are kept, new ones appended
    with RunStore(out / "a1-trot-hills") as st:
        old_rows = [(r.idx, r.theta.tolist(), r.cost) for r in st.rows(3)]
    code, _, err = run_cli("paper", *TINY, "--phase3-evals", "6", "--out", out, "--no-sim",
                           "--quiet")
    assert code == 0, err[-2000:]
    after = counts()
    for key, info in json.loads((out / "paper.json").read_text())["studies"].items():
        if info["kind"] in ("phase3", "tune"):
            assert after[key][2] == 6, key
        elif info["kind"] == "baseline":
            assert after[key][1] == 6, key
        if info["kind"] in ("tune", "preservation"):
            assert after[key][1] == before[key][1], key      # phase 1 budget unchanged
    with RunStore(out / "a1-trot-hills") as st:
        new_rows = [(r.idx, r.theta.tolist(), r.cost) for r in st.rows(3)]
    assert new_rows[:4] == old_rows and len(new_rows) == 6
    assert json.loads((out / "paper.json").read_text())["budgets"]["phase3"] == 6
    # another configuration in the same directory is refused
    code, _, err = run_cli("paper", "--robot", "a1", "--scale", "1e-6", "--steps", "300",
                           "--out", out)
    assert "another configuration" in error_line(code, err)
    tiny_default_vae = [a for a in TINY if a not in ("--vae-epochs", "100")]
    code, _, err = run_cli("paper", *tiny_default_vae, "--phase3-evals", "6", "--out", out)
    assert "another configuration" in error_line(code, err) and \
        "--vae-epochs 100 there, default here" in err


# ---------------------------------------------------------------------------- --seeds input
@pytest.mark.parametrize("extra, expect", [
    (["--seeds", "0"], "--seeds must be an integer >= 1, got 0"),
    (["--seeds", "-2"], "--seeds must be an integer >= 1, got -2"),
    (["--seeds", "two"], "--seeds must be an integer >= 1, got 'two'"),
    (["--seeds", "3", "--sources-only"], "--seeds does not apply to --sources-only"),
    (["--sources-only", "--no-sim"], "--no-sim does not apply to --sources-only"),   # ignored
    (["--sources-only", "--no-gif"], "--no-gif does not apply to --sources-only"),
])
def test_paper_bad_seeds(tmp_path: Path, run_cli, error_line, extra: list[str], expect: str):
    code, _, err = run_cli("paper", "--out", tmp_path / "o", "--scale", "1e-6", *extra)
    assert expect in error_line(code, err)
    assert not (tmp_path / "o" / "paper.json").exists()


@pytest.mark.parametrize("sampler", ["tpe", "cmaes"])
def test_optuna_critic_resume_replays_the_sampler(sampler: str):
    """A fresh OptunaCritic told a stored history (any order) asks the batch the original asks
    next; the warm start is its first point; cmaes takes source trials."""
    from latentune.critic.optuna import OptunaCritic

    rng = np.random.default_rng(0)

    def f(X):
        return ((X - 0.3) ** 2).sum(1)

    Xs = rng.random((30, 5))
    kw = dict(batch_size=4, seed=3, x0=np.full(5, 0.55), sampler=sampler,
              source=(Xs, f(Xs)) if sampler == "cmaes" else None)
    c = OptunaCritic(5, **kw)
    X, y, T = [], [], []
    for _ in range(5):
        U = c.ask()
        X.append(U), y.append(f(U)), T.append(c.last_tags.copy())
        c.tell(U, f(U), c.last_tags)
    assert np.array_equal(X[0][0], np.full(5, 0.55))
    nxt = c.ask()
    X, y, T = np.vstack(X), np.concatenate(y), np.concatenate(T)
    p = rng.permutation(len(y))
    c2 = OptunaCritic(5, **kw)
    c2.tell(X[p], y[p], T[p])
    assert np.array_equal(c2.ask(), nxt)
    assert c2.best_y == pytest.approx(float(y.min()))
    with pytest.raises(ValueError, match="source trials are an option of the cmaes"):
        OptunaCritic(5, sampler="tpe", source=(Xs, f(Xs)))


def _imported_as_rungs(out: Path, root: Path, meta: dict, B: int) -> None:
    """benchmarks.robot_transfer's import of the seeded rows that are rungs: a phase-3 study's
    trace is its zero-shot trial then its phase-3 trials, a baseline's its phase-1 trials, each
    cut at the budget; a second import writes nothing."""
    from benchmarks import robot_transfer as rt

    lines = rt.import_paper(out, root, budget=B)
    assert lines and not rt.import_paper(out, root, budget=B)
    with RunStore(out / "a1-trot") as st:
        n_src = st.count(1) + st.count(3)
    for key, rung, method in (("b1-jump-transfer-default-s1", "b1-jump-from-a1-trot", "transfer"),
                              ("a1-jump-cross-s1", "a1-jump-from-trot", "plain"),
                              ("b1-trot-transfer-tpe-s1", "b1-trot-from-a1", "tpe")):
        res = json.loads(rt.result_path(root, rung, n_src, 1, method).read_text())
        with RunStore(out / key) as st:
            zs, p3, p1 = st.rows(4), st.rows(3), st.rows(1)
        want = [zs[0]] + p3[: B - 1] if p3 else p1[:B]
        assert res["costs"] == [r.cost for r in want] and len(res["costs"]) == B, key
        assert res["failed"] == [bool(r.fell) for r in want], key
        assert res["imported"]["study"] == key and res["target_config"]["robot"] == \
            ("b1" if rung.startswith("b1") else "a1")
    zs = json.loads(rt.result_path(root, "a1-jump-from-trot", n_src, 1, "zero_shot").read_text())
    assert len(zs["costs"]) == 1
    assert not any(root.glob("targets/*/*/seed*/random.json"))   # not a peer of the ladder
    s = rt.summarize(root)
    assert {r["target"] for r in s["targets"]} == {"a1-jump-from-trot", "b1-jump-from-a1-trot",
                                                   "b1-trot-from-a1"}



def test_parallel_paper_processes_share_the_plan(tmp_path: Path, monkeypatch, caplog):
    """A study another process is writing (its store locked) is skipped with a warning and the
    rest of the plan runs; paper.json keeps the other process's invocation record."""
    import logging

    from latentune.errors import LockError
    from latentune.experiments import paper as pp
    from latentune.pipeline import evaluators
    from latentune.reporting import paper_report

    class _Ev:
        def close(self) -> None:
            pass

    ran: list[str] = []
    locked = "a1-jump"
    other = {"started": "2000-01-01T00:00:00Z", "command": "latentune paper (other)",
             "pid": 1, "wall_s": 12.5}

    def fake_run_study(plan_, opts, root, b, ev, log):
        if plan_.key == locked:
            meta = json.loads((root / "paper.json").read_text())    # the other one starts
            meta["invocations"].append(other)
            (root / "paper.json").write_text(json.dumps(meta))
            raise LockError(f"{root / plan_.key} is being written by pid 1")
        ran.append(plan_.key)

    monkeypatch.setattr(pp, "run_study", fake_run_study)
    monkeypatch.setattr(evaluators, "make_evaluator", lambda kind, n: _Ev())
    monkeypatch.setattr(paper_report, "write_paper_report", lambda *a, **k: "report")
    opts = pp.PaperOptions(robot="a1", scale=0.01, out=str(tmp_path / "p"), workers=1,
                           quiet=True)
    with caplog.at_level(logging.WARNING, logger="latentune"):
        assert pp.run_paper(opts) == "report"
    assert locked not in ran and len(ran) == len(pp.plan("a1", pp.budgets(0.01))) - 1
    assert any(f"[{locked}] skipped" in r.getMessage() and "being written by pid 1"
               in r.getMessage() for r in caplog.records)
    meta = json.loads((tmp_path / "p" / "paper.json").read_text())
    assert other in meta["invocations"] and len(meta["invocations"]) == 2
    mine = next(i for i in meta["invocations"] if i is not None and i["pid"] != 1)
    assert mine["wall_s"] is not None
    assert mine["machine"]["cores"] >= 1 and len(mine["loadavg_start"]) == len(
        mine["loadavg_end"]) == 3
    text = "\n".join(paper_report._md_machines(meta["invocations"]))
    assert "1 earlier invocation(s) did not record them" in text      # the other one
    assert f"{mine['machine']['cores']} cores" in text and "1-min load average" in text
    old = {"started": "x", "machine": {"cpus": 2, "cpu": "CPU X", "host": "h"}, "wall_s": 1.0,
           "loadavg_start": [1.0, 1.0, 1.0], "loadavg_end": None, "command": "c"}
    assert "- x: 2 cores (CPU X), 1-min load average 1.0, 1 s: `c`" in \
        paper_report._md_machines([old])                              # a record with "cpus"
    assert meta["wall_s_total"] == pytest.approx(12.5 + mine["wall_s"])
    ran.clear()                       # --studies: only those, and the command says so
    opts.studies = ("a1-trot-preservation", "a1-jump-hills")
    pp.run_paper(opts)
    assert ran == ["a1-jump-hills", "a1-trot-preservation"]       # in plan order
    meta = json.loads((tmp_path / "p" / "paper.json").read_text())
    assert meta["invocations"][-1]["command"].endswith(
        "--studies a1-trot-preservation a1-jump-hills")


def test_a_resume_with_another_v_des_is_refused(tmp_path, run_cli, error_line, monkeypatch):
    """``latentune paper`` on a directory that holds a paper run compared robot, actor, steps,
    seed and VAE epochs, not --v-des: a finished run resumed with ``--v-des 0.3`` ran nothing
    and rewrote paper.json, and the report said "v_des = 0.3 m/s" of rollouts made at 0.5.
    It is refused as another configuration, paper.json untouched."""
    import latentune.pipeline.evaluators as ev

    def no_run(*a, **k):
        raise AssertionError("the refused command ran a study")

    monkeypatch.setattr(ev, "make_evaluator", no_run)
    out = tmp_path / "p"
    out.mkdir()
    b = budgets(1e-6)
    meta = {"format": "latentune-paper", "robot": "a1", "actor": "convex", "steps": 60,
            "seed": 0, "v_des": 0.5, "workers": 1, "budgets": b, "seeds": 1,
            "vae_epochs": 100, "studies": {}}
    (out / "paper.json").write_text(json.dumps(meta))
    before = (out / "paper.json").read_text()
    code, _, err = run_cli("paper", *TINY, "--v-des", "0.3", "--out", out)
    line = error_line(code, err)
    assert "another configuration" in line and "--v-des" in line, line
    assert (out / "paper.json").read_text() == before


def test_a_missing_paper_directory_is_not_called_read_only(tmp_path):
    """write_paper_report on a directory that does not exist said it 'cannot be written
    (read-only)'; it says what is missing, as before the read-only check."""
    from latentune.errors import UsageError
    from latentune.reporting.paper_report import write_paper_report

    with pytest.raises(UsageError) as exc:
        write_paper_report(tmp_path / "nowhere")
    assert "read-only" not in str(exc.value) and "paper.json" in str(exc.value)
