"""The benchmark's contract at a tiny size: its last line is ``s_per_generation=<seconds>``, also for
the reference step's script (benchmarks/reference_step.py); a bad flag is one line, ``error: ...``,
exit status 2, before anything is timed."""
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from benchmarks.reference_step import ReferenceStep
from envs import TASKS, ForagingConfig, ForagingEnv, ForagingState
from lifelong_evo.commands.bench import main

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("argv", [
    ["--envs", "40", "--also", "20", "--steps", "3", "--eval-threads", "2"],
    ["--algo", "openai-es", "--population", "4", "--evals", "1", "--generations", "1", "--eval-threads", "2"],
    ["--algo", "neat", "--population", "5", "--evals", "1", "--generations", "1", "--runs", "3"],
])
def test_last_line_is_seconds_per_generation(argv, capsys):
    main(argv)
    lines = capsys.readouterr().out.strip().splitlines()
    assert f"eval_threads={2 if '--eval-threads' in argv else 1}" in lines[0]
    assert re.fullmatch(r"s_per_generation=\d+\.\d{3}", lines[-1]) and float(lines[-1].split("=")[1]) > 0


def test_algo_under_compile_prints_the_eager_figure_first(monkeypatch, capsys):
    """``--algo X --compile`` times X eagerly, then compiled; the last line is the compiled figure."""
    import lifelong_evo.commands.bench as bench
    calls = []

    def fake_bench_algo(algo, population, n_envs, generations, device, compiled, eval_threads=1, cuda_graphs=False,
                        runs=1):
        calls.append(compiled)
        seconds = 0.5 if compiled else 2.0
        return {"ask": 0.0, "evaluate": seconds, "tell": 0.0, "controllers": population,
                "s_per_generation": seconds}

    monkeypatch.setattr(bench, "bench_algo", fake_bench_algo)
    main(["--algo", "neat", "--compile"])
    lines = capsys.readouterr().out.strip().splitlines()
    assert calls == [False, True]
    assert "compile=off" in lines[1] and lines[1].endswith("2.000 s/generation")
    assert "compile=on" in lines[2] and lines[2].endswith("0.500 s/generation")
    assert lines[-1] == "s_per_generation=0.500"
    main(["--algo", "neat"])
    assert calls == [False, True, False]


def test_reference_step_senses_what_the_env_senses():
    """``--reference`` times a plain formulation of the same work: on the same arena (no ties)
    its observations are the env's, and its steps keep the one-hots well formed."""
    config = ForagingConfig()
    reference = ReferenceStep(config, batch_size=64)
    reference.reset(TASKS["red"], torch.Generator().manual_seed(3))
    generator = torch.Generator().manual_seed(4)
    for _ in range(30):  # move the agents away from their start, picking and dropping on the way
        observations = reference.step(torch.rand(64, config.n_agents, 3, generator=generator) * 40 - 20)[0]
    n = config.n_neighbors
    assert observations.shape == (64, config.n_agents, config.obs_dim) and observations.isfinite().all()
    slots = observations[..., :n * config.n_types].reshape(64, config.n_agents, n, config.n_types)
    assert (slots.sum(-1) == 1).all() and (observations[..., -(2 * config.n_colors + 1):].sum(-1) == 2).all()
    state = ForagingState(
        agent_pos=torch.stack((reference.ax.T, reference.ay.T), -1), heading=reference.heading.T,
        carrying=reference.carrying.T, box_pos=torch.stack((reference.bx.T, reference.by.T), -1),
        box_color=reference.color.T, box_present=reference.present.T, target=reference.target,
        season=torch.tensor([[True, True, False, False]]).repeat(64, 1), drop_zone=torch.zeros(64, dtype=torch.long),
        rewards=torch.tensor([[1.0, -1.0, 2.0, 0.0]]).repeat(64, 1), failed_robots=torch.zeros(64, dtype=torch.long),
        motor_gain=torch.ones(64),
        steps=torch.zeros(64, dtype=torch.long), retrieved=torch.zeros(64, dtype=torch.long),
        done=torch.zeros(64, dtype=torch.bool), respawn_key=torch.zeros(64, dtype=torch.long))
    # boxes respawned onto one cell tie: the spec senses them in index order, topk in any order
    cell = reference.bx * 100 + reference.by + 10_000 * ~reference.present                   # (K, B)
    untied = ((cell[:, None] == cell[None]).sum(1) == 1).all(0)
    assert untied.sum() >= 16
    torch.testing.assert_close(ForagingEnv(config, batch_size=64).reset(state=state)[untied],
                               reference.observe()[untied])


def test_the_reference_script_times_its_step(capsys):
    """``python benchmarks/reference_step.py`` runs the environment benchmark on ``ReferenceStep``."""
    result = subprocess.run([sys.executable, str(ROOT / "benchmarks/reference_step.py"), "--envs", "20", "--also", "[]",
                             "--steps", "2"], capture_output=True, text=True, cwd=ROOT, timeout=300,
                            env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert result.returncode == 0, result.stderr
    lines = result.stdout.strip().splitlines()
    assert lines[0].endswith("step=ReferenceStep") and re.fullmatch(r"s_per_generation=\d+\.\d{3}", lines[-1])


def refused(argv: list[str], capsys, env_class=ForagingEnv) -> str:
    """``main(argv)`` exits 2 with one ``error:`` line and times nothing; the line."""
    with pytest.raises(SystemExit) as stop:
        main(argv, env_class=env_class)
    captured = capsys.readouterr()
    assert stop.value.code == 2 and captured.out == "", captured
    assert captured.err.startswith("error: ") and captured.err.count("\n") == 1, captured.err
    return captured.err


@pytest.mark.parametrize("argv, message", [
    # the probes: tracebacks (the first seven) or another workload timed without a word
    (["--algo", "nosuch"], "unknown algorithm 'nosuch': choose one of neat, cmaes"),
    (["--algo", "neat", "--population", "0"], "argument --population: '0' is not an integer from 1 to 1000000"),
    (["--algo", "neat", "--evals", "0"], "argument --evals: '0' is not an integer from 1 to 100000"),
    (["--algo", "neat", "--generations", "0"], "argument --generations: '0' is not an integer from 1 to 1000"),
    (["--threads", "0"], "argument --threads: '0' is not an integer from 1 to 1024"),
    (["--eval-threads", "0"], "argument --eval-threads: '0' is not an integer from 1 to 1024"),
    (["--device", "nonsense"], "--device 'nonsense' is not a torch device"),
    (["--also", "a,b"], "argument --also: 'a,b' is not a list of at most 16 integers from 10 to 10000000"),
    (["--envs", "0"], "argument --envs: '0' is not an integer from 10 to 10000000"),
    (["--envs", "-5"], "argument --envs: '-5' is not an integer from 10 to 10000000"),
    (["--also", "0"], "argument --also: '0' is not a list of at most 16 integers from 10 to 10000000"),
    (["--envs", "25"], "--envs 25: one random controller drives 10 environments, so give multiples of 10"),
    # the run's own checks
    (["--algo", "neat", "--population", "3"], "--population: NEAT with genetics 0.92 needs a population of at least 5"),
    (["--algo", "openai-es", "--population", "3"], "--population: openai-es samples mirrored pairs: the population must "
                                                   "be even, got 3"),
    (["--envs", "10000000"], "this benchmark needs about "),
    (["--algo", "neat", "--population", "1000000", "--generations", "1"], "this benchmark needs about "),
    (["--steps", "600"], "argument --steps: '600' is not an integer from 1 to 497"),
    (["--cuda-graphs"], "--cuda-graphs needs --device cuda, not 'cpu': drop --cuda-graphs or run on a GPU"),
    (["--runs", "2"], "--runs N times N runs of an --algo in one batch"),
    (["--algo", "neat", "--runs", "2", "--eval-threads", "2"], "--runs N times N runs of an --algo in one batch"),
    (["--runs", "0"], "argument --runs: '0' is not an integer from 1 to 1000"),
])
def test_a_bad_flag_is_one_line(argv, message, capsys):
    assert message in refused(argv, capsys)


def test_the_memory_check_names_the_flag_that_lifts_it(capsys):
    assert refused(["--envs", "10000000"], capsys).endswith("lower --envs or --also, or pass --no-memory-check to "
                                                            "time it anyway\n")


def test_the_reference_step_with_an_algorithm_is_refused(capsys):
    assert "ReferenceStep is timed as the environment step alone: drop --algo" in refused(
        ["--algo", "neat"], capsys, ReferenceStep)


def test_the_real_command_line_is_refused_in_one_line(tmp_path):
    result = subprocess.run([sys.executable, "-m", "lifelong_evo.commands.bench", "--algo", "neat", "--population", "0"],
                            capture_output=True, text=True, cwd=tmp_path, timeout=300,
                            env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert result.returncode == 2 and result.stdout == ""
    assert result.stderr.startswith("error: argument --population: ") and result.stderr.count("\n") == 1
