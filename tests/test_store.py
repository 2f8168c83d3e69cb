"""The run store (latentune.pipeline.store): round trip of rows, meta and artifacts; corrupt and
foreign files refused without being changed."""
from __future__ import annotations

import contextlib
import json
import os
import sqlite3
import subprocess
import sys

import numpy as np
import pytest

from latentune.pipeline.store import RunStore, StoreError


def test_store_round_trip(tmp_path):
    with RunStore(tmp_path / "run", create=True) as st:
        st.set_meta("config", {"a": 1, "b": [1, 2]})
        for i in range(5):
            st.add(1, i, np.full(3, i / 10), cost=10.0 + i, tag=i * 7, fell=False, wall_s=0.5,
                   seed=3)
        st.add(3, 0, np.full(3, 0.5), cost=150.0, z=[0.1, 0.2], tag=2, fall_step=42)
        with pytest.raises(StoreError):
            st.add(1, 2, np.zeros(3), cost=1.0)            # an index is never written twice
        st.add_artifact("vae", tmp_path / "run" / "vae")
    with RunStore(tmp_path / "run") as st:
        assert st.get_meta("config") == {"a": 1, "b": [1, 2]}
        rows = st.rows(1)
        assert [r.idx for r in rows] == list(range(5))
        assert np.allclose(rows[3].theta, 0.3) and rows[3].cost == 13.0 and rows[3].tag == 21
        X, y, t = st.history(3)
        assert np.allclose(X, [[0.1, 0.2]]) and y[0] == 150.0 and t[0] == 2
        r3 = st.rows(3)[0]
        assert r3.fell and r3.fall_step == 42 and np.allclose(r3.theta, 0.5)
        assert st.best(1).idx == 0 and st.count(1) == 5 and st.next_idx(1) == 5
        assert st.artifact("vae") == tmp_path / "run" / "vae"
        st.check_contiguous(1)
        assert st.con.execute("PRAGMA journal_mode").fetchone()[0] == "wal"


def test_store_rejects_corrupt_and_foreign(tmp_path):
    d = tmp_path / "bad"
    d.mkdir()
    (d / "run.db").write_bytes(b"this is not a database at all" * 100)
    before = (d / "run.db").read_bytes()
    with pytest.raises(StoreError, match="not a latentune run store"):
        RunStore(d)
    assert (d / "run.db").read_bytes() == before
    f = tmp_path / "foreign"
    f.mkdir()
    con = sqlite3.connect(f / "run.db")
    con.execute("CREATE TABLE t (x)")
    con.commit()
    con.close()
    with pytest.raises(StoreError, match="not a latentune run store"):
        RunStore(f)
    with pytest.raises(StoreError, match="does not exist"):
        RunStore(tmp_path / "missing")


def test_store_of_a_newer_version_is_refused_untouched(tmp_path):
    """A store written by a newer latentune (another schema) was read and written as if it
    were this version's: one line saying to upgrade, and the file is not changed."""
    import json

    d = tmp_path / "new"
    with RunStore(d, create=True) as st:
        st.add(1, 0, np.zeros(3), cost=1.0)
        st.set_meta("version", 99)
    before = (d / "run.db").read_bytes()
    with pytest.raises(StoreError, match="of version 99, written by a newer latentune"):
        RunStore(d)
    assert (d / "run.db").read_bytes() == before
    con = sqlite3.connect(d / "run.db")
    con.execute("UPDATE meta SET value=? WHERE key='version'", (json.dumps(3),))
    con.commit()
    con.close()
    with RunStore(d) as st:
        assert st.count(1) == 1


@contextlib.contextmanager
def _read_only_dir(d):
    """``d`` cannot be written, as on read-only media: chmod for a user, ``chattr +i`` for root
    (who writes whatever the mode); skips where neither works."""
    if os.geteuid() != 0:
        d.chmod(0o555)
        try:
            yield
        finally:
            d.chmod(0o755)
        return
    if subprocess.run(["chattr", "+i", str(d)], capture_output=True).returncode != 0:
        pytest.skip("cannot make a directory read-only here (chattr)")
    try:
        yield
    finally:
        subprocess.run(["chattr", "-i", str(d)], check=True)


def test_store_in_a_read_only_directory_is_read_and_refuses_writes(tmp_path):
    """A run on read-only media (an archive, another user's run: a source for phase 3) was
    "corrupt (unable to open database file)": SQLite could not create its WAL's shared-memory
    file. It is read as usual; a write is one line."""
    d = tmp_path / "ro"
    with RunStore(d, create=True) as st:
        st.add(1, 0, np.zeros(3), cost=1.0)
    with _read_only_dir(d):
        with RunStore(d) as st:
            assert st.read_only and st.count(1) == 1 and st.rows(1)[0].cost == 1.0
            assert RunStore.data_version_of(d)[0] == st.data_version()[0]
            with pytest.raises(StoreError, match="cannot be written .read-only."):
                st.add(1, 1, np.zeros(3), cost=2.0)
        assert sorted(p.name for p in d.iterdir()) == ["run.db"]


@pytest.mark.parametrize("key, value", [("config", [1]), ("config", "phase1"),
                                        ("wall", [3.0]), ("artifacts", 7),
                                        ("wall_open", [3.0])])
@pytest.mark.parametrize("cmd", ["report", "status", "best"])
def test_a_meta_entry_that_is_not_a_json_object_is_one_line(tmp_path, run_cli, error_line,
                                                            key, value, cmd):
    """A run store whose ``config``, ``wall``, ``wall_open`` or ``artifacts`` entry is valid
    JSON but not an
    object (another tool's or another layout's store, a hand edit) ended ``report``, ``status``
    and ``best`` in a traceback ("'list' object has no attribute 'get'"): opening it says in
    one line which entry is wrong, and the store is left as it was."""
    d = tmp_path / "run"
    with RunStore(d, create=True) as st:
        st.add(1, 0, np.zeros(3), cost=1.0)
        st.set_meta(key, value)
    raw = (d / "run.db").read_bytes()
    line = error_line(*run_cli(cmd, d)[::2])
    assert line == (f"latentune: error: run store {d / 'run.db'}: meta entry {key!r} is not a "
                    f"JSON object (got {type(value).__name__})")
    assert (d / "run.db").read_bytes() == raw


def test_best_of_a_robot_run_stored_before_the_space_was_recorded(tmp_path, run_cli):
    """A built-in robot's run of the first store layout records its task, not its parameter
    space: ``status`` said "write it with: latentune best DIR", and ``best`` then refused
    ("no parameter space stored"), and ``trials()`` named θ ``theta[i]`` in the unit box. The
    space is the stored task's, as the report's re-simulation takes it."""
    import latentune as lt
    from latentune.task import Task

    task = {"robot": "a1", "gait": "trot", "terrain": "flat", "actor": "convex",
            "v_des": [0.5, 0.0, 0.0], "steps": 200, "seed": 0, "dim": 25}
    space = Task.from_config(task).space
    d = tmp_path / "run"
    with RunStore(d, create=True) as st:
        st.set_meta("config", {"task": task, "phase1": {"method": "turbo"}})
        st.add(1, 0, np.full(25, 0.5), cost=3.0)
        st.add(1, 1, np.full(25, 0.25), cost=2.0)
    assert "write it with: latentune best" in run_cli("status", d)[1]
    code, out, err = run_cli("best", d)
    assert code == 0, err
    best = json.loads((d / "best.json").read_text())
    assert best.pop("tuned_for") == {"robot": "a1", "gait": "trot", "actor": "convex"}
    assert best == space.as_dict(np.full(25, 0.25))
    with lt.Study(d) as st:
        assert st.trials()[1].params == space.as_dict(np.full(25, 0.25))


def test_best_of_a_store_with_trials_and_no_space_does_not_say_no_trial(tmp_path, run_cli,
                                                                        error_line):
    """``best`` on a run store that holds trials but no parameter space in its record (a store
    of another layout) said "no parameter space stored (no trial yet)", though ``status``
    lists its trials: it says the record has no space, so the θ cannot be named."""
    d = tmp_path / "run"
    with RunStore(d, create=True) as st:
        st.add(1, 0, np.zeros(3), cost=1.0)
    line = error_line(*run_cli("best", d)[::2])
    assert line == (f"latentune: error: {d}: no parameter space stored, though it holds 1 "
                    "trial (a store of another layout?): its θ cannot be named")
    assert not (d / "best.json").exists()


def test_status_of_a_store_with_trials_and_no_space_does_not_advise_best(tmp_path, run_cli,
                                                                        error_line):
    """``status`` on such a store (no space, no task recorded) said "write it with: latentune
    best DIR", and ``best`` then refused: it says the θ cannot be written, and why."""
    d = tmp_path / "run"
    with RunStore(d, create=True) as st:
        st.add(1, 0, np.zeros(3), cost=1.0)
    code, out, _ = run_cli("status", d)
    assert code == 0 and "latentune best" not in out, out
    assert out.splitlines()[-1] == ("best: 1 (phase 1, evaluation 0); its θ cannot be written: "
                                    "the store records no parameter space (a store of another "
                                    "layout?)")
    assert "no parameter space stored" in error_line(*run_cli("best", d)[::2])


@pytest.mark.parametrize("op", ["add", "forget"])
def test_an_artifact_recorded_by_another_process_meanwhile_is_kept(tmp_path, op):
    """``report`` records its figures in the run's artifacts while a phase run records its own
    (the latent space, the best θ files): each read the record, then wrote it back with its
    entry, so an entry written by the other between the two was lost (a ``vae`` lost this way
    leaves phase 3 without its latent space). The read and the write are one transaction."""
    import threading

    d = tmp_path / "run"
    with RunStore(d, create=True) as st:
        st.add_artifact("old", d / "old.png")
    a = RunStore(d)

    def other_writes() -> None:
        with RunStore(d) as b:
            b.add_artifact("vae", d / "vae")

    other = threading.Thread(target=other_writes)
    read = a.get_meta

    def read_then_other_writes(key, default=None):
        value = read(key, default)
        if key == "artifacts" and not other.is_alive() and other.ident is None:
            other.start()                       # the other process writes meanwhile ...
            other.join(timeout=0.5)             # ... or waits for this write to end
        return value

    a.get_meta = read_then_other_writes
    if op == "add":
        a.add_artifact("report_md", d / "report.md")
    else:
        a.forget_artifact("old")
    a.close()
    other.join()
    with RunStore(d) as st:
        arts = st.get_meta("artifacts")
    assert arts == ({"old": "old.png", "vae": "vae", "report_md": "report.md"} if op == "add"
                    else {"vae": "vae"})


def test_report_in_a_read_only_directory_is_one_line(tmp_path, run_cli, error_line):
    """``report`` on a run on read-only media ended in a traceback (PermissionError writing
    ``best_so_far.png``): the report is written into the run, so it says in one line that the
    run cannot be written and what to do, before writing anything; ``status`` still reads it."""
    d = tmp_path / "ro"
    with RunStore(d, create=True) as st:
        st.add(1, 0, np.zeros(3), cost=1.0)
    with _read_only_dir(d):
        for argv in (["report", d], ["report", d, "--no-sim"]):
            line = error_line(*run_cli(*argv)[::2])
            assert line == (f"latentune: error: {d} cannot be written (read-only): copy the run "
                            "to a writable directory and use the copy")
        assert run_cli("status", d)[0] == 0
    assert sorted(p.name for p in d.iterdir()) == ["run.db"]


def test_best_of_a_run_in_a_read_only_directory_names_out(tmp_path, run_cli, error_line):
    """``best`` on a run on read-only media said only "cannot write DIR/best.json: Operation
    not permitted": it says the run cannot be written and how to get the θ anyway
    (``--out FILE``), which writes it elsewhere."""
    import latentune as lt

    d = tmp_path / "ro"
    space = lt.ParameterSpace(["a", "b"], [0.0, 0.0], [1.0, 1.0], manual=[0.5, 0.5])
    with lt.Study(d) as st:
        st.tell(st.ask(1, space=space)[0].id, 1.0)
    (d / "best.json").unlink()
    with _read_only_dir(d):
        line = error_line(*run_cli("best", d)[::2])
        assert line == (f"latentune: error: {d} cannot be written (read-only): write the θ "
                        "elsewhere with --out FILE")
        out = tmp_path / "theta.json"
        assert run_cli("best", d, "--out", out)[0] == 0
    assert json.loads(out.read_text()) == {"a": 0.5, "b": 0.5}


def test_a_read_only_store_file_in_a_writable_directory_says_so(tmp_path, run_cli, error_line):
    """A run.db made read-only (chmod a-w, an archive's file) in a writable directory was opened
    for writing: ``report`` and ``ask`` failed with SQLite's "run store …: attempt to write a
    readonly database" (ask also warned it "could not undo the failed write"). It is read as a
    read-only store: status reads it, a write names the file and what to do."""
    d = tmp_path / "run"
    with RunStore(d, create=True) as st:
        st.add(1, 0, np.zeros(3), cost=1.0)
    f = d / "run.db"
    if os.geteuid() != 0:
        f.chmod(0o444)
    elif subprocess.run(["chattr", "+i", str(f)], capture_output=True).returncode != 0:
        pytest.skip("cannot make a file read-only here (chattr)")
    try:
        with RunStore(d) as st:
            assert st.read_only and st.count(1) == 1
            with pytest.raises(StoreError) as exc:
                st.add(1, 1, np.zeros(3), cost=2.0)
        assert str(exc.value) == (f"{f} cannot be written (read-only): make it writable, or "
                                  "copy the run to a writable directory")
        assert run_cli("status", d)[0] == 0
    finally:
        if os.geteuid() != 0:
            f.chmod(0o644)
        else:
            subprocess.run(["chattr", "-i", str(f)], check=True)


@pytest.mark.parametrize("name", ["a#b", "x?y", "50%41", "sp ace é"])
def test_store_reopens_under_a_name_with_uri_characters(tmp_path, name):
    """A directory named ``a#b`` or ``x?y`` was cut at the URI's fragment or query when the
    store was checked (an empty file ``a`` was created beside it and the run "missing
    tables"); ``50%41`` was read as an escape."""
    with RunStore(tmp_path / name, create=True) as st:
        st.add(1, 0, np.zeros(3), cost=1.0)
    with RunStore(tmp_path / name) as st:
        assert st.count(1) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == [name]


def test_a_new_store_appears_whole_to_another_process(tmp_path, monkeypatch):
    """Two first asks at once: the second opened DIR/run.db while the first was still
    creating it and failed with 'not a latentune run store (missing tables)'. run.db now
    appears complete (tables and format mark) or not at all."""
    d = tmp_path / "run"
    real = RunStore._is_current
    seen: list[str] = []

    def is_current(self):
        if self.path.is_file() and not getattr(is_current, "busy", False):
            is_current.busy = True       # what another process sees at this moment
            try:
                RunStore(d).close()
                seen.append("ok")
            except StoreError as exc:
                seen.append(str(exc))
            finally:
                is_current.busy = False
        return real(self)

    monkeypatch.setattr(RunStore, "_is_current", is_current)
    st = RunStore(d, create=True)
    monkeypatch.setattr(RunStore, "_is_current", real)
    assert all(s == "ok" for s in seen), seen
    assert st.get_meta("format") == "latentune-run-store" and st.get_meta("created")
    st.close()
    assert sorted(p.name for p in d.iterdir() if not p.name.startswith("run.db")) == []
    RunStore(d, create=True).close()            # a second creator opens the existing store


def _asked_and_told(d, costs=(3.0, 1.0)):
    """An ask/tell run in ``d`` with ``costs`` told; returns its Study, open."""
    import latentune as lt

    space = lt.ParameterSpace(names=["kp", "kd"], low=[0.0, 0.0], high=[1.0, 1.0],
                              manual=[0.5, 0.5])
    st = lt.Study(d, seed=0)
    for s, c in zip(st.ask(len(costs), space=space), costs):
        st.tell(s.id, c)
    return st


def test_best_theta_files_of_two_writers_at_once_and_a_users_tmp_file(tmp_path, monkeypatch):
    """best θ files were written through one temporary name, DIR/best.json.tmp: a second writer
    meanwhile renamed it away, so the first one's rename failed ('cannot write DIR/best.json'),
    and a user's own DIR/best.json.tmp was overwritten and removed. Each writer now has a
    temporary file of its own. The second writer is forced between the first one's write and
    its rename."""
    d = tmp_path / "run"
    st = _asked_and_told(d)
    mine = d / "best.json.tmp"
    mine.write_text("my notes")
    replace, other = os.replace, []

    def other_writes_meanwhile(src, dst):
        if not other:
            other.append(None)
            other[0] = st.best_params()              # the other writer, whole, in between
        return replace(src, dst)

    monkeypatch.setattr(os, "replace", other_writes_meanwhile)
    path = st.best_params()
    monkeypatch.undo()
    st.close()
    assert other == [path] and json.loads(path.read_text())["kp"] is not None
    assert mine.read_text() == "my notes"
    assert sorted(p.name for p in d.iterdir() if p.name.endswith(".tmp")) == ["best.json.tmp"]


def test_summary_and_report_are_not_left_truncated(tmp_path, monkeypatch, full_disk):
    """summary.json and report.md were written in place: a write cut short (a full disk, a
    kill) left a truncated file instead of the last whole one. They are written to a
    temporary file and renamed: the old file stays whole; no temporary file is left."""
    from latentune.reporting.run_report import make_report, write_summary

    d = tmp_path / "run"
    st = _asked_and_told(d)
    make_report(st.store, simulate=False, quiet=True)
    before = {n: (d / n).read_text() for n in ("summary.json", "report.md")}
    full_disk()
    with pytest.raises(OSError):
        write_summary(st.store)
    with pytest.raises(OSError):
        make_report(st.store, simulate=False, quiet=True)
    monkeypatch.undo()
    st.close()
    assert {n: (d / n).read_text() for n in before} == before
    assert not [p.name for p in d.iterdir() if p.name.endswith(".tmp")]


def test_a_wall_unknown_entry_that_is_not_a_list_is_one_line(tmp_path, run_cli, error_line):
    """``wall_unknown`` (the keys of timed blocks whose time is lost) holding a number ended
    ``report`` in a traceback ("'int' object is not iterable"); opening the store says so."""
    d = tmp_path / "run"
    with RunStore(d, create=True) as st:
        st.add(1, 0, np.zeros(3), cost=1.0)
        st.set_meta("wall_unknown", 5)
    line = error_line(*run_cli("report", d, "--no-sim")[::2])
    assert line == (f"latentune: error: run store {d / 'run.db'}: meta entry 'wall_unknown' is "
                    "not a JSON list (got int)")


def test_a_new_store_is_born_in_wal_mode(tmp_path, monkeypatch):
    """run.db is in WAL mode when it is linked in, before its first open (file format bytes 18
    and 19 are 2): that open never switches journal modes, the one write of a store through a
    rollback journal, which a kill could leave hot. Nothing of the temporary file is left."""
    heads = []
    link = os.link

    def recording_link(src, dst, *a, **kw):
        heads.append(open(src, "rb").read(20))
        return link(src, dst, *a, **kw)

    monkeypatch.setattr(os, "link", recording_link)
    RunStore(tmp_path / "run", create=True).close()
    assert len(heads) == 1 and heads[0][18:20] == b"\x02\x02", heads
    assert sorted(p.name for p in (tmp_path / "run").iterdir()) == ["run.db"]


def test_a_store_killed_with_a_hot_rollback_journal_opens_rolled_back(tmp_path, caplog):
    """A store of an earlier version (rollback journal) whose writer was killed mid-transaction
    (a hot run.db-journal): opening it rolled the transaction back and went on; before, the
    read-only check could not (SQLITE_READONLY_ROLLBACK) and every command said 'cannot read
    run store …: attempt to write a readonly database'."""
    d = tmp_path / "run"
    with RunStore(d, create=True) as st:
        for i in range(3):
            st.add(1, i, np.full(3, i / 10), cost=1.0 + i)
    con = sqlite3.connect(str(d / "run.db"))
    con.execute("PRAGMA journal_mode=DELETE")
    con.close()
    killed = r"""
import os, signal, sqlite3, sys
con = sqlite3.connect(sys.argv[1], isolation_level=None)
con.execute("PRAGMA cache_size=1")
con.execute("BEGIN")
con.execute("UPDATE evaluations SET cost = cost + 100")
con.execute("CREATE TABLE filler(x)")
con.execute("INSERT INTO filler SELECT randomblob(4000) FROM evaluations, evaluations AS b, "
            "evaluations AS c, evaluations AS e")
os.kill(os.getpid(), signal.SIGKILL)
"""
    subprocess.run([sys.executable, "-c", killed, str(d / "run.db")])
    assert (d / "run.db-journal").stat().st_size > 0            # hot: the kill left it
    with caplog.at_level("WARNING", logger="latentune.pipeline.store"):
        with RunStore(d) as st:
            assert [r.cost for r in st.rows(1)] == [1.0, 2.0, 3.0]   # the old values
            st.add(1, 3, np.full(3, 0.3), cost=4.0)                  # and it can be written
    assert "rolling back" in caplog.text
    assert not (d / "run.db-journal").exists() or (d / "run.db-journal").stat().st_size == 0


def test_a_second_open_in_one_process_keeps_its_writes_seen_by_other_processes(tmp_path):
    """RunStore read the file's header with Python's open(); closing that descriptor dropped
    every POSIX lock the process held on run.db, its open connection's too. Another process
    closing its connection (a `status` while a phase run wrote its report) then found itself
    the last one, checkpointed and deleted the write-ahead log still in use: the first
    process's later commits went to the deleted log, unseen by other processes, and an `ask`
    meanwhile failed with a traceback ("database disk image is malformed") or "disk I/O
    error". A second open no longer touches the file outside SQLite."""
    d = tmp_path / "r"
    read = ("import sys; from latentune.pipeline.store import RunStore; "
            "s = RunStore(sys.argv[1]); print(s.get_meta('x')); s.close()")

    def other_process() -> str:
        return subprocess.run([sys.executable, "-c", read, str(d)], check=True,
                              capture_output=True, text=True).stdout.strip()
    a = RunStore(d, create=True)
    a.set_meta("x", 1)
    RunStore(d).close()                 # a second open of the same run in this process
    assert other_process() == "1"       # it opens and closes its own connection
    assert (d / "run.db-wal").exists()  # the log in use stays
    a.set_meta("x", 2)
    assert other_process() == "2"
    a.close()
    assert other_process() == "2"


def test_a_store_that_reads_malformed_when_checked_is_one_line(tmp_path, run_cli, error_line,
                                                               monkeypatch):
    """A store SQLite found malformed when a writer checked it (an ask) ended in a traceback
    (``sqlite3.DatabaseError: database disk image is malformed``); it is one line."""
    sp = tmp_path / "S.yaml"
    sp.write_text("names: [a, b]\nlow: [0, 0]\nhigh: [1, 1]\n")
    d = tmp_path / "r"
    assert run_cli("ask", d, "--space", sp)[0] == 0
    assert run_cli("tell", d, "1", "--cost", "1")[0] == 0

    def malformed(self: RunStore, phase: int) -> None:
        raise sqlite3.DatabaseError("database disk image is malformed")
    monkeypatch.setattr(RunStore, "check_contiguous", malformed)
    line = error_line(*run_cli("ask", d)[::2])
    assert line == (f"latentune: error: run store {d / 'run.db'} is corrupt (database disk "
                    "image is malformed)")
