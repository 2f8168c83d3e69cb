"""Wall times of a run's phases, kept in its store's meta entries.

``wall``: seconds per key (``phase1``, ``vae``, ``phase3``, ``preservation_rollouts``), added
when a timed block ends. ``wall_open``: the unix time each running block started, stored before
it runs, so a command killed inside one (SIGKILL: no clean-up) leaves its start behind; its time
is counted up to the last trial a command stored since (:func:`wall_record`; not the trials
told through ask/tell after it), and written into ``wall``
when the next timed block of the store starts (:func:`settle_open`). ``wall_unknown``: the keys
of killed blocks that stored no trial, whose time nobody knows; a later block of the same key
that ends adds its time to ``wall`` and leaves the key in ``wall_unknown``: the key's total is
then partly known (the report shows its time "+ unknown").
"""
from __future__ import annotations

from typing import Any

from latentune.constants import Phase

WALL_PHASES: dict[str, Phase] = {"phase1": Phase.PHASE1, "phase3": Phase.PHASE3,
                                 "preservation_rollouts": Phase.PRESERVATION}
"""The wall keys whose blocks store trials, and the phase they store them in."""


def last_created(store: Any, since: float) -> float | None:
    """The unix time of the last trial a command stored at or after ``since`` (any phase), or
    None. Trials told through ask/tell (``info["trial"]``: the suggestion's id) are left out:
    no command timed them, and an ask or a tell settles no open block (:func:`settle_open`),
    so a killed block's time would otherwise stretch to the last tell after it."""
    row = store.con.execute("SELECT MAX(created) FROM evaluations WHERE created >= ? AND "
                            "(CASE WHEN json_valid(info) THEN json_extract(info, '$.trial') END) IS NULL",
                            (float(since),)).fetchone()
    return None if row[0] is None else float(row[0])


def open_walls(store: Any) -> tuple[dict[str, float], list[str]]:
    """The open blocks (``wall_open``) of ``store``: the seconds each ran up to the last trial
    stored since its start, and the keys of those that stored no trial (time unknown)."""
    spent: dict[str, float] = {}
    unknown: list[str] = []
    for key, start in (store.get_meta("wall_open", {}) or {}).items():
        last = last_created(store, start)
        if last is None:
            unknown.append(key)
        else:
            spent[key] = last - float(start)
    return spent, unknown


def wall_record(store: Any) -> tuple[dict[str, float], list[str]]:
    """The run's wall times [s] per key and the keys whose time is not (all) known.

    The ``wall`` entries, plus each open block's time up to its last stored trial (a command
    running now, or one killed inside the block). Unknown: a killed block that stored no trial
    (``wall_unknown`` and open ones), and a phase that holds trials but no wall entry (trials
    told through ask/tell or imported from Optuna, which no command timed, or a run killed
    before wall starts were stored)."""
    wall = {k: float(v) for k, v in (store.get_meta("wall", {}) or {}).items()}
    spent, unknown = open_walls(store)
    for key, s in spent.items():
        wall[key] = wall.get(key, 0.0) + s
    unknown = sorted(set(unknown) | set(store.get_meta("wall_unknown", []) or []))
    unknown += [key for key, phase in WALL_PHASES.items()
                if key not in wall and key not in unknown and store.count(phase)]
    return wall, unknown


def settle_open(store: Any) -> None:
    """Write the open blocks of a command that was killed into ``wall`` (their time up to their
    last stored trial) and ``wall_unknown`` (no trial stored), and close them. Only under the
    run's write lock, when no other command of the store is running."""
    spent, unknown = open_walls(store)
    if not spent and not unknown:
        return
    wall = store.get_meta("wall", {}) or {}
    for key, s in spent.items():
        wall[key] = float(wall.get(key, 0.0)) + s
    lost = sorted(set(store.get_meta("wall_unknown", []) or []) | set(unknown))
    store.update_meta({"wall": wall, "wall_unknown": lost or None, "wall_open": None})


__all__ = ["WALL_PHASES", "last_created", "open_walls", "wall_record", "settle_open"]
