"""What docs/studies/deciding-study.md says of the deciding study's data, checked on the data kept in
docs/data/study: each run's numbers repeat the earlier run of its configuration and seed byte for
byte where one exists (the reproducibility check of its plan), apart from the cells
docs/studies/deciding-study.md reports as not repeated (``DEVIATIONS``), the runs it reports as made on another
kind of CPU (``ANOTHER_CPU``), and the retention cells the earlier run
left empty (the stability gap's window, which the study's runs have and the earlier ones had
not, scores earlier tasks in every generation just after a switch), and each run keeps what the
held-out protocol needs (its controllers and its held-out block)."""
from __future__ import annotations

import csv
import json
import re
from pathlib import Path

import pytest

from tests.run_data import assert_keeps_what_held_out_scoring_needs, first_task_rows

DATA = Path(__file__).resolve().parents[1] / "docs/data"
PAGE = DATA.parent / "studies/deciding-study.md"
EARLIER = {"paper-claim": (DATA / "paper-genetics", {}),
           "families": (DATA / "families", {"reg0-": "sep-cmaes-reg0-", "reg100-": "sep-cmaes-reg100-importancel2-"})}
"""Each part of the study -> the earlier study whose runs it repeats, and how a trial's name there
begins where the two name the same configuration differently."""
DEVIATIONS: dict[str, dict[int, dict[str, tuple[str, str]]]] = {
    # docs/studies/deciding-study.md, "Lambda 11 on seed 31 does not repeat its earlier run in one generation"
    "paper-claim/reg11-seed31": {521: {"mean": ("5.53833332096537", "5.537333323508501"),
                                       "std": ("5.244873408500771", "5.243879552807582"),
                                       "reg_mean": ("-15.266338947316012", "-15.26733894477288"),
                                       "reg_std": ("7.005449016845879", "7.00590763634848")}},
}
"""The cells in which a study run does not repeat its earlier run, reported in docs/studies/deciding-study.md
(the deciding study's status): run -> generation -> column -> (this run's value, the earlier
run's). A run listed here must differ in exactly these cells; any other run, in none."""
ANOTHER_CPU: dict[str, tuple[str, str]] = {
    # docs/studies/deciding-study.md, "Lambda 11 on seeds 13 and 24, run on the Intel AVX-512 VM, differ ... from generation 0"
    "paper-claim/reg11-seed13": ("0.06466666693488757", "0.06500000024835269"),
    "paper-claim/reg11-seed24": ("-0.025333333363135657", "-0.025333333065112432"),
    # docs/studies/deciding-study.md, "Part 4's reproducibility check"
    "families/reg0-seed42": ("0.01229235997726751", "0.011295682196799307"),
    "families/reg0-seed13": ("0.05681063195201646", "0.05647840600869188"),
    "families/reg100-seed13": ("0.05681063195201646", "0.05647840600869188"),
    "families/reg0-seed17": ("-0.03554817360897001", "-0.035880399478036305"),
    "families/reg100-seed17": ("-0.03554817360897001", "-0.035880399478036305"),
    "families/reg0-seed24": ("-0.05847176117358414", "-0.059136212985975004"),
    "families/reg100-seed24": ("-0.05847176117358414", "-0.059136212985975004"),
    "families/reg0-seed31": ("0.0498338875134918", "0.04916943518129298"),
    "families/reg100-seed31": ("0.0498338875134918", "0.04916943518129298"),
    "families/reg100-seed42": ("0.01229235997726751", "0.011295682196799307"),
}
"""Study runs made on another kind of CPU than their earlier run (an Intel VM against AMD ones),
which part from it at generation 0, reported in docs/studies/deciding-study.md: run -> generation 0's mean (this
run's, the earlier run's). Such a run is checked to differ from its first generation on."""
RUNS = sorted(path for path in (DATA / "study").glob("*/*") if (path / "metrics.csv").is_file())


def test_the_study_has_data():
    assert RUNS, "docs/data/study holds no run"


@pytest.mark.parametrize("run", RUNS, ids=lambda path: f"{path.parent.name}/{path.name}")
def test_a_study_run_repeats_its_earlier_run_and_keeps_its_controllers(run):
    earlier = _earlier_run(run)
    name = f"{run.parent.name}/{run.name}"
    if earlier is not None:
        cells = _differing_cells(run / "metrics.csv", earlier / "metrics.csv")
        if name in ANOTHER_CPU:
            assert 0 in cells and cells[0]["mean"] == ANOTHER_CPU[name]
        else:
            assert cells == DEVIATIONS.get(name, {})
    assert_keeps_what_held_out_scoring_needs(run)


def test_the_status_counts_the_runs_kept():
    """docs/studies/deciding-study.md's status of each part and the reproducibility checks of parts 1 and 4 are
    counted from the data: the runs kept, and those of them with an earlier run, passed where they
    differ in no cell."""
    text = PAGE.read_text()
    for part, folder, planned in [(1, "paper-claim", 30), (2, "ms-lambda", 5), (3, "neat-lambda-grid", 8),
                                  (4, "families", 30), (5, "see-other-agents", 10)]:
        (finished,) = re.findall(rf"Part {part}:\s+(\d+)\s+of\s+{planned}\b", text)
        assert int(finished) == sum(run.parent.name == folder for run in RUNS), part
    not_repeated = DEVIATIONS.keys() | ANOTHER_CPU.keys()
    for sentence, folder in [("The reproducibility check", "paper-claim"), ("Part 4's reproducibility check", "families")]:
        repeated = [run for run in RUNS if run.parent.name == folder and _earlier_run(run) is not None]
        passed = len(repeated) - sum(f"{folder}/{run.name}" in not_repeated for run in repeated)
        assert not repeated or re.search(rf"{sentence}:\s+{passed}\s+of\s+{len(repeated)}\s+passed", text), folder


@pytest.mark.parametrize("run", [run for run in RUNS if json.loads((run / "summary.json").read_text())
                                 .get("first_task_from")], ids=lambda path: f"{path.parent.name}/{path.name}")
def test_a_run_that_took_over_a_first_task_repeats_it(run):
    """A study run started from another kept run's first task (``sweep --share-first-task``) has
    that run's rows up to the task's end, byte for byte."""
    started_from = Path(json.loads((run / "summary.json").read_text())["first_task_from"])
    # the sweep's folder is study-<part>, kept as docs/data/study/<part>
    source = DATA / "study" / started_from.parent.name.removeprefix("study-") / started_from.name
    if not (source / "metrics.csv").is_file():
        pytest.skip(f"the run it started from, {started_from}, is not kept")
    assert first_task_rows(run) == first_task_rows(source)


def _earlier_run(run: Path) -> Path | None:
    """The earlier run of ``run``'s configuration and seed, where its part repeats one."""
    if run.parent.name not in EARLIER:
        return None
    folder, renames = EARLIER[run.parent.name]
    name = next((new + run.name[len(old):] for old, new in renames.items() if run.name.startswith(old)), run.name)
    return folder / name if (folder / name).is_dir() else None


def _differing_cells(path, earlier) -> dict[int, dict[str, tuple[str, str]]]:
    """generation -> column -> (value in ``path``, value in ``earlier``) where the two metrics.csv
    files differ, except retention cells that ``earlier`` left empty; the same rows and columns
    are required."""
    readers = [csv.DictReader(open(file, newline="")) for file in (path, earlier)]
    assert readers[0].fieldnames == readers[1].fieldnames
    rows, earlier_rows = (list(reader) for reader in readers)
    assert [row["generation"] for row in rows] == [row["generation"] for row in earlier_rows]
    cells = {}
    for row, earlier_row in zip(rows, earlier_rows):
        differing = {key: (row[key], earlier_row[key]) for key in row if row[key] != earlier_row[key]
                     and not (key.startswith("retention_") and earlier_row[key] == "")}
        if differing:
            cells[int(row["generation"])] = differing
    return cells


def test_only_the_listed_cells_are_let_through(tmp_path):
    earlier = DATA / "paper-genetics/reg0-seed42/metrics.csv"

    def earlier_mean(generation: int) -> str:
        return next(row["mean"] for row in csv.DictReader(open(earlier)) if row["generation"] == str(generation))

    assert _differing_cells(earlier, earlier) == {}
    lines = earlier.read_text().splitlines(keepends=True)
    cells = lines[5].split(",")  # generation 4
    cells[5] = "1.5"  # its mean
    lines[5] = ",".join(cells)
    changed = tmp_path / "metrics.csv"
    changed.write_text("".join(lines))
    assert _differing_cells(changed, earlier) == {4: {"mean": ("1.5", earlier_mean(4))}}
    # generation 4 has no retention cell in the earlier run: one filled in is let through
    retention = lines[0].split(",").index("retention_pop_red")
    cells[retention] = "3.5"
    lines[5] = ",".join(cells)
    changed.write_text("".join(lines))
    assert _differing_cells(changed, earlier) == {4: {"mean": ("1.5", earlier_mean(4))}}
    # a retention cell the earlier run has must repeat
    lines = earlier.read_text().splitlines(keepends=True)
    cells = lines[211].split(",")  # generation 210, a retention generation (green, scored on red)
    assert cells[retention] != ""
    cells[retention] = "3.5"
    lines[211] = ",".join(cells)
    changed.write_text("".join(lines))
    assert set(_differing_cells(changed, earlier)) == {210}


def _stays_the_red_reference(run: Path) -> bool:
    """Whether the run's top individual at the end of its second task is the first task's, gene
    for gene (the regulariser's reference, unchanged)."""
    first, second = (json.loads((run / "controllers" / name).read_text())["genome"]
                     for name in ("task0-red-top.json", "task1-green-top.json"))
    return first == second


def test_the_seeds_whose_top_individual_stays_the_red_reference():
    """Part 1's "How the seeds behave" (and docs/results.md's verdict) name the seeds on which the
    lambda = 11 top individual at the end of green is the unchanged red reference, and their share
    of the summed held-out red R_top gain, counted here from the controllers and summaries."""
    def red_retention(run: Path) -> float:
        (cell,) = [cell for cell in json.loads((run / "summary.json").read_text())["held_out"]["forgetting"]
                   if cell["at_end_of"] == 1 and cell["task"] == "red"]
        return cell["R_top"]
    part = DATA / "study" / "paper-claim"
    seeds = sorted(int(run.name.removeprefix("reg11-seed")) for run in part.glob("reg11-seed*"))
    gain = {seed: red_retention(part / f"reg11-seed{seed}") - red_retention(part / f"reg0-seed{seed}") for seed in seeds}
    reference = [seed for seed in seeds if _stays_the_red_reference(part / f"reg11-seed{seed}")]
    share = sum(gain[seed] for seed in reference) / sum(gain.values())
    text = " ".join(PAGE.read_text().split())
    kept, total = sum(gain[seed] for seed in reference), sum(gain.values())
    assert (f"On {len(reference)} seeds ({', '.join(map(str, reference))}) the lambda = 11 top individual "
            "at the end of green is the red reference itself") in text
    assert f"they give {round(share * 100)}% of the summed R_top gain ({kept:.2f} of {total:.2f})" in text
    verdict = " ".join((DATA.parent / "results.md").read_text().split())
    assert f"({', '.join(map(str, reference[:-1]))} and {reference[-1]})" in verdict
    assert f"about {round(share * 100)}% of the summed red-retention gain" in verdict
