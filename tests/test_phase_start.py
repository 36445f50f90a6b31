"""The current task's score in a phase's first generation (``metrics.phase_start_scores``) and
``compare``'s figures of it (``start_pop``, ``start_top``), on metrics.csv rows written by hand."""
from __future__ import annotations

import json
from pathlib import Path

from lifelong_evo.analysis.comparison import compare_table
from lifelong_evo.metrics import phase_start_scores

PHASES = ["red", "green", "red"]


def rows_of(best: list[list[float]], top: list[list[float]], own: dict[int, list[str]] | None = None
            ) -> list[dict[str, str]]:
    """metrics.csv rows: ``best[k]`` and ``top[k]`` per generation of phase k; ``own[k]``: the
    current task's own cells of a phase whose training mixes tasks (``retention_pop_<task>``,
    "" where a generation has none), as such runs write them."""
    rows, generation = [], 0
    for k, (bests, tops) in enumerate(zip(best, top)):
        for g, (b, t) in enumerate(zip(bests, tops)):
            row = {"task": PHASES[k], "task_index": str(k), "generation": str(generation),
                   "generation_in_task": str(g), "best": repr(b), "top": repr(t),
                   "retention_pop_red": "", "retention_pop_green": ""}
            if own and k in own:
                row[f"retention_pop_{PHASES[k]}"] = own[k][g]
            rows.append(row)
            generation += 1
    return rows


BEST = [[1.0, 2.0, 3.0], [5.0, 6.0, 7.0], [8.0, 9.0, 10.0]]
TOP = [[0.5, 1.5, 2.5], [4.0, 5.5, 6.5], [7.0, 8.5, 9.5]]


def test_a_phase_start_is_the_first_generations_score_of_each_later_phase():
    assert phase_start_scores(rows_of(BEST, TOP)) == {1: 5.0, 2: 8.0}
    assert phase_start_scores(rows_of(BEST, TOP), "top") == {1: 4.0, 2: 7.0}
    assert phase_start_scores(rows_of(BEST[:2], TOP[:2])) == {1: 5.0}  # a run that has not reached red's return
    # a phase that mixes tasks: its own cells, not the mixture's best; none where the first has none
    assert phase_start_scores(rows_of(BEST, TOP, own={2: ["6.0", "7.0", "7.5"]})) == {1: 5.0, 2: 6.0}
    assert phase_start_scores(rows_of(BEST, TOP, own={2: ["", "7.0", "7.5"]})) == {1: 5.0}


def write_run(root: Path, name: str, seed: int, top: list[list[float]], **settings: object) -> None:
    path = root / name
    path.mkdir(parents=True)
    config = {"algo": "neat", "reg": 0.0, "schedule": "red-green-red", "generations": 3, "seed": seed, **settings}
    (path / "config.json").write_text(json.dumps(config))
    summary = {"phases": PHASES, "wall_time_s": 60.0, "current": [c[-1] for c in BEST],
               "current_top": [c[-1] for c in top], "forgetting": []}
    (path / "summary.json").write_text(json.dumps(summary))
    rows = rows_of(BEST, top)
    (path / "metrics.csv").write_text("\n".join([",".join(rows[0])] + [",".join(r.values()) for r in rows]) + "\n")


def test_compare_sets_each_phase_start_against_fine_tuning(tmp_path):
    """The archive puts red's controller back when red returns: its top individual starts red's
    return 3 and 5 higher than fine-tuning's on seeds 1 and 2 (mean 4), the same elsewhere."""
    for seed, gain in ((1, 3.0), (2, 5.0)):
        write_run(tmp_path, f"fine-s{seed}", seed, TOP)
        write_run(tmp_path, f"archive-s{seed}", seed, [TOP[0], TOP[1], [TOP[2][0] + gain, 9.0, 9.5]], archive=True)
    rows, markdown = compare_table([tmp_path])
    means = {(r["configuration"], r["metric"]): r for r in rows if r["statistic"] == "mean"}
    archive, fine = "neat reg=0 red-green-red archive=True", "neat reg=0 red-green-red"
    assert means[(archive, "start_top phase 2 (red)")]["values"] == [10.0, 12.0]
    assert means[(fine, "start_top phase 2 (red)")]["episodes"] == "selection-time"
    assert means[(fine, "start_pop phase 1 (green)")]["values"] == [5.0, 5.0]
    assert means[(fine, "start_pop phase 1 (green)")]["episodes"] == "training"
    assert not [metric for _, metric in means if metric.startswith("start_") and "phase 0" in metric]
    assert "| start_top phase 2 (red) | selection-time | +4.00 [-8.71, +16.71] | 0.5 | +2.83 | 2 |" in markdown
    assert "| start_top phase 1 (green) | selection-time | +0.00 [+0.00, +0.00] |" in markdown
    mine = markdown[markdown.index(f"## {archive}\n"):]
    assert "| phase | start_pop (training) | start_top (selection-time) |" in mine
    assert "| phase 2 (red) | 8.00 [8.00, 8.00] | 11.00 [-1.71, 23.71] |" in mine
