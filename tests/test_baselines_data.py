"""What docs/results.md says of the baselines' data, checked on the data kept: the grid's own runs
in docs/data/baselines and the deciding study's runs it reuses (``REUSED``). Each is its trial of
examples/sweep_baselines.toml (the settings `sweep` would resume it with), keeps what the held-out
protocol needs, the grid's own runs were made on one kind of CPU (the plan's rule), a run that took
over a first task repeats it byte for byte, a whole run repeats the first task an earlier run on
that CPU played (``SAME_FIRST_TASK``), and the baselines' status counts the runs kept."""
from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from lifelong_evo.commands.cli import build_parser
from lifelong_evo.commands.grid import build_grid
from lifelong_evo.rundir import RunDir
from tests.run_data import assert_keeps_what_held_out_scoring_needs, first_task_rows

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "docs/data"
SEEDS = (42, 13, 17, 24, 31)
REUSED = {**{f"sep-cmaes-reg0-seed{s}": DATA / f"study/families/reg0-seed{s}" for s in SEEDS},
          **{f"sep-cmaes-reg100-importancel2-seed{s}": DATA / f"study/families/reg100-seed{s}" for s in SEEDS},
          **{f"neat-reg11-seed{s}": DATA / f"study/paper-claim/reg11-seed{s}" for s in (13, 24)}}
"""The grid's trials whose runs are the deciding study's (docs/results.md, the baselines plan's
additions of 2026-11-28 and 2026-11-29): trial -> the study run kept in docs/data/study."""
SAME_FIRST_TASK = {f"neat-reg0-seed{s}": DATA / f"study/ms-lambda/seed{s}" for s in (42, 17, 31)}
"""Grid runs that play their first task themselves, and an earlier run on the same kind of CPU
(part 2's lambda = 5 runs of those seeds, whole runs on the Intel VM at the study's commit) played
the same first task: the regulariser acts only after it, so the two must agree byte for byte."""
GRID_CPU = {"cpu": "Intel(R) Xeon(R) Processor (family 6, model 167)", "vector_isa": "AVX512"}
"""The kind of CPU the grid runs on (docs/results.md, the baselines' status)."""
OWN = sorted(path for path in (DATA / "baselines").glob("*") if (path / "metrics.csv").is_file())
KEPT = {**{run.name: run for run in OWN}, **REUSED}


def _trials() -> dict:
    args = build_parser().parse_args(["sweep", "--config", str(ROOT / "examples/sweep_baselines.toml")])
    return {trial.name: trial for trial in build_grid(args).trials}


TRIALS = _trials()


def test_the_grid_and_the_reused_runs_are_the_plans():
    assert len(TRIALS) == 50 and REUSED.keys() <= TRIALS.keys()
    assert all((run / "metrics.csv").is_file() for run in REUSED.values())
    assert {run.name for run in OWN} <= TRIALS.keys() - REUSED.keys()


@pytest.mark.parametrize("name", sorted(KEPT), ids=str)
def test_a_kept_run_is_its_trial_and_keeps_its_controllers(name):
    run = KEPT[name]
    assert RunDir(run).setting_differences(TRIALS[name].config.to_dict()) == []
    assert_keeps_what_held_out_scoring_needs(run)


@pytest.mark.parametrize("run", OWN, ids=lambda path: path.name)
def test_the_grids_own_runs_ran_on_one_kind_of_cpu(run):
    machines = json.loads((run / "summary.json").read_text())["machines"]
    assert machines and all({key: m[key] for key in GRID_CPU} == GRID_CPU for m in machines)


@pytest.mark.parametrize("run", [run for run in OWN if json.loads((run / "summary.json").read_text())
                                 .get("first_task_from")], ids=lambda path: path.name)
def test_a_run_that_took_over_a_first_task_repeats_it(run):
    source = _kept(Path(json.loads((run / "summary.json").read_text())["first_task_from"]))
    if source is None:
        pytest.skip("the run it started from is not kept")
    assert first_task_rows(run) == first_task_rows(source)


@pytest.mark.parametrize("run", [run for run in OWN if run.name in SAME_FIRST_TASK], ids=lambda path: path.name)
def test_a_whole_run_repeats_the_first_task_an_earlier_run_on_its_cpu_played(run):
    assert not json.loads((run / "summary.json").read_text()).get("first_task_from")
    assert first_task_rows(run) == first_task_rows(SAME_FIRST_TASK[run.name])


def _kept(started_from: Path) -> Path | None:
    """Where the run a grid run took its first task from is kept: a trial of the grid's folder
    (``baselines``) by its trial name, a deciding-study run (``study-<part>``) in docs/data/study."""
    if started_from.parent.name == "baselines":
        return KEPT.get(started_from.name)
    study = DATA / "study" / started_from.parent.name.removeprefix("study-") / started_from.name
    return study if study.is_dir() else None


def test_the_status_counts_the_runs_kept():
    text = (ROOT / "docs/results.md").read_text()
    (finished,) = re.findall(r"Baselines:\s+(\d+)\s+of\s+38\s+runs\s+of\s+the\s+grid's\s+own", text)
    assert int(finished) == len(OWN)
