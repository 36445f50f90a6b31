"""Tasks as data (issue #61): ``[tasks.NAME]`` tables in a ``--tasks`` file or a ``--config`` file
define tasks that ``--schedule`` names; the named drift schedules; every bad task file is one
``error:`` line and exit status 2 before anything is written; config.json records every task's
definition and ``--resume`` refuses a run whose definitions changed."""
from __future__ import annotations

import csv
import json
import re
from pathlib import Path

import pytest

from envs import TASKS, Rewards
from lifelong_evo import loop
from lifelong_evo.commands.cli import build_parser, main
from lifelong_evo.commands.flags import resolve_run_config
from lifelong_evo.commands.grid import build_grid
from lifelong_evo.schedule import NAMED_SCHEDULES, parse_schedule

SOUTH = """
[tasks.red-south]
target = "red"
season = ["red", "blue"]
drop_zone = "bottom"
rewards = { pick_other = -2.5, deliver_other = -1 }
failed_robots = 1
motor_gain = 0.8
"""
"""A task of every drift field."""
TINY = ["--preset", "smoke", "--generations", "2", "--env", "duration=40", "--no-record", "--quiet"]


def task_file(tmp_path: Path, text: str | bytes, name: str = "tasks.toml") -> str:
    path = tmp_path / name
    path.write_bytes(text if isinstance(text, bytes) else text.encode())
    return str(path)


def configured(*argv: str):
    return resolve_run_config(build_parser().parse_args(["run", *argv, "--preset", "smoke"]))


def test_a_task_file_defines_tasks_the_schedule_names(tmp_path):
    config = configured("--tasks", task_file(tmp_path, SOUTH), "--schedule", "red:3,red-south:4,red:3")
    phases = config.phases()
    assert [(p.name, p.generations) for p in phases] == [("red", 3), ("red-south", 4), ("red", 3)]
    south = phases[1].task
    assert (south.target, south.season, south.drop_zone, south.failed_robots, south.motor_gain) == \
        (3, (3, 4), "bottom", 1, 0.8)
    assert south.rewards == Rewards(pick_target=1.0, pick_other=-2.5, deliver_target=2.0, deliver_other=-1.0)
    assert phases[0].task is TASKS["red"] or phases[0].task == TASKS["red"]
    blended = configured("--tasks", task_file(tmp_path, SOUTH), "--schedule", "red:2,red>red-south:3").phases()
    assert blended[1].source == TASKS["red"] and blended[1].task == south
    # a task the schedule leaves unused may have colours the run's arena (the schedule's) lacks
    dark = SOUTH + "[tasks.dark]\ntarget = 'black'\nseason = ['black', 'white']\n"
    assert configured("--tasks", task_file(tmp_path, dark), "--schedule", "red-south").env_config().colors == (3, 4)


def test_a_config_file_holds_task_tables_and_the_flag_wins(tmp_path):
    # with a byte-order mark, as some Windows editors save UTF-8 (tomllib alone refuses it)
    text = 'schedule = "red:2,red-south:2"\n' + SOUTH
    config_file = task_file(tmp_path, b"\xef\xbb\xbf" + text.encode(), "run.toml")
    assert configured("--config", config_file).phases()[1].task.drop_zone == "bottom"
    other = task_file(tmp_path, SOUTH.replace('"bottom"', '"left"'))
    assert configured("--config", config_file, "--tasks", other).phases()[1].task.drop_zone == "left"


def test_a_sweep_file_holds_task_tables_and_the_flag_adds_its_own(tmp_path, capsys):
    sweep = ('schedule = "red:2,red-south:2"\n[grid]\nseed = [1, 2]\n' + SOUTH
             + "[tasks.spare]\ntarget = 'green'\nseason = ['green', 'yellow']\n")
    argv = ["sweep", "--config", task_file(tmp_path, sweep, "sweep.toml"), "--preset", "smoke", "--out", str(tmp_path)]
    trials = build_grid(build_parser().parse_args(argv)).trials
    assert [trial.name for trial in trials] == ["seed1", "seed2"]
    assert all(trial.config.phases()[1].task.drop_zone == "bottom" and "spare" in trial.config.tasks for trial in trials)
    west_file = task_file(tmp_path, SOUTH.replace('"bottom"', '"left"'))
    west = build_grid(build_parser().parse_args([*argv, "--tasks", west_file]))
    assert west.trials[0].config.phases()[1].task.drop_zone == "left" and "spare" in west.trials[0].config.tasks
    for bad, message in (("tasks = 3\n", r"tasks in \S+ must be \[tasks.NAME\] tables"),
                         ("[grid]\nseed = [1, 2]\ntasks = [{}]\n", r"tasks in \[grid\] of \S+: every trial defines"),
                         ("[grid]\nvariants = [{ tasks = {} }]\n", r"tasks in \[grid\] variants of \S+: every trial")):
        assert main(["sweep", "--config", task_file(tmp_path, bad, "bad.toml"), "--out", str(tmp_path / "bad"),
                     "--dry-run"]) == 2
        err = capsys.readouterr().err
        assert re.search(f"^error: {message}", err) and err.count("\n") == 1, err
    assert not (tmp_path / "bad").exists()


def test_the_named_drift_schedules():
    relocation = parse_schedule("nest-relocation", 200)
    assert [p.task.drop_zone for p in relocation] == ["top", "bottom", "top"]
    assert all(p.task.target == TASKS["red"].target and p.generations == 200 for p in relocation)
    failure = parse_schedule("robot-failure", 200)
    assert [p.task.failed_robots for p in failure] == [0, 2, 0]
    assert relocation[0].task == failure[2].task == TASKS["red"]
    assert {"nest-relocation", "robot-failure"} <= set(NAMED_SCHEDULES)


def test_help_lists_the_drift_schedules_and_the_tasks_flag(capsys):
    assert main(["--help"]) == 0
    shown = "".join(capsys.readouterr().out.split())  # argparse wraps lines, at hyphens too
    assert "nest-relocation" in shown and "robot-failure" in shown and "--tasksFILE" in shown


# ------------------------------------------------------------------------------------- bad input
@pytest.fixture
def nothing_runs(monkeypatch):
    def run(*args, **kwargs):
        raise AssertionError("the run started although its configuration is bad")
    monkeypatch.setattr(loop, "run", run)


def refused(argv: list[str], out: Path, capsys) -> str:
    """``main(argv)`` exits 2 with one ``error:`` line, writing nothing under ``out``; the line."""
    code = main([*argv, *TINY, "--out", str(out)])
    captured = capsys.readouterr()
    assert code == 2, captured
    assert captured.out == "" and captured.err.startswith("error: ") and captured.err.count("\n") == 1, captured.err
    assert not out.exists(), "a refused run leaves no run directory"
    return captured.err


BAD_FILES = {
    "unknown key": (SOUTH + "colour = 'red'\n", r"task 'red-south': unknown key\(s\) \['colour'\]: valid ones are target"),
    "nest edge": (SOUTH.replace('"bottom"', '"north"'), "drop_zone 'north' is not an edge: choose one of top, bottom"),
    "too many failed": (SOUTH.replace("failed_robots = 1", "failed_robots = 5"),
                        "failed_robots=5, but at least one of the 5 robots must work: use 0 to 4"),
    "too many failed, unused": (SOUTH + "[tasks.spare]\ntarget = 'red'\nseason = ['red', 'blue']\nfailed_robots = 5\n",
                                "task 'spare': failed_robots=5, but at least one of the 5 robots must work"),
    "target outside season": (SOUTH.replace('season = ["red", "blue"]', 'season = ["blue"]'),
                              r"task 'red-south': target red is not in its season \[blue\]: add red to the season"),
    "negative failed": (SOUTH.replace("failed_robots = 1", "failed_robots = -1"), "failed_robots must be an integer >= 0"),
    "infinite reward": (SOUTH.replace("pick_other = -2.5", "pick_other = -inf"),
                        "task 'red-south': reward pick_other must be a number from -1e6 to 1e6"),
    "nan reward": (SOUTH.replace("deliver_other = -1", "deliver_other = nan"), "reward deliver_other must be a number"),
    # finite as Python floats, but none (or no sum of them) is in the step's float32
    "reward beyond float32": (SOUTH.replace("pick_other = -2.5", "pick_other = 1e39"), "reward pick_other must be a"),
    "rewards at float32's edge": (SOUTH.replace("pick_other = -2.5", "pick_target = 3e38, pick_other = -3e38"),
                                  "task 'red-south': reward pick_target must be a number from -1e6 to 1e6"),
    "401-digit reward": (SOUTH.replace("pick_other = -2.5", f"pick_other = {10 ** 400}"),
                         r"reward pick_other must be a number from -1e6 to 1e6 .*, got 1000.*\.\.\.0000000000$"),
    "motor gain 0 in float32": (SOUTH.replace("motor_gain = 0.8", "motor_gain = 1e-50"),
                                "task 'red-south': motor_gain must be a number from 1e-6 to 1"),
    "unknown reward": (SOUTH.replace("deliver_other", "deliver_late"), r"unknown reward\(s\) \['deliver_late'\]"),
    "motor gain zero": (SOUTH.replace("motor_gain = 0.8", "motor_gain = 0"), "motor_gain must be a number from 1e-6 to 1"),
    "motor gain above one": (SOUTH.replace("motor_gain = 0.8", "motor_gain = 1.5"), "motor_gain must be a number from"),
    "unknown colour": (SOUTH.replace('target = "red"', 'target = "pink"'), "target 'pink' is no colour: use one of red"),
    "no season": (SOUTH.replace('season = ["red", "blue"]', ""), "task 'red-south' needs season"),
    "built-in name": (SOUTH.replace("[tasks.red-south]", "[tasks.red]"),
                      "task 'red' is built in and cannot be defined again: give your task another name"),
    "built-in name in other case": (SOUTH.replace("[tasks.red-south]", "[tasks.Red]"),
                                    "task 'Red' differs from the built-in task 'red' only in case or in _ for -"),
    "built-in name with _": (SOUTH.replace("[tasks.red-south]", "[tasks.red_nest_bottom]"),
                             "task 'red_nest_bottom' differs from the built-in task 'red-nest-bottom'"),
    "names one run name": (SOUTH + SOUTH.replace("[tasks.red-south]", "[tasks.RED_south]"),
                           "tasks 'red-south' and 'RED_south' differ only in case or in _ for -.*rename one of them"),
    "other settings": ("seed = 3\n" + SOUTH, r"holds \['seed'\]: it may hold only \[tasks.NAME\] tables"),
    "rewards a word": (SOUTH.replace("rewards = { pick_other = -2.5, deliver_other = -1 }", 'rewards = "high"'),
                       r"task 'red-south': rewards must be a table of event values, e.g. rewards = \{ pick_other = -2 \}"),
    "tasks a value": ("tasks = 3\n", r"tasks in task file \S+ must be \[tasks.NAME\] tables, one per task: write e.g. "
                                     r"\[tasks.red-south\]"),
    "tasks an array": ("[[tasks]]\ntarget = 'red'\n", r"tasks in task file \S+ must be \[tasks.NAME\] tables"),
    "not TOML": ("[tasks.red-south\n", r"^error: task file \S+ is not valid TOML"),
    "not UTF-8": (b"[tasks.x]\ntarget = '\xff'\n", r"^error: task file \S+ is not UTF-8 text \(byte 20 cannot"),
    "no task": ("", "defines no task"),
}


@pytest.mark.parametrize("case", list(BAD_FILES))
def test_a_bad_task_file_is_one_line_before_anything_is_written(case, tmp_path, capsys, nothing_runs):
    text, message = BAD_FILES[case]
    line = refused(["--tasks", task_file(tmp_path, text), "--schedule", "red:2,red-south:2"], tmp_path / "runs", capsys)
    assert re.search(message, line), line


@pytest.mark.parametrize("argv, message", [
    (["--schedule", "red,red-south"], "unknown task 'red-south' in schedule 'red,red-south'.*define it in a "
                                      r"\[tasks.red-south\] table"),
    (["--schedule", "red>blue-north:3"], "unknown task 'blue-north'"),
    (["--tasks", "/nonexistent/tasks.toml"], "task file /nonexistent/tasks.toml does not exist"),
    # a built-in task cannot be edited: the fix is a larger swarm or a task of one's own
    (["--schedule", "robot-failure", "--env", "n_agents=2"], "task 'red-two-failed' is built in with 2 failed robots.*"
                                                             "raise n_agents to at least 3, or define a task of your own"),
])
def test_a_schedule_the_arena_cannot_run_is_refused(argv, message, tmp_path, capsys, nothing_runs):
    assert re.search(message, refused(argv, tmp_path / "runs", capsys))


def test_a_bad_task_in_a_config_file_is_refused_too(tmp_path, capsys, nothing_runs):
    config_file = task_file(tmp_path, 'schedule = "red-south"\n' + SOUTH.replace('"bottom"', '"up"'), "run.toml")
    assert "drop_zone 'up' is not an edge" in refused(["--config", config_file], tmp_path / "runs", capsys)
    config_file = task_file(tmp_path, 'tasks = 3\n', "run.toml")
    assert "tasks in the config file must be [tasks.NAME] tables" in refused(["--config", config_file], tmp_path / "runs",
                                                                             capsys)


# ------------------------------------------------------------------------- config.json, resume
def test_config_json_records_every_task_and_resume_refuses_changed_definitions(tmp_path, capsys):
    tasks = task_file(tmp_path, SOUTH)
    argv = [*TINY, "--algo", "neat", "--tasks", tasks, "--schedule", "red:2,red-south:2", "--out",
            str(tmp_path / "runs"), "--name", "south"]
    assert main(argv) == 0
    run = tmp_path / "runs" / "south"
    written = json.loads((run / "config.json").read_text())
    assert written["task_definitions"]["red-south"] == {
        "target": "red", "season": ["red", "blue"], "drop_zone": "bottom",
        "rewards": {"pick_target": 1.0, "pick_other": -2.5, "deliver_target": 2.0, "deliver_other": -1.0},
        "failed_robots": 1, "motor_gain": 0.8}
    assert written["task_definitions"]["red"]["drop_zone"] == "top"
    with open(run / "metrics.csv", newline="") as handle:
        assert {row["task"] for row in csv.DictReader(handle)} == {"red", "red-south"}
    capsys.readouterr()
    changed = task_file(tmp_path, SOUTH.replace("motor_gain = 0.8", "motor_gain = 0.7"), "changed.toml")
    assert main([*argv[:argv.index("--tasks")], "--tasks", changed, *argv[argv.index("--tasks") + 2:], "--resume"]) == 2
    line = capsys.readouterr().err
    assert line.startswith("error: ") and "task red-south: motor_gain 0.7 (stored: 0.8)" in line, line
    assert "pick_other" not in line, "the one field that differs is named, not the whole table"
    # a table the schedule never plays changes no number: the run resumes with its stored tables
    unused = task_file(tmp_path, SOUTH + '\n[tasks.green-west]\ntarget = "green"\nseason = ["green", "blue"]\n',
                       "unused.toml")
    assert main([*argv[:argv.index("--tasks")], "--tasks", unused, *argv[argv.index("--tasks") + 2:], "--resume"]) == 0
    assert json.loads((run / "config.json").read_text()) == written
    assert main([*argv, "--resume"]) == 0, "the same definitions resume"

