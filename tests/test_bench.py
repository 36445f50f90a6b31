"""The benchmark's contract at a tiny size: its last line is ``s_per_generation=<seconds>``, also for
the reference step's script (benchmarks/reference_step.py)."""
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from benchmarks.reference_step import ReferenceStep
from envs import TASKS, ForagingConfig, ForagingEnv, ForagingState
from lifelong_evo.bench import main

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("argv", [
    ["--envs", "40", "--also", "20", "--steps", "3", "--eval-threads", "2"],
    ["--algo", "openai-es", "--population", "4", "--evals", "1", "--generations", "1", "--eval-threads", "2"],
    ["--algo", "neat", "--population", "4", "--evals", "1", "--generations", "1", "--runs", "3"],
])
def test_last_line_is_seconds_per_generation(argv, capsys):
    main(argv)
    lines = capsys.readouterr().out.strip().splitlines()
    assert f"eval_threads={2 if '--eval-threads' in argv else 1}" in lines[0]
    assert re.fullmatch(r"s_per_generation=\d+\.\d{3}", lines[-1]) and float(lines[-1].split("=")[1]) > 0


def test_algo_under_compile_prints_the_eager_figure_first(monkeypatch, capsys):
    """``--algo X --compile`` times X eagerly, then compiled; the last line is the compiled figure."""
    import lifelong_evo.bench as bench
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
        season=torch.tensor([[True, True, False, False]]).repeat(64, 1),
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
    result = subprocess.run([sys.executable, str(ROOT / "benchmarks/reference_step.py"), "--envs", "20", "--also", "",
                             "--steps", "2"], capture_output=True, text=True, cwd=ROOT, timeout=300,
                            env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert result.returncode == 0, result.stderr
    lines = result.stdout.strip().splitlines()
    assert lines[0].endswith("step=ReferenceStep") and re.fullmatch(r"s_per_generation=\d+\.\d{3}", lines[-1])


def test_the_reference_step_with_an_algorithm_is_refused(capsys):
    with pytest.raises(SystemExit):
        main(["--algo", "neat"], env_class=ReferenceStep)
    assert "ReferenceStep is timed as the environment step alone: drop --algo" in capsys.readouterr().err


def test_steps_beyond_an_episode_are_refused(capsys):
    with pytest.raises(SystemExit):
        main(["--steps", "600"])
    assert "--steps must be from 1 to 497" in capsys.readouterr().err


def test_cuda_graphs_are_refused_off_a_gpu(capsys):
    with pytest.raises(SystemExit) as stop:
        main(["--cuda-graphs"])
    assert stop.value.code == 2 and "add --device cuda, or drop --cuda-graphs" in capsys.readouterr().err


def test_runs_together_need_an_algorithm_and_one_thread(capsys):
    for argv in (["--runs", "2"], ["--algo", "neat", "--runs", "2", "--eval-threads", "2"], ["--runs", "0"]):
        with pytest.raises(SystemExit) as stop:
            main(argv)
        assert stop.value.code == 2 and "--runs N times N runs" in capsys.readouterr().err
