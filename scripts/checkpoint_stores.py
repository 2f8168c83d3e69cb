"""Fold each SQLite WAL under the given directories into its run.db (a PASSIVE checkpoint, safe
while a run writes), so that ``git add DIR/**/run.db`` commits every finished evaluation.
Usage: python scripts/checkpoint_stores.py results/paper10k"""
from __future__ import annotations

import sqlite3
import sys
from pathlib import Path

for root in sys.argv[1:] or ["results"]:
    for db in sorted(Path(root).rglob("run.db")):
        con = sqlite3.connect(db, timeout=30)
        busy, log, done = con.execute("PRAGMA wal_checkpoint(PASSIVE)").fetchone()
        n = con.execute("SELECT COUNT(*) FROM evaluations").fetchone()[0] if con.execute(
            "SELECT name FROM sqlite_master WHERE name='evaluations'").fetchone() else -1
        con.close()
        print(f"{db}: {n} rows, wal frames {log}, checkpointed {done}")
