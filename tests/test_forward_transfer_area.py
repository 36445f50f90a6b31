"""Forward transfer as the area between curves (Continual World, Wolczyk et al. 2021):
``metrics.forward_transfer_area`` and ``compare``'s pairing of each run with a from-scratch run of
its seed, on run directories written by hand."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from lifelong_evo.analysis.comparison import compare_table, scratch_partners
from lifelong_evo.metrics import forward_transfer_area
from lifelong_evo.runs import load_runs

PHASES = ["red", "green", "red"]


def metrics_rows(best: list[list[float]]) -> list[dict[str, str]]:
    """metrics.csv rows (as csv.DictReader yields them) with ``best[k]`` the best column of phase
    k; the mean column is half the best, so that the two tell apart."""
    rows, generation = [], 0
    for k, curve in enumerate(best):
        for in_task, value in enumerate(curve):
            rows.append({"task": PHASES[k], "task_index": str(k), "generation": str(generation),
                         "generation_in_task": str(in_task), "best": repr(value), "mean": repr(value / 2),
                         "top": repr(value)})
            generation += 1
    return rows


# seed 1: the run, its from-scratch partner
RUN_1 = [[1.0, 2.0, 3.0], [5.0, 6.0, 7.0], [8.0, 8.0, 9.0]]
SCRATCH_1 = [[1.0, 2.0, 3.0], [1.0, 2.0, 3.0], [2.0, 4.0, 6.0]]
# FT_1 = mean(4, 4, 4) = 4; FT_2 = mean(6, 4, 3) = 13/3; FT_area = (4 + 13/3) / 2 = 25/6
# seed 2
RUN_2 = [[1.0, 1.0, 1.0], [4.0, 4.0, 4.0], [5.0, 5.0, 5.0]]
SCRATCH_2 = [[1.0, 1.0, 1.0], [2.0, 3.0, 4.0], [5.0, 6.0, 7.0]]
# FT_1 = mean(2, 1, 0) = 1; FT_2 = mean(0, -1, -2) = -1; FT_area = 0
# the same settings at lambda 0: seed 1 against SCRATCH_1, seed 2 against SCRATCH_2
PLAIN_1 = [[1.0, 2.0, 3.0], [3.0, 3.0, 3.0], [4.0, 4.0, 4.0]]  # FT_1 = 1, FT_2 = 0, FT_area = 1/2
PLAIN_2 = [[1.0, 1.0, 1.0], [2.0, 3.0, 4.0], [6.0, 6.0, 6.0]]  # FT_1 = 0, FT_2 = 0, FT_area = 0


def test_the_area_of_each_phase_matches_a_hand_computation():
    areas = forward_transfer_area(metrics_rows(RUN_1), metrics_rows(SCRATCH_1), 3)
    assert areas == {1: 4.0, 2: pytest.approx(13 / 3)}
    assert forward_transfer_area(metrics_rows(RUN_2), metrics_rows(SCRATCH_2), 3) == {1: 1.0, 2: -1.0}
    # only the phases both have ended: the first task has no area (nothing came before it)
    assert forward_transfer_area(metrics_rows(RUN_1), metrics_rows(SCRATCH_1), 2) == {1: 4.0}
    assert forward_transfer_area(metrics_rows(RUN_1), metrics_rows(SCRATCH_1), 1) == {}


def make_run(root: Path, name: str, seed: int, best: list[list[float]], reg: float = 1.0, ended: int = 3,
             **settings: object) -> None:
    """A run directory: config.json (``settings`` added; ``from_scratch`` only where given, as in
    runs from before the setting), summary.json (``ended`` phases ended) and metrics.csv."""
    path = root / name
    path.mkdir(parents=True)
    config = {"algo": "neat", "reg": reg, "schedule": "red-green-red", "generations": 3, "seed": seed, **settings}
    (path / "config.json").write_text(json.dumps(config))
    summary = {"phases": PHASES[:ended], "wall_time_s": 60.0, "current": [c[-1] for c in best[:ended]],
               "current_top": [c[-1] for c in best[:ended]], "forgetting": []}
    (path / "summary.json").write_text(json.dumps(summary))
    rows = metrics_rows(best)
    lines = [",".join(rows[0])] + [",".join(row.values()) for row in rows]
    (path / "metrics.csv").write_text("\n".join(lines) + "\n")


@pytest.fixture
def runs(tmp_path) -> Path:
    make_run(tmp_path, "reg1-s1", 1, RUN_1)
    make_run(tmp_path, "reg1-s2", 2, RUN_2, from_scratch=False)
    make_run(tmp_path, "reg0-s1", 1, PLAIN_1, reg=0.0)
    make_run(tmp_path, "reg0-s2", 2, PLAIN_2, reg=0.0)
    # the baseline: lambda 0, learning each task afresh; it may differ in the rehearsal settings too
    make_run(tmp_path, "scratch-s1", 1, SCRATCH_1, reg=0.0, from_scratch=True, reference_every=0)
    make_run(tmp_path, "scratch-s2", 2, SCRATCH_2, reg=0.0, from_scratch=True, rehearsal=0.0, joint=False)
    # a seed with no from-scratch run, and another population with none at all
    make_run(tmp_path, "reg1-s3", 3, RUN_1)
    make_run(tmp_path, "pop50-s1", 1, RUN_1, population=50)
    return tmp_path


def test_runs_are_paired_with_the_from_scratch_run_of_their_seed(runs):
    partners = {path.name: [p.path.name for p in found] for path, found in scratch_partners(load_runs([runs])).items()}
    assert partners == {"reg1-s1": ["scratch-s1"], "reg1-s2": ["scratch-s2"], "reg0-s1": ["scratch-s1"],
                        "reg0-s2": ["scratch-s2"]}


def test_compare_reports_the_areas_over_seeds_and_against_the_baseline(runs):
    rows, markdown = compare_table([runs])
    means = {(r["configuration"], r["metric"]): r for r in rows if r["statistic"] == "mean"}
    # labels name what sets the configurations apart: the population of pop50-s1, from_scratch where it is on
    label, plain = (f"neat reg={reg} red-green-red population=300" for reg in (1, 0))
    green, red, area = (means[(label, m)] for m in ("FT_area phase 1 (green)", "FT_area phase 2 (red)", "FT_area"))
    assert all(m["episodes"] == "training" and m["seeds"] == [1, 2] for m in (green, red, area))  # not seed 3
    assert green["values"] == [4.0, 1.0] and green["mean"] == 2.5
    assert red["values"] == [pytest.approx(13 / 3), -1.0]
    assert area["values"] == [pytest.approx(25 / 6), 0.0]
    assert means[(plain, "FT_area")]["values"] == [0.5, 0.0]
    # no partner: no area, for the from-scratch runs themselves neither
    assert not [key for key in means if key[1].startswith("FT_area") and key[0] not in (label, plain)]
    # against lambda 0, paired by seed: 25/6 - 1/2 and 0 - 0
    (paired,) = [r for r in rows if r["statistic"] == "paired difference" and r["metric"] == "FT_area"]
    assert paired["values"] == (pytest.approx(11 / 3), 0.0) and paired["mean"] == pytest.approx(11 / 6)
    mine = markdown[markdown.index(f"## {label}"):]
    assert "| phase | FT_area (training) |" in mine and "| phase 1 (green) | 2.50 [" in mine
    assert "| mean over phases >= 1 | 2.08 [" in mine
    assert "| FT_area | training | +1.83 [" in markdown


def test_an_unfinished_run_has_the_areas_of_the_phases_both_have_ended(tmp_path):
    """Stopped in its third phase: no area of that phase, whose first generations alone would
    weigh the switch's early generations too much, and so no mean over the phases."""
    make_run(tmp_path, "run", 1, [*RUN_1[:2], RUN_1[2][:2]], ended=2)
    make_run(tmp_path, "scratch", 1, SCRATCH_1, reg=0.0, from_scratch=True)
    rows, _ = compare_table([tmp_path])
    found = {r["metric"]: r["values"] for r in rows if r["metric"].startswith("FT_area") and r["statistic"] == "mean"}
    assert found == {"FT_area phase 1 (green)": [4.0]}


def test_without_a_from_scratch_run_nothing_changes(tmp_path):
    make_run(tmp_path, "reg1-s1", 1, RUN_1)
    make_run(tmp_path, "reg0-s1", 1, PLAIN_1, reg=0.0)
    rows, markdown = compare_table([tmp_path])
    assert not [r for r in rows if "FT_area" in r["metric"]] and "FT_area" not in markdown
