"""What docs/studies/baselines.md says of the baselines' data, checked on the data kept: the grid's own runs
in docs/data/baselines and the deciding study's runs it reuses (``REUSED``). Each is its trial of
examples/sweep_baselines.toml (the settings `sweep` would resume it with), keeps what the held-out
protocol needs, the runs of one family and seed were made on the one kind of CPU the plan gives
that seed (``PLANNED_CPU``; ``PLANNED_CPU_OF_TRIAL`` for a run that shares no generation with
another), a run that took over a first task repeats it byte for byte, runs that
share a first task on one kind of CPU play it alike, taken over or each by itself, the
baselines' status counts the runs kept, and each family's verdict is its data's (and is drawn only
once the family's runs are complete)."""
from __future__ import annotations

import itertools
import json
import re
from pathlib import Path

import pytest

from lifelong_evo.commands.cli import build_parser
from lifelong_evo.commands.grid import build_grid
from lifelong_evo.analysis.comparison import comparison
from lifelong_evo.analysis.statistics import paired_difference
from lifelong_evo.config import RunConfig
from lifelong_evo.rundir import RunDir
from tests.run_data import assert_keeps_what_held_out_scoring_needs, first_task_rows

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "docs/data"
PAGE = ROOT / "docs/studies/baselines.md"
SEEDS = (42, 13, 17, 24, 31)
INTEL = {"cpu": "Intel(R) Xeon(R) Processor (family 6, model 167)", "vector_isa": "AVX512"}
AMD_ZEN4 = {"cpu": "AMD EPYC (family 25, model 17)", "vector_isa": "AVX512"}
SEP_CMAES_ON_AMD_ZEN4 = (42, 24)
"""sep-CMA-ES seeds whose first run of the grid started on the AMD Zen 4 kind: all five of their
runs are the grid's, and part 4's two stay the study's (the second addition of 2026-12-01)."""
PLANNED_CPU = {("neat", 17): AMD_ZEN4, ("neat", 31): AMD_ZEN4, ("neat", 24): AMD_ZEN4,
               **{("sep-cmaes", seed): AMD_ZEN4 for seed in SEP_CMAES_ON_AMD_ZEN4}}
"""The kind of CPU of each family and seed whose runs are not on the Intel VM (docs/studies/baselines.md, the
baselines plan's additions of 2026-12-01); every other family and seed, the reused study runs
included, is the Intel VM's."""
REUSED = {**{f"sep-cmaes-{row}-seed{s}": DATA / f"study/families/{study_row}-seed{s}"
             for row, study_row in (("reg0", "reg0"), ("reg100-importancel2", "reg100"))
             for s in SEEDS if s not in SEP_CMAES_ON_AMD_ZEN4},
          "neat-reg11-seed13": DATA / "study/paper-claim/reg11-seed13"}
"""The grid's trials whose runs are the deciding study's (docs/studies/baselines.md, the baselines plan's
additions of 2026-11-28, 2026-11-29 and 2026-12-01): trial -> the study run kept in docs/data/study."""
PLANNED_CPU_OF_TRIAL = {"neat-joint-seed13": AMD_ZEN4, "sep-cmaes-joint-seed42": INTEL}
"""Trials whose kind of CPU is not their family and seed's: allowed only for a run that shares no
generation with any other (the second addition of 2026-12-01, the addition of 2026-12-02)."""
EARLIER_ON_INTEL = [DATA / f"study/ms-lambda/seed{s}" for s in (42, 17, 31)]
"""Study runs that are no trial of the grid but share a first task with some: part 2's lambda = 5
runs of those seeds, whole runs on the Intel VM at the study's commit (the regulariser acts only
after the first task)."""
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


def _planned_cpu(run: Path) -> dict:
    if run.name in PLANNED_CPU_OF_TRIAL:
        return PLANNED_CPU_OF_TRIAL[run.name]
    config = json.loads((run / "config.json").read_text())
    return PLANNED_CPU.get((config["algo"], config["seed"]), INTEL)


def _cpus(run: Path) -> list[dict]:
    """The kind of CPU of every machine a grid run played on (summary.json's ``machines``)."""
    machines = json.loads((run / "summary.json").read_text())["machines"]
    return [{key: machine[key] for key in INTEL} for machine in machines]


@pytest.mark.parametrize("run", OWN, ids=lambda path: path.name)
def test_each_grid_run_ran_on_the_cpu_the_plan_gives_its_family_and_seed(run):
    cpus = _cpus(run)
    assert cpus and all(cpu == _planned_cpu(run) for cpu in cpus)


@pytest.mark.parametrize("name", sorted(PLANNED_CPU_OF_TRIAL))
def test_a_trial_on_a_kind_of_cpu_of_its_own_shares_its_first_task_with_no_other(name):
    mine = RunConfig.first_task_settings(TRIALS[name].config.to_dict())
    sharing = [other.name for other in TRIALS.values()
               if other.name != name and RunConfig.first_task_settings(other.config.to_dict()) == mine]
    assert sharing == []


def test_the_reused_study_runs_are_of_seeds_the_plan_keeps_on_the_intel_vm():
    assert all(_planned_cpu(run) == INTEL for run in REUSED.values())


@pytest.mark.parametrize("run", [run for run in OWN if json.loads((run / "summary.json").read_text())
                                 .get("first_task_from")], ids=lambda path: path.name)
def test_a_run_that_took_over_a_first_task_repeats_it(run):
    source = _kept(Path(json.loads((run / "summary.json").read_text())["first_task_from"]))
    if source is None:
        pytest.skip("the run it started from is not kept")
    assert first_task_rows(run) == first_task_rows(source)


def _cpu(run: Path) -> dict:
    """The one kind of CPU a run played on: a grid run's from its summary.json, the study's runs'
    (made before runs named their machine) the Intel VM's, as docs/studies/baselines.md records."""
    if run.parent != DATA / "baselines":
        return INTEL
    (cpu,) = {json.dumps(cpu, sort_keys=True) for cpu in _cpus(run)}
    return json.loads(cpu)


def _first_task_partners() -> list[tuple[Path, Path]]:
    """Every pair of kept runs (and earlier study runs) that share their first task, settings and
    kind of CPU alike: whether one took it over from the other or each played it itself."""
    runs = sorted({*KEPT.values(), *EARLIER_ON_INTEL})
    return [(a, b) for a, b in itertools.combinations(runs, 2) if _cpu(a) == _cpu(b)
            and not RunDir(a).first_task_differences(RunDir(b).read_config().to_dict())]


@pytest.mark.parametrize("a, b", _first_task_partners(), ids=lambda path: f"{path.parent.name}/{path.name}")
def test_runs_that_share_a_first_task_on_one_kind_of_cpu_play_it_alike(a, b):
    assert first_task_rows(a) == first_task_rows(b)


def _kept(started_from: Path) -> Path | None:
    """Where the run a grid run took its first task from is kept: a trial of the grid's folder
    (``baselines``) by its trial name, a deciding-study run (``study-<part>``) in docs/data/study."""
    if started_from.parent.name == "baselines":
        return KEPT.get(started_from.name)
    study = DATA / "study" / started_from.parent.name.removeprefix("study-") / started_from.name
    return study if study.is_dir() else None


def test_the_status_counts_the_runs_kept():
    text = PAGE.read_text()
    ((finished, planned),) = re.findall(r"Baselines:\s+(\d+)\s+of\s+(\d+)\s+runs\s+of\s+the\s+grid's\s+own", text)
    assert (int(finished), int(planned)) == (len(OWN), len(TRIALS) - len(REUSED))


VERDICTS = {"NEAT (0.92)": ("neat", "reg11"), "sep-CMA-ES": ("sep-cmaes", "reg100-importancel2")}
"""Per family, as its verdict paragraph names it (``**Verdict, <family>:**``): its trials' name
prefix and its regulariser's row (docs/studies/baselines.md, the verdict rule)."""


def _held_out_red_retention(row: str) -> dict[int, float]:
    """Seed -> held-out red ``R_top`` at the end of green, for the kept runs of one row of the
    grid (a trial's name without its seed)."""
    values = {}
    for name, run in KEPT.items():
        if name.rsplit("-seed", 1)[0] == row:
            (red_at_green,) = [cell for cell in json.loads((run / "summary.json").read_text())["held_out"]["forgetting"]
                               if cell["at_end_of"] == 1 and cell["task"] == "red"]
            values[int(name.rsplit("-seed", 1)[1])] = red_at_green["R_top"]
    return values


@pytest.mark.parametrize("family", sorted(VERDICTS))
def test_a_family_verdict_is_drawn_from_its_complete_data_by_the_rule(family):
    """The verdict rule (with its amendment of 2026-11-29): the position (regulariser - fine-tune) /
    (rehearsal - fine-tune) of the seed means of held-out red R_top, given only where rehearsal's
    paired 95% t-interval excludes zero, beside the exact sign-flip p; no verdict before every run
    of the family is kept."""
    prefix, regulariser_row = VERDICTS[family]
    text = PAGE.read_text()
    paragraphs = re.findall(rf"\*\*Verdict, {re.escape(family)}:\*\*(.*?)(?:\n\n|$)", text, re.S)
    if not {name for name in TRIALS if name.startswith(prefix + "-")} <= KEPT.keys():
        assert paragraphs == []
        return
    (paragraph,) = [" ".join(paragraph.split()) for paragraph in paragraphs]
    fine_tune, regulariser, rehearsal = (_held_out_red_retention(f"{prefix}-{row}")
                                         for row in ("reg0", regulariser_row, "rehearsal0.3"))
    assert len(fine_tune) == len(regulariser) == len(rehearsal) == len(SEEDS)
    by_rehearsal = paired_difference(rehearsal, fine_tune)
    assert f"sign-flip p = {by_rehearsal.p:.3f}" in paragraph
    if by_rehearsal.low > 0 or by_rehearsal.high < 0:
        position = paired_difference(regulariser, fine_tune).mean / by_rehearsal.mean
        assert f"position {position:.2f}" in paragraph and "not established" not in paragraph
    else:
        assert "the scale is not established" in paragraph and "position " not in paragraph


@pytest.mark.parametrize("family", sorted(VERDICTS))
def test_compare_places_the_regulariser_where_the_verdict_does(family):
    """``compare``'s section "Between fine-tuning and rehearsal" on the family's kept runs gives the
    position the verdict rule computes from the seed means (the test above)."""
    prefix, regulariser_row = VERDICTS[family]
    fine_tune, regulariser, rehearsal = (_held_out_red_retention(f"{prefix}-{row}")
                                         for row in ("reg0", regulariser_row, "rehearsal0.3"))
    expected = paired_difference(regulariser, fine_tune).mean / paired_difference(rehearsal, fine_tune).mean
    runs = [KEPT[name] for name in KEPT if name.rsplit("-seed", 1)[0] in
            (f"{prefix}-reg0", f"{prefix}-{regulariser_row}", f"{prefix}-rehearsal0.3")]
    (row,) = [r for r in comparison(runs).rows if r["statistic"] == "position" and r["episodes"] == "held-out"
              and r["metric"] == "R_top red at end of phase 1"]
    assert row["mean"] == pytest.approx(expected, rel=1e-12) and len(row["seeds"]) == len(SEEDS)
