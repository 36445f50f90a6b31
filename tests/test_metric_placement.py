"""The metric code against numbers worked out by hand: the lifelong loop driven with made-up
fitness that says which task and which controller it belongs to (so a retention read from the
wrong task's row, or a top individual taken from the wrong controller, shows), and summary.json
and its held-out block for a four-phase schedule with a repeated task."""
from __future__ import annotations

import csv
import json

import pytest
import torch

from lifelong_evo import loop
from lifelong_evo.config import resolve
from lifelong_evo.metrics import held_out_summary, parse_controller_key, summarise
from lifelong_evo.rundir import RunDir

CODES = {"red": 1, "green": 2, "purple": 3}
"""Each task's fitness lies in [100 * code, 100 * code + 100): a value says which task it is of."""
STRIDES = {"red": 1, "green": 11, "purple": 13}
"""Each task ranks the controllers in its own order (p * stride mod P, a permutation for P = 20
and P = 21), so the best controller of one task is not the best of another."""
SCHEDULE = "red:3,green:3,red:2,purple:2"


def made_up(task: str, controller: int, generation: int, population: int) -> float:
    """What the test says controller ``controller`` scores on ``task`` in ``generation``."""
    rank = (controller * STRIDES[task] + generation) % population
    return float(torch.tensor(100.0 * CODES[task] + rank + generation / 1000, dtype=torch.float32))


def play_with_made_up_fitness(config, run_dir, monkeypatch) -> dict:
    """``loop.lifelong`` sent the made-up fitness of every controller on every task it asks for,
    the stability gap's own evaluations included."""
    steps = loop.lifelong(config, run_dir)
    generation = 0

    def made_up_evaluation(policy, env_config, tasks, *args, **kwargs):
        population = policy.population_size
        return torch.tensor([[made_up(task.name, p, generation, population) for p in range(population)]
                             for task in tasks])

    monkeypatch.setattr(loop, "evaluate", made_up_evaluation)
    try:
        evaluation = next(steps)
        while True:
            population = evaluation.policy.population_size
            fitness = torch.tensor([[made_up(task.name, p, generation, population) for p in range(population)]
                                    for task in evaluation.tasks])
            evaluation = steps.send(fitness)
            generation += 1
    except StopIteration as finished:
        return finished.value


@pytest.mark.parametrize("algo", ["neat", "sep-cmaes"])
def test_every_number_lands_where_its_definition_puts_it(tmp_path, algo, monkeypatch):
    config = resolve("smoke", None, {"algo": algo, "schedule": SCHEDULE, "record": False, "retention_every": 2,
                                     "gap_window": 2, "env": {"duration": 20}})
    run_dir = RunDir(tmp_path / algo)
    summary = play_with_made_up_fitness(config, run_dir, monkeypatch)
    rows = list(csv.DictReader(open(run_dir.metrics)))
    population = 21 if algo == "sep-cmaes" else 20
    centre = population - 1 if algo == "sep-cmaes" else None
    phases = ["red"] * 3 + ["green"] * 3 + ["red"] * 2 + ["purple"] * 2
    ends = {2: 0, 5: 1, 7: 2, 9: 3}  # generation -> phase it ends
    expected_ends = []
    for g, (row, task) in enumerate(zip(rows, phases)):
        # without a regulariser the top individual is the best on the current task
        top = max(range(population), key=lambda p: made_up(task, p, g, population))
        assert row["task"] == task and int(row["generation"]) == g
        assert float(row["best"]) == made_up(task, top, g, population) == float(row["top"])
        if centre is not None:
            assert float(row["centre"]) == made_up(task, centre, g, population)
        seen_before = {t for t in phases[:g] if t != task}
        starts = {0: 0, 3: 1, 6: 2, 8: 3}  # generation -> phase it starts
        in_window = any(start <= g < start + 2 and phase > 0 for start, phase in starts.items())
        measured = ([t for t in CODES if t != task] if g in ends or g == 0 else
                    sorted(seen_before) if g % 2 == 0 or in_window else [])
        for other in CODES:
            if other == task:
                continue
            cells = [row.get(f"retention_{level}_{other}", "") for level in ("pop", "top", "centre")]
            if other in seen_before and other in measured:
                assert float(cells[0]) == max(made_up(other, p, g, population) for p in range(population)), (g, other)
                assert float(cells[1]) == made_up(other, top, g, population), (g, other)
                if centre is not None:
                    assert float(cells[2]) == made_up(other, centre, g, population), (g, other)
            else:
                assert cells[:2] == ["", ""] or f"retention_pop_{other}" not in row, (g, other)
        if g in ends:
            expected_ends.append({
                "C": made_up(task, top, g, population),
                "pop": {t: max(made_up(t, p, g, population) for p in range(population)) for t in CODES},
                "top": {t: made_up(t, top, g, population) for t in CODES}})
    names = ["red", "green", "red", "purple"]
    assert summary["current"] == [end["C"] for end in expected_ends]
    assert summary["current_top"] == [end["top"][name] for end, name in zip(expected_ends, names)]
    assert summary["R_pop"] == [[end["pop"][name] for name in names] for end in expected_ends]
    assert summary["R_top"] == [[end["top"][name] for name in names] for end in expected_ends]
    # forgetting of green at the end of purple starts from green's phase (1), not the phase before (2: red)
    green = next(row for row in summary["forgetting"] if row["at_end_of"] == 3 and row["task"] == "green")
    assert green["C"] == expected_ends[1]["C"]
    assert green["F_pop"] == pytest.approx(expected_ends[1]["C"] - expected_ends[3]["pop"]["green"])


@pytest.mark.parametrize("algo", ["neat", "sep-cmaes", "openai-es"])
def test_each_exported_controller_is_the_one_its_kind_names(tmp_path, algo, monkeypatch):
    """controllers/: the top individual is the best of all; an ES's centre is its centre and its best
    sample the best of the others, the centre left out (at generation 0 the centre is red's best, so
    a best sample that could be the centre shows)."""
    config = resolve("smoke", None, {"algo": algo, "schedule": SCHEDULE, "record": False, "gap_window": 0,
                                     "env": {"duration": 20}})
    run_dir = RunDir(tmp_path / algo)
    play_with_made_up_fitness(config, run_dir, monkeypatch)
    es = algo != "neat"
    population = 21 if es else 20
    centre = population - 1
    phases = ["red"] * 3 + ["green"] * 3 + ["red"] * 2 + ["purple"] * 2
    assert max(range(population), key=lambda p: made_up("red", p, 0, population)) == centre
    kinds = ("top", "centre", "best-sample") if es else ("top",)
    exported = {}
    for key, controller in run_dir.read_controllers().items():
        parsed = parse_controller_key(key)
        if parsed is None:  # final-top, the latest top
            continue
        g, kind = controller["generation"], parsed[2]
        scores = {p: made_up(phases[g], p, g, population) for p in range(population)}
        expected = {"top": max(scores.values()), "centre": scores[centre],
                    "best-sample": max(v for p, v in scores.items() if p != centre)}[kind]
        assert controller["fitness"] == expected == controller["selection_fitness"], (key, kind)
        exported.setdefault(g, set()).add(kind)
    assert exported == {g: set(kinds) for g in (0, 2, 5, 7, 9)}


@pytest.mark.parametrize("algo", ["neat", "sep-cmaes"])
def test_the_held_out_block_holds_each_exported_controllers_own_scores(tmp_path, algo, monkeypatch):
    """The loop's held-out block, with made-up held-out scores that say which controller (its
    training fitness, unique to it) and which task (the thousands) they belong to: every C, R and F
    of the top individual and the centre comes from the controller exported at that task end."""

    def made_up_held_out(controllers, env_config, tasks, episodes):
        return {key: {task.name: 1000.0 * CODES[task.name] + exported["fitness"] for task in tasks}
                for key, exported in controllers.items()}

    monkeypatch.setattr(loop, "score_controllers", made_up_held_out)
    config = resolve("smoke", None, {"algo": algo, "schedule": SCHEDULE, "record": False, "gap_window": 0,
                                     "env": {"duration": 20}})
    run_dir = RunDir(tmp_path / algo)
    block = play_with_made_up_fitness(config, run_dir, monkeypatch)["held_out"]
    controllers = run_dir.read_controllers()
    names = ["red", "green", "red", "purple"]

    def held_out(i: int, kind: str, task: str) -> float:
        return 1000.0 * CODES[task] + controllers[f"task{i}-{names[i]}-{kind}"]["fitness"]

    for kind in ("top", "centre") if algo == "sep-cmaes" else ("top",):
        assert block[f"current_{kind}"] == [held_out(i, kind, name) for i, name in enumerate(names)]
        assert block[f"R_{kind}"] == [[held_out(i, kind, task) for task in names] for i in range(len(names))]
        rows = {(row["at_end_of"], row["task"]): row for row in block["forgetting"]}
        # green at the end of purple: from green's own phase (1); red at the end of green: from phase 0
        assert rows[(3, "green")][f"F_{kind}"] == pytest.approx(held_out(1, kind, "green") - held_out(3, kind, "green"))
        assert rows[(1, "red")][f"R_{kind}"] == held_out(1, kind, "red")
        assert rows[(1, "red")][f"F_{kind}"] == pytest.approx(held_out(0, kind, "red") - held_out(1, kind, "red"))


def test_summary_of_a_four_phase_schedule_with_a_repeated_task():
    """summarise() against values worked out by hand."""
    names = ["red", "green", "red", "purple"]
    ends = [
        {"task": "red", "C": 10.0, "R_pop": {"red": 10.0, "green": 1.0, "purple": 2.0},
         "R_top": {"red": 9.0, "green": 0.5, "purple": 1.5}},
        {"task": "green", "C": 20.0, "R_pop": {"red": 6.0, "green": 20.0, "purple": 3.0},
         "R_top": {"red": 5.0, "green": 18.0, "purple": 2.5}},
        {"task": "red", "C": 12.0, "R_pop": {"red": 12.0, "green": 8.0, "purple": 4.0},
         "R_top": {"red": 11.0, "green": 7.0, "purple": 3.5}},
        {"task": "purple", "C": 30.0, "R_pop": {"red": 7.0, "green": 5.0, "purple": 30.0},
         "R_top": {"red": 6.0, "green": 4.0, "purple": 28.0}},
    ]
    initial = {"pop": {"red": 1.0, "green": 2.0, "purple": 3.0}, "top": {"red": 0.0, "green": 0.0, "purple": 0.0}}
    summary = summarise(names, ends, initial, 1.0, has_centre=False)
    assert summary["current"] == [10, 20, 12, 30] and summary["current_top"] == [9, 18, 11, 28]
    rows = {(row["at_end_of"], row["task"]): row for row in summary["forgetting"]}
    assert list(rows) == [(1, "red"), (2, "green"), (3, "red"), (3, "green")]
    assert rows[(1, "red")] == {"at_end_of": 1, "task": "red", "C": 10, "C_top": 9, "R_pop": 6, "R_top": 5,
                                "F_pop": 4, "F_top": 4}
    assert rows[(2, "green")] == {"at_end_of": 2, "task": "green", "C": 20, "C_top": 18, "R_pop": 8, "R_top": 7,
                                  "F_pop": 12, "F_top": 11}
    # red's latest phase before purple is phase 2, green's is phase 1
    assert rows[(3, "red")] == {"at_end_of": 3, "task": "red", "C": 12, "C_top": 11, "R_pop": 7, "R_top": 6,
                                "F_pop": 5, "F_top": 5}
    assert rows[(3, "green")] == {"at_end_of": 3, "task": "green", "C": 20, "C_top": 18, "R_pop": 5, "R_top": 4,
                                  "F_pop": 15, "F_top": 14}
    assert summary["R_pop"] == [[10, 1, 10, 2], [6, 20, 6, 3], [12, 8, 12, 4], [7, 5, 7, 30]]
    assert summary["R_top"] == [[9, 0.5, 9, 1.5], [5, 18, 5, 2.5], [11, 7, 11, 3.5], [6, 4, 6, 28]]
    assert summary["ACC_pop"] == pytest.approx(12.25) and summary["ACC_top"] == pytest.approx(11.0)
    assert summary["BWT_pop"] == pytest.approx(-23 / 3) and summary["BWT_top"] == pytest.approx(-22 / 3)
    # FWT: R[j-1][j] - b_j, b_j the fresh population's best on phase j's task
    assert summary["FWT_pop"] == pytest.approx(5 / 3) and summary["FWT_top"] == pytest.approx(1.0)


def test_held_out_block_of_a_four_phase_schedule_with_a_repeated_task():
    names = ["red", "green", "red", "purple"]
    top = [{"red": 9.0, "green": 0.5, "purple": 1.5}, {"red": 5.0, "green": 18.0, "purple": 2.5},
           {"red": 11.0, "green": 7.0, "purple": 3.5}, {"red": 6.0, "green": 4.0, "purple": 28.0}]
    centre = [{t: v + 1 for t, v in scores.items()} for scores in top]
    scores = {f"task{i}-{name}-{kind}": values for i, name in enumerate(names)
              for kind, values in (("top", top[i]), ("centre", centre[i]))}
    scores["initial-top"] = {"red": 1.0, "green": 2.0, "purple": 3.0}
    block = held_out_summary(names, scores, episodes=100)
    assert block["episodes"] == 100 and block["phases"] == names
    assert list(block["scores"]) == ["initial-top", "task0-red-top", "task0-red-centre", "task1-green-top",
                                     "task1-green-centre", "task2-red-top", "task2-red-centre", "task3-purple-top",
                                     "task3-purple-centre"]
    assert block["current_top"] == [9, 18, 11, 28] and block["current_centre"] == [10, 19, 12, 29]
    assert "current_best_sample" not in block
    rows = {(row["at_end_of"], row["task"]): row for row in block["forgetting"]}
    assert rows[(1, "red")] == {"at_end_of": 1, "task": "red", "C_top": 9, "R_top": 5, "F_top": 4,
                                "C_centre": 10, "R_centre": 6, "F_centre": 4}
    assert rows[(3, "red")]["C_top"] == 11 and rows[(3, "red")]["F_top"] == 5
    assert rows[(3, "green")]["C_top"] == 18 and rows[(3, "green")]["F_top"] == 14
    assert block["R_top"] == [[9, 0.5, 9, 1.5], [5, 18, 5, 2.5], [11, 7, 11, 3.5], [6, 4, 6, 28]]
    assert block["ACC_top"] == pytest.approx(11.0) and block["BWT_top"] == pytest.approx(-22 / 3)
    assert block["FWT_top"] == pytest.approx(1.0)
    # no generation-0 centre was scored: no baseline, no forward transfer
    assert block["ACC_centre"] == pytest.approx(12.0) and block["FWT_centre"] is None
    # unfinished: the phases that ended, no matrix
    partial = held_out_summary(names, {k: v for k, v in scores.items() if not k.startswith(("task2", "task3"))}, 100)
    assert partial["phases"] == ["red", "green"] and "R_top" not in partial
    assert json.dumps(partial["forgetting"]) == json.dumps([rows[(1, "red")]])
