"""The paper's tasks give the numbers they gave before tasks became data (issue #61), byte for
byte: a NEAT run (neat-python 0.92's genetics, the default) and a sep-CMA-ES run at a fixed seed
on red-green-red write the metrics.csv, species.csv and controllers stored in
tests/data/paper-tasks/, which the code before the change wrote (that folder's README says how).

The arena's arithmetic is portable (envs/numerics.py), so the stored bytes hold on any x86-64
CPU; a difference means the step, a task's defaults or the loop computes something else."""
from __future__ import annotations

from pathlib import Path

import pytest

from lifelong_evo.commands.cli import main

STORED = Path(__file__).resolve().parent / "data" / "paper-tasks"
FLAGS = ["--preset", "smoke", "--generations", "3", "--env", "duration=60", "--seed", "42",
         "--schedule", "red-green-red", "--no-record", "--quiet"]
"""The runs' shared settings: the smoke preset (eager, one evaluation thread), cut to seconds."""
RUNS = {"neat-reg11": ["--algo", "neat", "--reg", "11"],
        "sep-cmaes-reg1": ["--algo", "sep-cmaes", "--reg", "1"]}
"""Stored run -> its own flags."""


def compared_files(run: Path) -> list[str]:
    """The files of a run directory the test compares, relative to it: metrics.csv, species.csv
    (NEAT's) and every controller."""
    names = [name for name in ("metrics.csv", "species.csv") if (run / name).exists()]
    return names + sorted(f"controllers/{path.name}" for path in (run / "controllers").glob("*.json"))


@pytest.mark.parametrize("name", list(RUNS))
def test_paper_tasks_give_the_stored_bytes(name, tmp_path):
    assert main([*FLAGS, *RUNS[name], "--out", str(tmp_path), "--name", name]) == 0
    stored, fresh = STORED / name, tmp_path / name
    assert compared_files(fresh) == compared_files(stored), "the run wrote other files than the stored one"
    assert len(compared_files(stored)) >= 6
    for relative in compared_files(stored):
        assert (fresh / relative).read_bytes() == (stored / relative).read_bytes(), \
            f"{name}/{relative} differs from the stored bytes"
