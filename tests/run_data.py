"""Checks shared by the tests of kept run data (docs/data): what a kept run must hold for the
held-out protocol, and the rows of its first task, as written, for the byte-for-byte checks."""
from __future__ import annotations

import json
from pathlib import Path

from lifelong_evo.config import parse_schedule


def phases(run: Path) -> list:
    """The schedule's phases of ``run``, from its config.json."""
    config = json.loads((run / "config.json").read_text())
    return parse_schedule(config["schedule"], config["generations"])


def assert_keeps_what_held_out_scoring_needs(run: Path) -> None:
    """summary.json covers every phase and has the held-out block (100 episodes), and every
    controller it scored is kept in controllers/."""
    summary = json.loads((run / "summary.json").read_text())
    assert len(summary["phases"]) == len(phases(run)) and summary["held_out"]["episodes"] == 100
    kept = {path.stem for path in (run / "controllers").glob("*.json")}
    assert summary["held_out"]["scores"] and set(summary["held_out"]["scores"]) <= kept


def first_task_rows(run: Path) -> list[str]:
    """metrics.csv's header and its rows of the schedule's first task, as written; checked to be
    as many rows as the task has generations."""
    rows = (run / "metrics.csv").read_text().splitlines()
    task_index = rows[0].split(",").index("task_index")
    first_task = [rows[0]] + [row for row in rows[1:] if row.split(",")[task_index] == "0"]
    assert len(first_task) - 1 == phases(run)[0].generations
    return first_task
