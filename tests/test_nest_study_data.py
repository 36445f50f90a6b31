"""What docs/studies/nest-relocation.md says of its data, checked on the runs kept in
docs/data/study-nest-relocation: each is its trial of examples/sweep_study_nest_relocation.toml
(the settings `sweep` would resume it with), keeps what the held-out protocol needs, ran under
the portable arithmetic (so the machine it names does not matter), and a regularised run that
took over its lambda-0 sibling's first task repeats it byte for byte."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from lifelong_evo.commands.cli import build_parser
from lifelong_evo.commands.grid import build_grid
from lifelong_evo.rundir import RunDir
from tests.run_data import assert_keeps_what_held_out_scoring_needs, first_task_rows

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "docs/data/study-nest-relocation"
KEPT = sorted(path for path in DATA.glob("*") if (path / "metrics.csv").is_file())


def _trials() -> dict:
    args = build_parser().parse_args(["sweep", "--config", str(ROOT / "examples/sweep_study_nest_relocation.toml")])
    return {trial.name: trial for trial in build_grid(args).trials}


TRIALS = _trials()


def test_every_trial_of_the_plan_is_kept():
    assert len(TRIALS) == 20 and {run.name for run in KEPT} == TRIALS.keys()


@pytest.mark.parametrize("run", KEPT, ids=lambda path: path.name)
def test_a_kept_run_is_its_trial_and_keeps_its_controllers(run):
    assert RunDir(run).setting_differences(TRIALS[run.name].config.to_dict()) == []
    assert json.loads((run / "config.json").read_text())["numerics"] == "portable"
    assert_keeps_what_held_out_scoring_needs(run)


@pytest.mark.parametrize("run", [run for run in KEPT if json.loads((run / "summary.json").read_text())
                                 .get("first_task_from")], ids=lambda path: path.name)
def test_a_run_that_took_over_a_first_task_repeats_it(run):
    source = DATA / Path(json.loads((run / "summary.json").read_text())["first_task_from"]).name
    assert source != run and (source / "metrics.csv").is_file()
    assert first_task_rows(run) == first_task_rows(source)
