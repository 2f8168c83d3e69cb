"""Examples of latentune on user-defined systems (run from the repository root).

* :mod:`examples.toy_plant` — a pure-numpy plant (no extra dependency; used by the tests);
* :mod:`examples.gym_controller` — a 36-weight linear feedback controller for Gymnasium's
  MuJoCo ``Hopper-v5`` (needs ``pip install "gymnasium[mujoco]"``);
* :mod:`examples.sim_to_real` — phases 1 + 2 on the Hopper model, phase 3 on a perturbed
  "real" Hopper, against the zero-shot θ and direct TuRBO-m on the real one;
* ``examples/ask_tell_session.sh`` — ask/tell from the shell, as a person at a robot would.
"""
from __future__ import annotations

import math


def checked_gap(gap: float) -> float:
    """A system's model-to-plant ``gap`` as a float; ValueError unless a finite number >= 0
    (a bool is not one: ``gap=true`` was a gap of 1)."""
    if isinstance(gap, bool):
        raise ValueError(f"gap must be a finite number >= 0, got {gap}")
    g = float(gap)
    if not math.isfinite(g) or g < 0:
        raise ValueError(f"gap must be a finite number >= 0, got {gap}")
    return g


def checked_steps(steps: int) -> int:
    """An episode's ``steps`` as an int; ValueError unless a whole number >= 1 (``steps=2.5``
    was 2 steps, ``steps=true`` one)."""
    if isinstance(steps, bool) or not isinstance(steps, (int, float)) or steps != int(steps) \
            or steps < 1:
        raise ValueError(f"steps must be a whole number >= 1, got {steps!r}")
    return int(steps)

