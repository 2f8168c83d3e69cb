"""Named constants shared by every module: the fall threshold, the phases, gaits, terrains, g.

Defined once here; every other module imports them.
"""
from __future__ import annotations

from enum import IntEnum

C1: float = 100.0
"""Fall threshold of the path cost: cost < C1 ⇔ the trial did not fail (paper Eq. 2)."""

STABLE_CAP: float = C1 * (1.0 - 1e-6)
"""The largest cost a trial that did not fail can have (so cost < C1 ⇔ stable always holds)."""

COST_LIMIT: float = 1e300
"""The largest size of a cost a trial may report: the run store keeps ±COST_LIMIT for ±inf
(SQLite's REAL column has no inf), so a finite cost this large or larger is refused."""

G: float = 9.81
"""Gravitational acceleration [m/s²]."""

GAITS: tuple[str, ...] = ("trot", "jump")
"""Built-in gaits: trot (diagonal pairs) and jump (all four legs together, a forward pronk)."""

TERRAINS: tuple[str, ...] = ("flat", "hills")
"""Built-in terrains: a plane, or Perlin hills (10 octaves × 0.02 m, 5 m × 5 m, 0.05 m cells)."""


class Phase(IntEnum):
    """The ``phase`` column of the run store."""

    MANUAL = 0        #: the system's manual θ, evaluated once
    PHASE1 = 1        #: the critic on the full θ box
    PHASE3 = 3        #: the critic on the latent box, through the decoder
    ZERO_SHOT = 4     #: the source run's best θ evaluated as it is on the target
    PRESERVATION = 5  #: stable θ passed through encode → decode and evaluated again


PHASE_NAMES: dict[Phase, str] = {Phase.MANUAL: "manual", Phase.PHASE1: "phase 1",
                                 Phase.PHASE3: "phase 3", Phase.ZERO_SHOT: "zero-shot",
                                 Phase.PRESERVATION: "preservation"}
"""The name of each phase of the store, as status, trials and error lines give it."""


def phase_name(phase: int) -> str:
    """"phase 1", "zero-shot", ...: the name of a stored phase number."""
    return PHASE_NAMES.get(Phase(int(phase)), f"phase {int(phase)}")


def fail_cost(fall_step: int | None, horizon: int) -> float:
    """The path cost of a trial that failed at step ``fall_step`` of ``horizon`` steps:
    ``C1 · (2 − k/N_H)`` (a later failure is better). ``None`` (step unknown) gives ``2 · C1``."""
    if fall_step is None:
        return 2.0 * C1
    return C1 * (2.0 - float(fall_step) / float(horizon))


PAPER_PHASE1 = 10000
"""The paper's phase-1 budget (evaluations per gait; Sarmadi et al.)."""
PAPER_PHASE3 = 220
"""The paper's phase-3 budget (evaluations per study)."""
