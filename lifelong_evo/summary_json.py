"""summary.json: its schema, beside metrics.csv's (``metrics_csv.MetricsLayout``). Every key of
summary.json and of its ``held_out`` block that code writes, checks or reads is spelled here.

``SummaryLayout`` names them: what ``metrics.summarise`` (and ``metrics.held_out_summary``, and
``score``) write, what ``run_files.check_summary`` checks, and what ``runs``, ``analysis`` and
``sweep`` read. README.md (The run directory) and docs/metrics.md (Where each number goes) give
each key's meaning. Contract: summary.json is one JSON object; its ``phases`` are the first tasks
of config.json's schedule, one per ended phase; the figures are numbers or null.
"""
from __future__ import annotations

SUMMARY_FILE = "summary.json"
"""A run directory's summary of the paper's table values and the transfer metrics."""


class SummaryLayout:
    """The keys of summary.json (and of its ``held_out`` block, which repeats the figures' keys)."""

    PHASES = "phases"
    """The tasks of the ended phases, in order (the held-out block's: those its scores cover)."""
    WALL_TIME = "wall_time_s"
    """The run's wall time so far, in seconds (a first task taken over counts)."""
    MACHINES = "machines"
    """Where the generations ran (``provenance.machine``), each from the generation it began at."""
    NUMERICS = "numerics"
    """The arithmetic of the fitness (``RunConfig.numerics``)."""
    FIRST_TASK_FROM = "first_task_from"
    """The run whose first task this one took over (``--start-from``), where it did."""
    CURRENT = "current"
    """Per ended phase, the population's best on the phase's task (C)."""
    CURRENT_TOP = "current_top"
    """Per ended phase, the top individual's score on the phase's task (C_top)."""
    CENTRE_CURRENT = "centre_current"
    """ES: per ended phase, the centre's score on the phase's task."""
    FORGETTING = "forgetting"
    """One row per earlier task at each later task end: C, R and F of each level."""
    STABILITY_GAP = "stability_gap"
    """Per earlier task and switch, the lowest retention in the window after it."""
    HELD_OUT = "held_out"
    """The exported controllers' figures on the fixed held-out episodes (``metrics.held_out_summary``)."""
    EPISODES = "episodes"
    """The held-out block's episodes per task."""
    SCORES = "scores"
    """The held-out block's score of each exported controller per task."""
    ARCHIVE = "archive"
    """The held-out block of a run with a skill archive: each task's archived controller and its
    held-out score on that task."""
    ARCHIVE_MEAN = "archive_mean"
    """The mean of the archived controllers' held-out scores over their tasks."""
    LEVELS = ("pop", "top", "centre", "best_sample")
    """The controllers whose figures summary.json and its held-out block hold (each has some of them)."""
    TRANSFER = ("ACC", "BWT", "FWT")
    """The transfer metrics, one key per level each (``transfer``)."""
    PHASE_FIGURES = (CURRENT, CENTRE_CURRENT, *(f"current_{level}" for level in LEVELS))
    """The lists with a figure per ended phase (the held-out block's: ``current_<level>``)."""

    @staticmethod
    def matrix(level: str) -> str:
        """The key of a level's R matrix (``R_pop``, ``R_top``, ...)."""
        return f"R_{level}"

    @staticmethod
    def transfer(metric: str, level: str) -> str:
        """The key of a transfer metric of a level (``ACC_top``, ...)."""
        return f"{metric}_{level}"
