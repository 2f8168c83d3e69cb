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
import numbers


def checked_gap(gap: float) -> float:
    """A system's model-to-plant ``gap`` as a float; ValueError unless a finite number >= 0
    (a bool is not one: ``gap=true`` was a gap of 1)."""
    if isinstance(gap, bool):
        raise ValueError(f"gap must be a finite number >= 0, got {gap}")
    g = float(gap)
    if not math.isfinite(g) or g < 0:
        raise ValueError(f"gap must be a finite number >= 0, got {gap}")
    return g


def checked_steps(steps: int, name: str = "steps", least: int = 1) -> int:
    """An episode's ``steps`` (or another count ``name``) as an int; ValueError unless a whole
    number >= ``least`` (``steps=2.5`` was 2 steps, ``steps=true`` one)."""
    if isinstance(steps, bool) or not isinstance(steps, numbers.Real) \
            or not math.isfinite(steps) or steps != int(steps) or steps < least:
        raise ValueError(f"{name} must be a whole number >= {least}, got {steps!r}")
    return int(steps)


def checked_scale(value: float, name: str, zero: bool = False) -> float:
    """A plant's scale factor ``name`` as a float; ValueError unless a finite number > 0
    (``zero``: >= 0)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real) \
            or not math.isfinite(value) or value < 0 or (value == 0 and not zero):
        raise ValueError(f"{name} must be a finite number {'>=' if zero else '>'} 0, "
                         f"got {value!r}")
    return float(value)

