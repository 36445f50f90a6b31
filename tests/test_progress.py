"""Following a run: the progress display's modes, and what a run prints when its output goes to
files (nohup, SLURM, Ray) rather than a terminal."""
from __future__ import annotations

import io
import os
import subprocess
import sys
from pathlib import Path

import pytest

from lifelong_evo.progress import Progress, choose_mode

ROOT = Path(__file__).resolve().parents[1]


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def _feed(progress: Progress, per_task: int = 3, tasks=("red", "green", "red")) -> None:
    """Generations of a red-green-red run: best 0.5 per generation, retention of red in green."""
    generation = 0
    for number, task in enumerate(tasks, start=1):
        for in_task in range(per_task):
            retention = {"red": 2.25} if task == "green" and in_task == 1 else {}
            progress.update(generation, task, number, len(tasks), 0.5 * (generation + 1), retention,
                            task_end=in_task == per_task - 1)
            generation += 1
    progress.close()


def test_default_mode_follows_the_stream():
    assert choose_mode(None, Terminal()) == "bar"
    assert choose_mode(None, io.StringIO()) == "lines"
    assert choose_mode("off", Terminal()) == "off"
    with pytest.raises(ValueError):
        choose_mode("dots", io.StringIO())


def test_lines_at_the_start_at_task_ends_and_every_interval():
    stream = io.StringIO()
    _feed(Progress(9, stream=stream, interval_s=3600))
    lines = stream.getvalue().splitlines()
    assert "\r" not in stream.getvalue()
    # generation 1, then the end of each task; nothing in between within the interval
    assert [line.split("gen ")[1].split()[0] for line in lines] == ["1/9", "3/9", "6/9", "9/9"]
    assert lines[0].startswith("task 1/3 red") and "best 0.50" in lines[0]
    assert lines[2].startswith("task 2/3 green") and "ret red 2.25" in lines[2]  # the latest retention
    assert "ret" not in lines[3], "retention is of the tasks before the current one"
    every = io.StringIO()
    _feed(Progress(9, stream=every, interval_s=0))
    assert len(every.getvalue().splitlines()) == 9


def test_a_resumed_run_counts_from_its_checkpoint():
    stream = io.StringIO()
    progress = Progress(9, done_generations=6, stream=stream, interval_s=3600)
    progress.update(6, "red", 3, 3, 1.0, {})
    assert "gen 7/9" in stream.getvalue() and " 78%" in stream.getvalue()


def test_bar_on_a_terminal_and_off():
    terminal = Terminal()
    _feed(Progress(9, stream=terminal))
    assert "\r" in terminal.getvalue() and "9/9" in terminal.getvalue() and "task 3/3 red" in terminal.getvalue()
    silent = Terminal()
    _feed(Progress(9, mode="off", stream=silent))
    assert silent.getvalue() == ""


def test_a_run_writing_to_files_shows_where_it_writes_and_that_it_is_alive(tmp_path):
    """As under nohup or SLURM: stdout and stderr are files. The run directory comes first, then
    progress lines (no carriage returns), then the summary with a wall time in seconds and the machine."""
    out, err = tmp_path / "out.log", tmp_path / "err.log"
    with open(out, "w") as stdout, open(err, "w") as stderr:
        subprocess.run([sys.executable, "-m", "lifelong_evo", "--algo", "neat", "--preset", "smoke",
                        "--generations", "2", "--env", "duration=30", "--no-record", "--out", str(tmp_path),
                        "--name", "logged"], stdout=stdout, stderr=stderr, check=True, cwd=ROOT,
                       env={**os.environ, "PYTHONPATH": str(ROOT)})
    printed = out.read_text().splitlines()
    assert printed[0] == f"run directory: {tmp_path / 'logged'}"
    assert printed[-2].startswith("wall time: ") and printed[-2].endswith(" s")
    assert printed[-1].startswith("machine: ") and printed[-1].endswith(" CPUs")
    progress = [line for line in err.read_text().splitlines() if line.startswith("task ")]
    assert "\r" not in err.read_text()
    assert [line.split("gen ")[1].split()[0] for line in progress] == ["1/6", "2/6", "4/6", "6/6"]


def test_the_run_end_table_keeps_its_columns_under_a_long_task_name():
    """The table a run prints at its end: a task name longer than the column's header widens the
    column, so every figure ends where its header ends."""
    from lifelong_evo.analysis.report import summary_table

    summary = {"phases": ["red", "red-nest-bottom", "red"], "current": [1.0, 22.5, 3.0], "current_top": [1.0, 2.0, 3.0],
               "forgetting": [{"at_end_of": 1, "task": "red", "R_pop": 1.5, "F_pop": -0.5, "R_top": 0.0, "F_top": 1.0},
                              {"at_end_of": 2, "task": "red-nest-bottom", "R_pop": 10.5, "F_pop": 12.0, "R_top": 0.0,
                               "F_top": -0.5}],
               "ACC_pop": 1.0, "BWT_pop": -10.25, "FWT_pop": 0.0, "ACC_top": 1.0, "BWT_top": 0.0, "FWT_top": 0.0,
               "wall_time_s": 1.0}
    blocks = [block.splitlines() for block in summary_table(summary).split("\n\n")[:3]]
    for header, *rows in blocks:
        for title in header.split("  "):
            title = title.strip()
            if title and title not in ("task", "phase", "at end of"):  # figures, right-aligned under their title
                end = header.index(title) + len(title)
                assert all(row[end - 1] != " " and (len(row) == end or row[end] == " ") for row in rows), (title, rows)
    assert blocks[0][2].split()[:3] == ["1", "red-nest-bottom", "22.50"]
