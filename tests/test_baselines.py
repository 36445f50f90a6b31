"""The continual-learning baselines as run settings (docs/metrics.md, Baselines): rehearsal, the
joint upper bound, from scratch, blends without a boundary, the boundary-free reference and the
stability gap's own episodes, each checked against what its definition says a run plays."""
from __future__ import annotations

import csv
import json
import shutil

import pytest
import torch

from algorithms import REGISTRY
from envs import TASKS
from lifelong_evo import checkpoint, loop
from lifelong_evo.commands.cli import main
from lifelong_evo.config import resolve
from lifelong_evo.rundir import RunDir
from lifelong_evo.schedule import parse_schedule, training_episodes

SMOKE = {"record": False, "env": {"duration": 40}}


def _run(tmp_path, name: str, **settings) -> RunDir:
    run_dir = RunDir(tmp_path / name)
    loop.run(resolve("smoke", None, {**SMOKE, **settings}), run_dir, progress="off")
    return run_dir


def _rows(run_dir: RunDir) -> list[dict[str, str]]:
    return list(csv.DictReader(open(run_dir.metrics)))


def _played(monkeypatch) -> list[list[tuple[str, int]]]:
    """Every generation's training evaluation, as (task, episodes per controller) pairs, in order."""
    seen: list[list[tuple[str, int]]] = []
    real = loop.Evaluation

    def spy(policy, config, tasks, n_envs, *args, **kwargs):
        counts = [n_envs] * len(tasks) if isinstance(n_envs, int) else list(n_envs)
        seen.append([(task.name, n) for task, n in zip(tasks, counts)])
        return real(policy, config, tasks, n_envs, *args, **kwargs)

    monkeypatch.setattr(loop, "Evaluation", spy)
    return seen


# -- what a generation trains on ---------------------------------------------------------------


def test_a_blend_shifts_its_episodes_linearly_from_one_task_to_the_other():
    phases = parse_schedule("red:2,red>green:5,green:2", 200)
    assert [(p.name, p.source and p.source.name, p.generations) for p in phases] == [
        ("red", None, 2), ("green", "red", 5), ("green", None, 2)]
    plan = [{task.name: n for task, n in training_episodes(phases, 1, g, 10)} for g in range(5)]
    # shares of green 0, 1/4, 1/2, 3/4, 1 of 10 episodes, rounded half up
    assert plan == [{"red": 10}, {"red": 7, "green": 3}, {"red": 5, "green": 5}, {"red": 2, "green": 8},
                    {"green": 10}]
    assert [task.name for task, _ in training_episodes(phases, 2, 0, 10)] == ["green"]


def test_rehearsal_and_joint_split_the_same_budget():
    phases = parse_schedule("red:3,green:3,purple:3", 200)
    assert training_episodes(phases, 0, 0, 10, rehearsal=0.3) == [(TASKS["red"], 10)]  # nothing earlier yet
    assert training_episodes(phases, 1, 0, 10, rehearsal=0.3) == [(TASKS["green"], 7), (TASKS["red"], 3)]
    assert training_episodes(phases, 2, 1, 10, rehearsal=0.35) == [(TASKS["purple"], 6), (TASKS["red"], 2),
                                                                   (TASKS["green"], 2)]
    assert training_episodes(phases, 2, 0, 10, rehearsal=0.99) == [(TASKS["purple"], 1), (TASKS["red"], 5),
                                                                   (TASKS["green"], 4)]
    for index in range(3):
        assert training_episodes(phases, index, 0, 10, joint=True) == [(TASKS["red"], 4), (TASKS["green"], 3),
                                                                       (TASKS["purple"], 3)]


def test_a_run_plays_what_its_schedule_and_baseline_say(tmp_path, monkeypatch):
    seen = _played(monkeypatch)
    _run(tmp_path, "blend", schedule="red:2,red>green:3", evals=4, gap_window=0, retention_every=100)
    assert seen == [[("red", 4), ("green", 4)],  # generation 0: every task scored
                    [("red", 4), ("green", 4)],  # red's end
                    [("red", 4)],  # the blend's first generation: all red
                    [("red", 2), ("green", 2)],
                    [("green", 4), ("red", 4)]]  # its last, all green: the end of a phase named green
    config = json.loads((tmp_path / "blend/config.json").read_text())
    assert config["training_episodes"] == [{"task": "red", "episodes": {"red": 4}},
                                           {"task": "green", "blend_from": "red", "first": {"red": 4},
                                            "last": {"green": 4}}]


def test_where_training_mixes_tasks_the_task_end_scores_the_current_task_apart(tmp_path, monkeypatch):
    seen = _played(monkeypatch)
    _run(tmp_path, "rehearsal", schedule="red:2,green:2", evals=4, rehearsal=0.5, gap_window=0, retention_every=100)
    assert seen[2] == [("green", 2), ("red", 2)]
    assert seen[3] == [("green", 2), ("red", 2), ("red", 4), ("green", 4)]


def test_joint_reports_every_task_in_every_generation(tmp_path):
    rows = _rows(_run(tmp_path, "joint", schedule="red:3,green:3", joint=True, gap_window=0, retention_every=100))
    assert all(row["retention_pop_green"] for row in rows[:3]) and all(row["retention_pop_red"] for row in rows[3:])


# -- the same numbers where a baseline changes nothing -----------------------------------------


@pytest.mark.parametrize("settings", [{"rehearsal": 0.3}, {"joint": True}])
def test_on_one_task_rehearsal_and_joint_are_the_plain_run(tmp_path, settings):
    plain = _run(tmp_path, "plain", schedule="red:4")
    baseline = _run(tmp_path, "baseline", schedule="red:4", **settings)
    assert baseline.metrics.read_bytes() == plain.metrics.read_bytes()


def test_rehearsal_begins_at_the_first_switch(tmp_path):
    plain = _rows(_run(tmp_path, "plain", schedule="red:3,green:3"))
    rehearsed = _rows(_run(tmp_path, "rehearsal", schedule="red:3,green:3", rehearsal=0.5))
    assert rehearsed[:3] == plain[:3]
    assert [row["best"] for row in rehearsed[3:]] != [row["best"] for row in plain[3:]]


def test_the_stability_gap_scores_leave_the_training_numbers_alone(tmp_path):
    """Scoring earlier tasks in every generation of the window changes only the retention cells
    it fills: the training columns, the retention of the regular generations and every task end
    stay as without it."""
    without = _rows(_run(tmp_path, "off", schedule="red:3,green:6", gap_window=0))
    with_gap = _rows(_run(tmp_path, "on", schedule="red:3,green:6", gap_window=4))
    retention = [c for c in without[0] if c.startswith("retention_")]
    for before, after in zip(without, with_gap):
        assert {k: v for k, v in before.items() if k not in retention} == \
               {k: v for k, v in after.items() if k not in retention}
        for column in retention:
            assert before[column] in ("", after[column])
    filled = [bool(row["retention_pop_red"]) for row in with_gap[3:]]
    assert filled == [True] * 4 + [False, True]  # the window, an unscored generation, the task end


# -- from scratch ------------------------------------------------------------------------------


def _state(run_dir: RunDir, generation: int) -> dict:
    return checkpoint.load(run_dir.checkpoints / f"generation-{generation:06d}.pt")["optimizer"]


def _same(a, b) -> bool:
    if isinstance(a, torch.Tensor):
        return isinstance(b, torch.Tensor) and a.dtype == b.dtype and torch.equal(a, b)
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    return a == b


@pytest.mark.parametrize("algo", sorted(REGISTRY))
def test_from_scratch_starts_each_task_afresh_whatever_came_before(tmp_path, algo):
    after_red = _run(tmp_path, "after-red", algo=algo, schedule="red:2,green:2", from_scratch=True)
    after_green = _run(tmp_path, "after-green", algo=algo, schedule="green:2,green:2", from_scratch=True)
    assert _same(_state(after_red, 2), _state(after_green, 2))
    transferred = _run(tmp_path, "transfer", algo=algo, schedule="red:2,green:2")
    assert not _same(_state(after_red, 2), _state(transferred, 2))
    # each phase its own fresh population: the seed comes from the phase, not only the run
    three = _run(tmp_path, "three", algo=algo, schedule="red:2,green:2,red:2", from_scratch=True)
    assert not _same(_state(three, 4), _state(after_red, 2))
    # nor is any phase regularised: no task end has a reference to draw its top controller against
    assert not list(three.controllers.glob("*-reference.json"))


# -- the regulariser's reference without a boundary --------------------------------------------


@pytest.mark.parametrize("every, expected", [(0, [2, 6]), (3, [2, 5])])
def test_the_reference_is_taken_at_task_ends_or_every_k_generations(tmp_path, monkeypatch, every, expected):
    taken: list[int] = []
    made = loop._make_optimizer

    def spied(config, env_config, seed):
        optimizer = made(config, env_config, seed)
        tells, tell, end_task = [], optimizer.tell, optimizer.end_task

        def counted_tell(*args, **kwargs):
            tells.append(None)
            return tell(*args, **kwargs)

        def recorded_end_task():
            taken.append(len(tells) - 1)  # the generation just told
            end_task()

        optimizer.tell, optimizer.end_task = counted_tell, recorded_end_task
        return optimizer

    monkeypatch.setattr(loop, "_make_optimizer", spied)
    _run(tmp_path, "reference", algo="sep-cmaes", reg=1.0, schedule="red:3,green:4", reference_every=every)
    assert taken == expected


# -- bad input ---------------------------------------------------------------------------------


@pytest.mark.parametrize("argv, says", [
    (["--rehearsal", "0.3", "--joint"], "--rehearsal and --joint are different baselines"),
    (["--joint", "--from-scratch"], "--joint and --from-scratch are different baselines"),
    (["--rehearsal", "1"], "leaves no episode on the current task"),
    (["--rehearsal", "0.01"], "rounds to no episode"),
    (["--joint", "--evals", "1"], "--joint splits --evals 1 over the schedule's 2 tasks"),
    (["--schedule", "red:2,green>green:3"], "blends green into itself"),
    (["--schedule", "red:2,blue>green:3"], "unknown task 'blue'"),
    (["--rehearsal", "abc"], "--rehearsal"),
])
def test_bad_baseline_settings_are_refused_before_anything_is_written(tmp_path, capsys, argv, says):
    assert main([*argv, "--preset", "smoke", "--out", str(tmp_path), "--name", "x", "--no-record"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and says in err and err.count("\n") == 1, err
    assert not (tmp_path / "x").exists()


# -- resume ------------------------------------------------------------------------------------


@pytest.mark.parametrize("settings", [{"rehearsal": 0.5}, {"joint": True}, {"from_scratch": True},
                                      {"schedule": "red:3,red>green:4", "reference_every": 2, "reg": 1.0}])
def test_a_baseline_resumes_to_the_numbers_of_the_uninterrupted_run(tmp_path, settings):
    options = {"schedule": "red:3,green:4", "checkpoint_every": 2, **settings}
    whole = _run(tmp_path, "whole", **options)
    copy = tmp_path / "copy"
    shutil.copytree(whole.path, copy)
    # back to the middle of green: a run keeps its last two checkpoints (after 6 and 7 generations),
    # and deleting both, as this did, resumed from generation 0
    sorted(copy.glob("checkpoints/generation-*.pt"))[-1].unlink()
    config = resolve("smoke", None, {**SMOKE, **options})
    loop.run(config, RunDir(copy), resume=True, progress="off")
    assert (copy / "metrics.csv").read_bytes() == whole.metrics.read_bytes()
    summaries = [json.loads(p.read_text()) for p in (copy / "summary.json", whole.summary)]
    for summary in summaries:
        summary.pop("wall_time_s")
    assert summaries[0] == summaries[1]


# -- compare -----------------------------------------------------------------------------------


def test_compare_pairs_every_baseline_with_fine_tuning_of_its_seeds(tmp_path):
    root = tmp_path / "runs"
    for name, settings in (("fine", {}), ("rehearsal", {"rehearsal": 0.5}), ("joint", {"joint": True})):
        for seed in (1, 2):
            _run(root, f"{name}-{seed}", seed=seed, schedule="red:2,green:2", **settings)
    assert main(["compare", str(root), "--out", str(tmp_path / "cmp")]) == 0
    headings = [line for line in (tmp_path / "cmp/comparison.md").read_text().splitlines()
                if line.startswith("### ") and " against " in line]
    fine_tuning = "neat reg=0 red:2,green:2"
    assert headings == [f"### neat reg=0 red:2,green:2 rehearsal=0.5 against {fine_tuning}",
                        f"### neat reg=0 red:2,green:2 joint=True against {fine_tuning}"]


def test_a_mixed_run_writes_the_current_tasks_own_curve_and_forward_transfer_reads_it(tmp_path):
    rows = _rows(_run(tmp_path, "rehearsal", schedule="red:2,green:3", evals=4, rehearsal=0.5, gap_window=0))
    # red trains alone (its best is its own); green trains on a mixture from the switch on
    assert [bool(row["retention_pop_green"]) for row in rows] == [False, False, True, True, True]
    assert [bool(row["retention_pop_red"]) for row in rows[:2]] == [False, False]
    plain = _rows(_run(tmp_path, "plain", schedule="red:2,green:3", evals=4, gap_window=0))
    assert not any(row["retention_pop_green"] for row in plain[2:4])
    from lifelong_evo.metrics import forward_transfer_area

    own = [float(row["retention_pop_green"]) for row in rows[2:]]
    scratch = [{**row, "best": "1.0"} for row in plain]
    assert forward_transfer_area(rows, scratch, 2) == {1: pytest.approx(sum(own) / 3 - 1.0)}


def test_the_figures_draw_a_mixed_runs_own_current_curve(tmp_path):
    from lifelong_evo.analysis.figures import current_by_task, stack_current
    from lifelong_evo.runs import load_runs

    run_dir = _run(tmp_path, "rehearsal", schedule="red:2,green:3", evals=4, rehearsal=0.5, gap_window=0)
    rows = _rows(run_dir)
    (run,) = load_runs([run_dir.path])
    own = [float(row["retention_pop_green"]) for row in rows[2:]]
    generations, values = current_by_task([run])["green"]
    assert list(values[0][2:]) == own and all(value != value for value in values[0][:2])  # NaN: red's phase
    _, drawn = stack_current([run])
    assert list(drawn[0]) == [float(rows[0]["best"]), float(rows[1]["best"]), *own]
    assert own != [float(row["best"]) for row in rows[2:]], "the mixture's best must differ for the test to bite"


# -- the families side by side: controller sizes and evaluation budget -------------------------


def test_controller_size_counts_what_a_controller_is_made_of():
    from algorithms import controller_size

    assert controller_size({"layer_sizes": [41, 16, 3], "parameters": []}) == {"parameters": 42 * 16 + 17 * 3}
    genome = {"nodes": [{"key": 0}, {"key": 1}, {"key": 2}, {"key": 7}],
              "connections": [{"enabled": True}, {"enabled": False}, {"enabled": True}]}
    assert controller_size({"format": "neat-python-genome", "genome": genome}) == {"nodes": 4, "connections": 2}
    with pytest.raises(ValueError):
        controller_size({"weights": []})


def test_compare_sets_sizes_and_budgets_side_by_side(tmp_path):
    from lifelong_evo.analysis.comparison import compare_table

    root = tmp_path / "runs"
    for algo in ("neat", "sep-cmaes"):
        for seed in (1, 2):
            _run(root, f"{algo}-{seed}", algo=algo, seed=seed, schedule="red:2,green:2")
    rows, markdown = compare_table([root])
    sizes = {(r["configuration"].split()[0], r["metric"]): r["mean"] for r in rows
             if r["statistic"] == "mean" and r["episodes"] == ""}
    assert sizes[("sep-cmaes", "evaluations per generation")] == 21 * 2  # 20 samples and the centre, N = 2
    assert sizes[("neat", "evaluations per generation")] == 20 * 2
    assert sizes[("sep-cmaes", "parameters of the top at end of phase 1 (green)")] == 42 * 16 + 17 * 3
    neat = [json.loads((root / f"neat-{seed}/controllers/task1-green-top.json").read_text()) for seed in (1, 2)]
    connections = [sum(c["enabled"] for c in g["genome"]["connections"]) for g in neat]
    assert sizes[("neat", "connections of the top at end of phase 1 (green)")] == pytest.approx(sum(connections) / 2)
    assert markdown.count("Controllers and budget: ") == 2  # each configuration's section
    # and one table beside the paper's tables, a line per family, each size in its own measure
    (header, _, *lines) = [line for line in markdown.split("Controllers and budget (red -> green)")[1].splitlines()
                           if line.startswith("|")][:4]
    assert header == ("| configuration | n seeds | evaluations per generation | top at end of phase 0 (red) "
                      "| top at end of phase 1 (green) |")
    cells = {line.split(" | ")[0][2:].split()[0]: line.strip("| ").split(" | ") for line in lines}
    assert cells["sep-cmaes"][2] == "42.00 [42.00, 42.00]" and cells["neat"][2] == "40.00 [40.00, 40.00]"
    assert cells["sep-cmaes"][4] == f"parameters {42 * 16 + 17 * 3:.2f} [{42 * 16 + 17 * 3:.2f}, {42 * 16 + 17 * 3:.2f}]"
    assert cells["neat"][4].startswith("nodes ") and f"; connections {sum(connections) / 2:.2f} [" in cells["neat"][4]
    # how often an ES's top individual is its centre, from metrics.csv's top and centre columns
    from lifelong_evo.analysis.tables import top_is_centre_name
    from lifelong_evo.metrics_csv import read_metrics

    shares = []
    for seed in (1, 2):
        green = [row for row in read_metrics(root / f"sep-cmaes-{seed}/metrics.csv") if row["task"] == "green"]
        shares.append(100 * sum(row["top"] == row["centre"] for row in green) / len(green))
    assert sizes[("sep-cmaes", top_is_centre_name(1, "green"))] == pytest.approx(sum(shares) / 2)
    assert ("neat", top_is_centre_name(1, "green")) not in sizes
