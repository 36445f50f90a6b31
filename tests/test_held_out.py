"""Held-out scoring: a fixed test set of episodes, the same for every run and never among the
training episodes; every exported controller scored on it at every task end; ``score`` writes the
block the loop wrote."""
from __future__ import annotations

import json
import shutil

import pytest
import torch

from envs import TASKS
from lifelong_evo import evaluate, held_out, loop
from lifelong_evo.commands.cli import main
from lifelong_evo.config import resolve
from lifelong_evo.rundir import RunDir

SMALL = {"schedule": "red:2,green:2", "record": False, "env": {"duration": 60}}


def _initial_states(states) -> torch.Tensor:
    """One row per episode: where its robots and boxes start (what makes two episodes the same)."""
    return torch.cat([states.agent_pos.flatten(1), states.box_pos.flatten(1), states.box_color.flatten(1).float()], 1)


def test_held_out_episodes_are_shared_by_every_run_and_never_trained_on(tmp_path, monkeypatch):
    trained, tested = [], []
    sample, held = evaluate.sample_episodes, held_out.held_out_episodes

    def training(*args, **kwargs):
        states = sample(*args, **kwargs)
        trained.append(_initial_states(states))
        return states

    def testing(*args, **kwargs):
        states = held(*args, **kwargs)
        tested.append(_initial_states(states))
        return states

    monkeypatch.setattr(evaluate, "sample_episodes", training)
    monkeypatch.setattr(held_out, "held_out_episodes", testing)
    for algo, seed in (("neat", 1), ("sep-cmaes", 2)):
        config = resolve("smoke", None, {**SMALL, "algo": algo, "seed": seed})
        loop.run(config, RunDir(tmp_path / algo), progress="off")
    first_run = tested[:len(tested) // 2]
    assert len(first_run) == 3  # generation 0 and two task ends
    for states in tested:
        assert torch.equal(states, tested[0])  # every scoring, in both runs, plays the same episodes
    assert tested[0].shape[0] == 2 * 10  # the smoke preset's 10 per task, red then green
    assert len(torch.unique(tested[0], dim=0)) == tested[0].shape[0]
    training_rows = {tuple(row.tolist()) for states in trained for row in states}
    assert len(trained) == 2 * 4 and not training_rows & {tuple(row.tolist()) for row in tested[0]}


def test_held_out_seeds_lie_above_every_training_seed():
    assert all(held_out.held_out_seed(name) >= 2 ** 63 for name in TASKS)
    assert len({held_out.held_out_seed(name) for name in TASKS}) == len(TASKS)
    config = resolve("smoke", None, SMALL).env_config()
    red = held_out.held_out_episodes(config, [TASKS["red"]], 5)
    assert torch.equal(red.agent_pos, held_out.held_out_episodes(config, [TASKS["red"], TASKS["green"]], 5).agent_pos[:5])


@pytest.mark.parametrize("algo", ["neat", "openai-es"])
def test_score_writes_the_block_the_loop_wrote(tmp_path, algo, capsys):
    assert main(["--algo", algo, "--reg", "1", "--preset", "smoke", "--schedule", "red:2,green:2", "--env",
                 "duration=100", "--out", str(tmp_path), "--name", "run", "--no-record", "--quiet"]) == 0
    run = tmp_path / "run"
    written = (run / "summary.json").read_bytes()
    block = json.loads(written)["held_out"]
    kinds = ["top"] if algo == "neat" else ["top", "centre", "best-sample"]
    assert list(block["scores"]) == [f"{phase}-{kind}" for phase in ("initial", "task0-red", "task1-green")
                                     for kind in kinds]
    assert set(block["scores"]["task1-green-top"]) == {"red", "green"}
    # the top controller's held-out score is its own, not the one it was selected with
    exported = json.loads((run / "controllers/task1-green-top.json").read_text())
    assert block["current_top"][1] == block["scores"]["task1-green-top"]["green"]
    assert block["forgetting"][0]["F_top"] == pytest.approx(block["scores"]["task0-red-top"]["red"]
                                                            - block["scores"]["task1-green-top"]["red"])
    assert exported["generation"] == 3
    summary = json.loads(written)
    summary.pop("held_out")
    (run / "summary.json").write_text(json.dumps(summary))
    capsys.readouterr()
    assert main(["score", str(run)]) == 0
    assert (run / "summary.json").read_bytes() == written
    assert main(["score", str(tmp_path)]) == 0  # twice: the same bytes
    assert (run / "summary.json").read_bytes() == written
    assert "held-out" in capsys.readouterr().out


def test_score_a_controller_file_and_fewer_episodes(tmp_path, capsys):
    assert main(["--algo", "neat", "--preset", "smoke", "--schedule", "red:2,green:2", "--out", str(tmp_path),
                 "--name", "run", "--no-record", "--quiet"]) == 0
    loose = tmp_path / "top.json"
    shutil.copy(tmp_path / "run/controllers/task1-green-top.json", loose)
    capsys.readouterr()
    assert main(["score", str(loose), "--schedule", "red:2,green:2", "--episodes", "10", "--env", "duration=200"]) == 0
    printed = json.loads(capsys.readouterr().out)
    block = json.loads((tmp_path / "run/summary.json").read_text())["held_out"]
    assert printed["scores"] == block["scores"]["task1-green-top"]  # the run's own arena and 10 episodes
    assert main(["score", str(tmp_path / "run"), "--episodes", "5"]) == 0
    assert json.loads((tmp_path / "run/summary.json").read_text())["held_out"]["episodes"] == 5


def test_score_a_controller_file_on_tasks_a_file_defines(tmp_path, capsys):
    """``score FILE --tasks``: the loose controller of a run whose schedule plays a task of a task
    file scores as the run scored it; without the file the task is unknown, in one line."""
    tasks = tmp_path / "tasks.toml"
    tasks.write_text('[tasks.red-south]\ntarget = "red"\nseason = ["red", "blue"]\ndrop_zone = "bottom"\n')
    assert main(["--algo", "neat", "--preset", "smoke", "--tasks", str(tasks), "--schedule", "red:2,red-south:2",
                 "--out", str(tmp_path), "--name", "run", "--no-record", "--quiet"]) == 0
    loose = tmp_path / "top.json"
    shutil.copy(tmp_path / "run/controllers/task1-red-south-top.json", loose)
    capsys.readouterr()
    argv = ["score", str(loose), "--schedule", "red:2,red-south:2", "--episodes", "10", "--env", "duration=200"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "red-south" in err and err.count("\n") == 1
    assert main([*argv, "--tasks", str(tasks)]) == 0
    printed = json.loads(capsys.readouterr().out)
    block = json.loads((tmp_path / "run/summary.json").read_text())["held_out"]
    assert printed["scores"] == block["scores"]["task1-red-south-top"] and set(printed["scores"]) == {"red", "red-south"}


@pytest.mark.parametrize("argv, message", [
    (["score", "/no/such/run"], "does not exist"),
    (["score", "RUN", "--episodes", "0"], "--episodes must be >= 1"),
    (["score", "RUN", "--episodes", "ten"], "--episodes: 'ten' is not an integer"),
    (["score", "BAD"], "/bad.json is not an exported controller"),  # the file, named by its whole path
])
def test_score_refuses_bad_input_in_one_line(tmp_path, argv, message, capsys):
    assert main(["--algo", "neat", "--preset", "smoke", "--schedule", "red:2,green:2", "--out", str(tmp_path),
                 "--name", "run", "--no-record", "--quiet"]) == 0
    bad = tmp_path / "bad.json"
    bad.write_text('{"format": "neat-python-genome"}')
    before = (tmp_path / "run/summary.json").read_bytes()
    capsys.readouterr()
    argv = [str(tmp_path / "run") if a == "RUN" else str(bad) if a == "BAD" else a for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and message in err, err
    assert (tmp_path / "run/summary.json").read_bytes() == before
