"""Reports of runs and of paper directories, all numbers read from the run stores.

* :mod:`latentune.reporting.metrics`: evaluations to beat a target, best-so-far curve, stable
  share, falls, RMS velocity error, the paper's packaged numbers.
* :mod:`latentune.reporting.run_report`: one run directory (``comparison_table``,
  ``write_summary``, ``make_report``).
* :mod:`latentune.reporting.paper_report`: a ``latentune paper`` directory
  (``write_paper_report``).
* :mod:`latentune.reporting.plots`: the figures (matplotlib, imported on first use).
"""
from __future__ import annotations

from latentune.reporting.metrics import (best_so_far, evals_to_beat, fall_count, paper_results,
                                         paper_row, phase_stats, rms_velocity_error,
                                         stable_count, stable_share)
from latentune.reporting.paper_report import write_paper_report
from latentune.reporting.run_report import comparison_table, make_report, write_summary

__all__ = ["evals_to_beat", "best_so_far", "stable_count", "stable_share", "fall_count",
           "rms_velocity_error", "phase_stats", "paper_results", "paper_row",
           "comparison_table", "write_summary", "make_report", "write_paper_report"]
