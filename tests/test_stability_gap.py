"""The stability gap (De Lange et al. 2023): ``metrics.stability_gap`` on a metrics.csv written by
hand, its summary.json block, its outcomes in ``compare`` and its markers in ``plot``."""
from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from lifelong_evo.analysis import figures as plots
from lifelong_evo.analysis.comparison import compare_table
from lifelong_evo.analysis.statistics import t_interval
from lifelong_evo.analysis.tables import Estimate
from lifelong_evo.metrics import stability_gap, summarise
from lifelong_evo.metrics_csv import MetricsLayout, read_metrics

SCHEDULE = "red:4,green:4,red:4,purple:4"
PHASES = ["red", "green", "red", "purple"]
WINDOW = 3
"""generation_in_task 0, 1 and 2 of each phase: the task end (3) lies outside, and holds the
lowest retention of all, so a window one too long shows."""


def row(phase: int, in_task: int, best: float, top: float, **kept: tuple[float, float]) -> dict[str, object]:
    """A metrics.csv row; ``kept``: task -> (R_pop, R_top), every other retention cell empty."""
    cells: dict[str, object] = {"task": PHASES[phase], "task_index": phase, "generation": 4 * phase + in_task,
                                "generation_in_task": in_task, "best": best, "mean": best / 2, "top": top}
    for task, (pop, top_kept) in kept.items():
        cells.update({f"retention_pop_{task}": pop, f"retention_top_{task}": top_kept})
    return cells


ROWS = [
    # red: generation 0 and the task end score every task
    row(0, 0, 1.0, 1.0, green=(0.5, 0.5), purple=(0.3, 0.3)), row(0, 1, 4.0, 3.0), row(0, 2, 7.0, 6.0),
    row(0, 3, 10.0, 9.0, green=(1.0, 0.5), purple=(2.0, 1.5)),
    # green: red kept in the window, once not scored (empty), R_top tied at generations 4 and 6
    row(1, 0, 3.0, 3.0, red=(8.0, 7.0)), row(1, 1, 5.0, 4.0), row(1, 2, 8.0, 7.0, red=(6.0, 7.0)),
    row(1, 3, 20.0, 18.0, red=(2.0, 1.0), purple=(3.0, 2.5)),
    # red returns: green's gap, R_pop tied at generations 9 and 10
    row(2, 0, 9.0, 8.0, green=(15.0, 12.0)), row(2, 1, 10.0, 9.0, green=(14.0, 13.0)),
    row(2, 2, 11.0, 10.0, green=(14.0, 11.0)), row(2, 3, 12.0, 11.0, green=(8.0, 7.0), purple=(4.0, 3.5)),
    # purple: red (phase 2's own task) and green (scored at the end of phase 2) each miss a generation
    row(3, 0, 1.0, 1.0, red=(11.0, 10.0), green=(9.0, 8.0)), row(3, 1, 2.0, 2.0, green=(7.5, 6.0)),
    row(3, 2, 3.0, 3.0, red=(10.5, 10.5)), row(3, 3, 30.0, 28.0, red=(7.0, 6.0), green=(5.0, 4.0)),
]

EXPECTED = [
    # red after the switch to green: before = red's C and top at generation 3 (red was phase 0's task)
    {"after_switch_to": 1, "task": "red", "window": 2,
     "before_pop": 10.0, "min_pop": 6.0, "generation_pop": 6, "gap_pop": 4.0,
     "before_top": 9.0, "min_top": 7.0, "generation_top": 4, "gap_top": 2.0},
    # green when red returns (red itself is the current task, not an earlier one)
    {"after_switch_to": 2, "task": "green", "window": 3,
     "before_pop": 20.0, "min_pop": 14.0, "generation_pop": 9, "gap_pop": 6.0,
     "before_top": 18.0, "min_top": 11.0, "generation_top": 10, "gap_top": 7.0},
    # purple: red was phase 2's task (its C and top at generation 11) ...
    {"after_switch_to": 3, "task": "red", "window": 2,
     "before_pop": 12.0, "min_pop": 10.5, "generation_pop": 14, "gap_pop": 1.5,
     "before_top": 11.0, "min_top": 10.0, "generation_top": 12, "gap_top": 1.0},
    # ... green was not: its retention cells at generation 11 (not its C at the end of its own phase, 20)
    {"after_switch_to": 3, "task": "green", "window": 2,
     "before_pop": 8.0, "min_pop": 7.5, "generation_pop": 13, "gap_pop": 0.5,
     "before_top": 7.0, "min_top": 6.0, "generation_top": 13, "gap_top": 1.0},
]


def write_metrics(path: Path, rows: list[dict[str, object]], layout: MetricsLayout) -> list[dict[str, str]]:
    """``rows`` as a metrics.csv of ``layout``'s columns (missing cells empty); read back as the loop reads it."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as handle:
        writer = csv.DictWriter(handle, layout.columns, restval="", lineterminator="\n")
        writer.writeheader()
        writer.writerows({k: repr(v) if isinstance(v, float) else v for k, v in r.items()} for r in rows)
    return read_metrics(path)


LAYOUT = MetricsLayout(tasks=("red", "green", "purple"), species=False, centre=False)


@pytest.fixture
def rows(tmp_path) -> list[dict[str, str]]:
    return write_metrics(tmp_path / "metrics.csv", ROWS, LAYOUT)


def test_the_gap_of_each_earlier_task_at_each_switch_matches_a_hand_computation(rows):
    assert stability_gap(rows, PHASES, WINDOW) == EXPECTED


def test_the_window_and_the_switches_the_rows_reach(rows):
    assert stability_gap(rows, PHASES, 0) == []
    assert stability_gap(rows[:4], PHASES, WINDOW) == []  # green not reached: no switch yet
    # a run stopped after green's first generation: one switch, one generation of window
    assert stability_gap(rows[:5], PHASES, WINDOW) == [
        {"after_switch_to": 1, "task": "red", "window": 1, "before_pop": 10.0, "min_pop": 8.0, "generation_pop": 4,
         "gap_pop": 2.0, "before_top": 9.0, "min_top": 7.0, "generation_top": 4, "gap_top": 2.0}]
    # the whole phase as window takes in the task end, where red sank to 2 (top: 1)
    whole = stability_gap(rows, PHASES, 4)[0]
    assert (whole["window"], whole["min_pop"], whole["generation_pop"], whole["min_top"]) == (3, 2.0, 7, 1.0)
    # a window without any score of the task: no entry (here green after purple's generation 0 only, emptied)
    emptied = [dict(r, retention_pop_green="", retention_top_green="") if r["generation"] == "12" else r for r in rows]
    assert [(e["after_switch_to"], e["task"]) for e in stability_gap(emptied[:13], PHASES, WINDOW)] == [
        (1, "red"), (2, "green"), (3, "red")]


def test_an_es_centre_has_its_gap_too(tmp_path):
    layout = MetricsLayout(tasks=("red", "green"), species=False, centre=True)
    table = [{"task": "red", "task_index": 0, "generation": 0, "generation_in_task": 0, "best": 1.0, "top": 1.0,
              "centre": 0.5, "retention_pop_green": 0.1, "retention_top_green": 0.1, "retention_centre_green": 0.1},
             {"task": "red", "task_index": 0, "generation": 1, "generation_in_task": 1, "best": 6.0, "top": 6.0,
              "centre": 5.0, "retention_pop_green": 0.2, "retention_top_green": 0.2, "retention_centre_green": 0.2},
             {"task": "green", "task_index": 1, "generation": 2, "generation_in_task": 0, "best": 1.0, "top": 1.0,
              "centre": 1.0, "retention_pop_red": 5.5, "retention_top_red": 4.0, "retention_centre_red": 3.0},
             {"task": "green", "task_index": 1, "generation": 3, "generation_in_task": 1, "best": 2.0, "top": 2.0,
              "centre": 2.0, "retention_pop_red": 4.5, "retention_top_red": 5.0, "retention_centre_red": 4.0}]
    found = stability_gap(write_metrics(tmp_path / "metrics.csv", table, layout), ["red", "green"], 20)
    assert found == [{"after_switch_to": 1, "task": "red", "window": 2,
                      "before_pop": 6.0, "min_pop": 4.5, "generation_pop": 3, "gap_pop": 1.5,
                      "before_top": 6.0, "min_top": 4.0, "generation_top": 2, "gap_top": 2.0,
                      "before_centre": 5.0, "min_centre": 3.0, "generation_centre": 2, "gap_centre": 2.0}]


ENDS = [{"task": "red", "C": 10.0, "R_pop": {"red": 10.0, "green": 1.0}, "R_top": {"red": 9.0, "green": 0.5}},
        {"task": "green", "C": 20.0, "R_pop": {"red": 2.0, "green": 20.0}, "R_top": {"red": 1.0, "green": 18.0}}]
INITIAL = {"pop": {"red": 1.0, "green": 0.5}, "top": {"red": 1.0, "green": 0.5}}


def test_summary_json_holds_the_block_only_when_given():
    plain = summarise(["red", "green"], ENDS, INITIAL, 1.0, has_centre=False)
    assert "stability_gap" not in plain
    assert json.dumps(summarise(["red", "green"], ENDS, INITIAL, 1.0, False, stability_gap=None)) == json.dumps(plain)
    entries = EXPECTED[:1]
    with_gap = summarise(["red", "green"], ENDS, INITIAL, 1.0, False, stability_gap=entries)
    assert with_gap["stability_gap"] == entries
    assert {k: v for k, v in with_gap.items() if k != "stability_gap"} == plain
    assert summarise(["red", "green"], ENDS, INITIAL, 1.0, False, stability_gap=[])["stability_gap"] == []


def make_run(path: Path, seed: int, reg: float, gaps: list[dict] | None, rows: list[dict[str, object]] | None = None
             ) -> None:
    """A run directory: config.json, summary.json (with ``gaps`` as its block unless None) and,
    with ``rows``, metrics.csv."""
    path.mkdir(parents=True)
    config = {"algo": "neat", "reg": reg, "schedule": SCHEDULE, "generations": 4, "seed": seed}
    (path / "config.json").write_text(json.dumps(config))
    summary = {"phases": PHASES, "wall_time_s": 60.0, "current": [10.0, 20.0, 12.0, 30.0],
               "current_top": [9.0, 18.0, 11.0, 28.0], "forgetting": []}
    if gaps is not None:
        summary["stability_gap"] = gaps
    (path / "summary.json").write_text(json.dumps(summary))
    if rows is not None:
        write_metrics(path / "metrics.csv", rows, LAYOUT)


def shifted(entries: list[dict], by: float) -> list[dict]:
    return [{**e, "gap_pop": e["gap_pop"] + by, "gap_top": e["gap_top"] + 2 * by} for e in entries]


def test_compare_reports_each_gap_over_seeds_and_against_the_baseline(tmp_path):
    for seed, by in ((1, 0.0), (2, 1.0)):
        make_run(tmp_path / f"reg1-s{seed}", seed, 1.0, shifted(EXPECTED, by))
        make_run(tmp_path / f"reg0-s{seed}", seed, 0.0, shifted(EXPECTED, 3 * by + 1))
    rows, markdown = compare_table([tmp_path])
    means = {(r["configuration"], r["episodes"], r["metric"]): r for r in rows if r["statistic"] == "mean"}
    label = f"neat reg=1 {SCHEDULE}"
    top = means[(label, "selection-time", "gap_top red after switch to phase 1")]
    interval = t_interval([2.0, 4.0])
    assert (top["seeds"], top["values"], top["mean"]) == ([1, 2], [2.0, 4.0], 3.0)
    assert (top["ci_low"], top["ci_high"]) == (interval.low, interval.high)
    pop = means[(label, "training", "gap_pop green after switch to phase 3")]
    assert pop["values"] == [0.5, 1.5]
    assert ("training", "gap_pop red after switch to phase 3") in {(k[1], k[2]) for k in means}
    # the paired differences: gap_pop per seed (0.0 - 1.0, 1.0 - 4.0)
    paired = [r for r in rows if r["statistic"] == "paired difference"
              and r["metric"] == "gap_pop red after switch to phase 1"]
    assert len(paired) == 1 and paired[0]["values"] == (-1.0, -3.0) and paired[0]["mean"] == -2.0
    assert "| gap_pop red after switch to phase 1 | training | -2.00 [" in markdown
    # the configuration's own table: a row per earlier task and switch, a column per level
    assert "| earlier task after the switch | gap_pop (training) | gap_top (selection-time) |" in markdown
    mine = markdown[markdown.index(f"## {label}"):]
    assert f"| red after switch to phase 1 | {estimate([4.0, 5.0])} | {estimate([2.0, 4.0])} |" in mine


def estimate(values: list[float]) -> str:
    """A table cell: the mean over seeds and its t-interval."""
    return str(Estimate.of(values))


def test_runs_without_the_block_compare_as_before(tmp_path):
    for seed in (1, 2):
        make_run(tmp_path / "old" / f"s{seed}", seed, 0.0, None)
    rows, markdown = compare_table([tmp_path / "old"])
    assert not [r for r in rows if "gap" in r["metric"]]
    assert "gap" not in markdown and "Stability" not in markdown and "FT_area" not in markdown
    # one run with the block beside runs without: its cells rest on its seed alone
    make_run(tmp_path / "old" / "s3", 3, 0.0, EXPECTED)
    rows, _ = compare_table([tmp_path / "old"])
    gap = next(r for r in rows if r["metric"] == "gap_pop red after switch to phase 1")
    assert (gap["n"], gap["seeds"], gap["values"]) == (1, [3], [4.0])


def test_plot_marks_each_minimum_on_the_retention_figures(tmp_path, monkeypatch):
    make_run(tmp_path / "run", 1, 0.0, stability_gap(write_metrics(tmp_path / "m.csv", ROWS, LAYOUT), PHASES, WINDOW),
             ROWS)
    figures = {}
    monkeypatch.setattr(plots, "save", lambda fig, path: figures.setdefault(path.name, fig) and path)
    plots.plot_runs([tmp_path / "run"], tmp_path / "figures")
    for level in ("pop", "top"):
        ax = figures[f"neat-red-4-green-4-red-4-purple-4-reg0-retention-{level}.png"].axes[0]
        marked = [line for line in ax.get_lines() if line.get_marker() == plots.GAP_MARKER]
        found = sorted((float(line.get_xdata()[0]), float(line.get_ydata()[0]), line.get_color()) for line in marked)
        assert found == sorted((e[f"generation_{level}"], e[f"min_{level}"], plots.task_color(e["task"]))
                               for e in EXPECTED)
        labels = [t.get_text() for t in ax.get_legend().get_texts()]
        assert labels.count("stability gap: lowest retention after a switch") == 1
        # the switches are drawn: a line before the first generation of each phase after the first
        drifts = sorted(line.get_xdata()[0] for line in ax.get_lines() if line.get_linestyle() == "--"
                        and line.get_color() == "0.3")
        assert drifts == [3.5, 7.5, 11.5]


def test_plot_without_the_block_marks_nothing(tmp_path, monkeypatch):
    make_run(tmp_path / "run", 1, 0.0, None, ROWS)
    figures = {}
    monkeypatch.setattr(plots, "save", lambda fig, path: figures.setdefault(path.name, fig) and path)
    plots.plot_runs([tmp_path / "run"], tmp_path / "figures")
    for fig in figures.values():
        assert not [line for line in fig.axes[0].get_lines() if line.get_marker() == plots.GAP_MARKER]


def test_plot_writes_the_marked_figures(tmp_path):
    make_run(tmp_path / "run", 1, 0.0, EXPECTED, ROWS)
    written = plots.plot_runs([tmp_path / "run"], tmp_path / "figures")
    assert sorted(p.name for p in written) == ["neat-red-4-green-4-red-4-purple-4-reg0-retention-pop.png",
                                               "neat-red-4-green-4-red-4-purple-4-reg0-retention-top.png"]
    assert all(p.read_bytes().startswith(b"\x89PNG") for p in written)
