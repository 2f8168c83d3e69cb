"""`latentune bench` (latentune.experiments.bench): it needs the checkout's benchmarks and says so
in one line without them; it reads each benchmark's JSON output (ratio, provenance)."""
from __future__ import annotations

import json
import math
import subprocess
from pathlib import Path

import pytest

from latentune.errors import UsageError
from latentune.experiments import bench


def test_without_a_checkout_one_clear_error(monkeypatch, tmp_path):
    monkeypatch.setattr(bench, "repo_root", lambda start=None: None)
    with pytest.raises(UsageError, match="not installed with the package: run latentune bench "
                                         "in a source checkout"):
        bench.run_bench(steps=10, n=1)


def test_finds_the_checkout_from_the_module_or_the_working_directory(tmp_path):
    root = bench.repo_root()
    assert root is not None and (root / "benchmarks" / "common.py").is_file()
    (tmp_path / "benchmarks").mkdir()
    (tmp_path / "benchmarks" / "common.py").write_text("")
    sub = tmp_path / "a" / "b"
    sub.mkdir(parents=True)
    assert bench.repo_root(sub) in (root, tmp_path)


def _proc(code: int, err: str = "") -> subprocess.CompletedProcess:
    return subprocess.CompletedProcess([], code, "", err)


def test_reads_ratio_and_load_from_the_json_output(tmp_path: Path):
    out = tmp_path / "b.json"
    out.write_text(json.dumps({"ratio": 1.75, "provenance": {"loadavg_end": [2.5, 1, 1]}}))
    assert bench._read(out, _proc(0)) == {"status": "ok", "ratio": 1.75, "load": 2.5}
    assert bench._read(tmp_path / "missing.json", _proc(1, "boom\nlast line\n"))["status"] == \
        "exit 1: last line"
    out.write_text(json.dumps({"no_ratio": 1}))
    assert bench._read(out, _proc(0))["status"].startswith("unreadable output (KeyError")


def test_runs_every_benchmark_module_with_out(monkeypatch, tmp_path, capsys):
    """Each benchmark is `python -m benchmarks.NAME ... --out FILE.json` in the checkout; the
    table shows the ratios read back (the subprocess is replaced by one writing the JSON)."""
    calls = []

    def fake_run(argv, **kw):
        calls.append((argv, kw["cwd"]))
        out = Path(argv[argv.index("--out") + 1])
        out.write_text(json.dumps({"ratio": 1.0 + len(calls),
                                   "provenance": {"loadavg_end": [0.5]}}))
        return _proc(0)

    monkeypatch.setattr(bench.subprocess, "run", fake_run)
    assert bench.run_bench(steps=50, n=3, root=tmp_path) == 0
    names = [argv[argv.index("-m") + 1] for argv, _ in calls]
    assert names == [f"benchmarks.{b.name}" for b in bench.BENCHES]
    assert all(cwd == tmp_path for _, cwd in calls)
    thr = calls[[b.name for b in bench.BENCHES].index("throughput")][0]
    assert thr[thr.index("--steps") + 1] == "50" and thr[thr.index("--n") + 1] == "3"
    table = capsys.readouterr().out
    assert "| actor | 2.00 |" in table and "| throughput | 4.00 |" in table
    # the status says whether a ratio meets its goal ("ok" read as met: actor 2.0 <= 2)
    assert "| ran, goal met |" in table.splitlines()[2]
    assert "ran, goal missed (3.00, goal <= 2)" in bench.BENCHES[0].verdict(3.0)
    assert bench.BENCHES[1].verdict(9.0) == "ran"


@pytest.mark.parametrize("timeout", [math.inf, 1e10, 3e6])
def test_an_infinite_timeout_is_no_limit(monkeypatch, tmp_path, capsys, timeout):
    """--timeout inf (1e999), or one longer than subprocess can wait, runs each benchmark
    without a limit (subprocess raised OverflowError: a traceback)."""
    (tmp_path / "benchmarks").mkdir()
    (tmp_path / "benchmarks" / "__init__.py").write_text("")
    (tmp_path / "benchmarks" / "tiny.py").write_text(
        "import json, sys\n"
        "open(sys.argv[sys.argv.index('--out') + 1], 'w').write(json.dumps({'ratio': 1.5}))\n")
    monkeypatch.setattr(bench, "BENCHES", (bench.Bench("tiny", (), "a tiny benchmark"),))
    assert bench.run_bench(steps=1, n=1, timeout=timeout, root=tmp_path) == 0
    assert "| tiny | 1.50 |" in capsys.readouterr().out
