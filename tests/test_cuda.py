"""The torch code on a CUDA device: the environment against the oracle, NEAT networks against
neat-python, every optimiser, the compiled step, the step replayed as a CUDA graph and the real
command line.

Skipped where torch sees no CUDA device (CI has none). On a GPU machine:
``python -m pytest tests/test_cuda.py``.
"""
from __future__ import annotations

import json
import random

import pytest
import torch

from algorithms import REGISTRY, make_optimizer
from algorithms.mlp import MLPPolicy, layer_sizes_for, n_parameters
from envs import TASKS, ForagingConfig, ForagingEnv, outputs_to_wheels
from lifelong_evo.commands.cli import main
from lifelong_evo.evaluate import evaluate

try:
    from test_env_oracle import CONFIGS, run_against_oracle
    from test_neat_network import HEAVY, _check_parity, _fresh_config, _mutated_genomes
except ImportError:  # tests/ imported as a package
    from tests.test_env_oracle import CONFIGS, run_against_oracle
    from tests.test_neat_network import HEAVY, _check_parity, _fresh_config, _mutated_genomes

pytestmark = pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")


@pytest.mark.parametrize("name", list(CONFIGS))
def test_env_matches_oracle_on_cuda(name):
    c, task_names, batch, n_steps = CONFIGS[name]
    stats = run_against_oracle(c, task_names, batch, n_steps, seed=list(CONFIGS).index(name) + 7, device="cuda")
    assert stats["picks"] >= 30 and stats["correct_drops"] >= 10 and stats["wrong_drops"] >= 8, stats


def test_env_float32_on_cuda_matches_oracle_short_horizon():
    c, task_names, _, _ = CONFIGS["c4_paper_repos"]
    stats = run_against_oracle(c, task_names, batch=60, n_steps=20, seed=99, dtype=torch.float32,
                               obs_atol=1e-4, device="cuda")
    assert stats["picks"] >= 5, stats


def _random_mlp(population: int, config: ForagingConfig, device: str) -> MLPPolicy:
    sizes = layer_sizes_for(config.obs_dim)
    params = torch.randn(population, n_parameters(sizes), generator=torch.Generator().manual_seed(0))
    return MLPPolicy(params.to(device), sizes)


def test_compiled_step_on_cuda_matches_eager():
    """Step by step from the same state (rounding differences would otherwise add up over an
    episode): the compiled step gives the eager step's observations and the same rewards."""
    config = ForagingConfig()
    eager, compiled = (ForagingEnv(config, batch_size=64, device="cuda") for _ in range(2))
    compiled.compile()
    policy = _random_mlp(8, config, "cuda")
    obs = eager.reset([TASKS["red"], TASKS["green"]] * 32, generator=3)
    total = 0.0
    for _ in range(150):
        wheels = outputs_to_wheels(policy(obs.view(8, 8, config.n_agents, -1)), config).view(64, config.n_agents, 3)
        compiled.reset(state=eager.state)
        compiled_obs, compiled_reward, *_ = compiled.step(wheels)
        obs, reward, *_ = eager.step(wheels)
        torch.testing.assert_close(compiled_obs, obs, rtol=1e-5, atol=1e-5)
        assert torch.equal(compiled_reward, reward)
        total += float(reward.sum())
    assert total > 0


def test_evaluation_on_cuda_matches_cpu():
    """Same episodes, same controllers: the fitness of almost every controller agrees to float
    precision (a float32 rounding difference can move one agent across a pick radius)."""
    config = ForagingConfig(duration=200)
    fitness = {device: evaluate(_random_mlp(40, config, device), config, [TASKS["red"], TASKS["green"]], 5,
                                torch.Generator().manual_seed(1), device).cpu()
               for device in ("cpu", "cuda")}
    assert fitness["cpu"].abs().sum() > 0
    agree = torch.isclose(fitness["cuda"], fitness["cpu"], rtol=0, atol=1e-4)
    assert agree.float().mean() >= 0.95, (fitness["cpu"] - fitness["cuda"]).abs().max()


def test_neat_networks_on_cuda_match_neat_python():
    random.seed(6)
    config = _fresh_config(overrides=HEAVY)
    genomes = _mutated_genomes(config, 30, 0, 100)
    for mode in ("zero", "bias"):
        _check_parity(genomes, config, mode, seed=4, E=4, A=5, device="cuda")


@pytest.mark.parametrize("name", sorted(REGISTRY))
def test_optimiser_on_cuda_repeats(name):
    """A few generations on the real environment, twice with one seed: the population is played
    on the GPU and the same seed gives the same numbers (learning itself: test_real_env_learning)."""
    config = ForagingConfig(duration=150)

    def run() -> list[float]:
        optimizer = make_optimizer(name, obs_dim=config.obs_dim, population_size=40, seed=0, device="cuda")
        generator = torch.Generator().manual_seed(0)
        best = []
        for _ in range(4):
            policy = optimizer.ask()
            fitness = evaluate(policy, config, [TASKS["red"]], 4, generator, "cuda")[0]
            assert fitness.device.type == "cuda"
            optimizer.tell(fitness, optimizer.regularise(fitness))
            best.append(float(fitness.max()))
        return best

    first = run()
    assert max(first) > 0, first
    assert run() == first


@pytest.mark.parametrize("algo", ["neat", "openai-es"])
def test_command_line_run_on_cuda_repeats(tmp_path, algo):
    argv = ["--algo", algo, "--reg", "2", "--preset", "smoke", "--device", "cuda", "--out", str(tmp_path),
            "--no-record", "--quiet"]
    for name in ("first", "again"):
        assert main([*argv, "--name", name]) == 0
    assert (tmp_path / "first/metrics.csv").read_text() == (tmp_path / "again/metrics.csv").read_text()
    machines = json.loads((tmp_path / "first/summary.json").read_text())["machines"]
    assert [entry["gpu"] for entry in machines] == [torch.cuda.get_device_name()]


@pytest.mark.parametrize("compiled", [False, True], ids=["eager", "compiled"])
def test_cuda_graph_replays_the_plain_step(compiled):
    """The step captured as a CUDA graph and replayed gives the plain step's numbers bit for bit
    on the same device, through pick conflicts, drops, episode ends and autoresets."""
    config = ForagingConfig(n_boxes=12, max_retrieves=3, duration=40)
    plain, graphed = (ForagingEnv(config, batch_size=24, device="cuda") for _ in range(2))
    if compiled:
        plain.compile()
        graphed.compile()
    graphed.graph_step()
    generator = torch.Generator().manual_seed(5)
    start = plain.sample_state(TASKS["red"], generator)
    start.box_pos[:, :4] = torch.tensor([1.0, 10.0])
    start.agent_pos[:, :, 0], start.agent_pos[:, :, 1] = 1.2, 10.1
    assert torch.equal(graphed.reset(state=start.clone()), plain.reset(state=start))
    events = {"conflicts": 0, "drops": 0}
    for step in range(90):
        wheels = (torch.rand(24, config.n_agents, 3, generator=generator) * 4 - 2).cuda()
        want, got = plain.step(wheels), graphed.step(wheels)
        for w, g in zip(want[:3], got[:3]):
            assert torch.equal(g, w), step
        for name, value in want[3].items():
            assert torch.equal(got[3][name], value), (step, name)
        events["conflicts"] += int(((want[3]["picked"] >= 0).sum(dim=1) >= 2).sum())
        events["drops"] += int((want[3]["dropped"] >= 0).sum())
        if step % 10 == 9:
            assert torch.equal(graphed.reset_done(TASKS["green"], generator=step),
                               plain.reset_done(TASKS["green"], generator=step))
    assert events["conflicts"] >= 5 and events["drops"] >= 5, events
    assert graphed._graph is not None  # replayed, not stepped eagerly


@pytest.mark.parametrize("compiled", [False, True], ids=["eager", "compiled"])
def test_evaluation_with_cuda_graphs_gives_the_same_fitness(compiled):
    config = ForagingConfig(duration=200)
    policy = _random_mlp(40, config, "cuda")
    fitness = [evaluate(policy, config, [TASKS["red"], TASKS["green"]], 5, torch.Generator().manual_seed(1), "cuda",
                        compiled=compiled, cuda_graphs=graphs) for graphs in (False, True)]
    assert fitness[0].abs().sum() > 0
    assert torch.equal(fitness[1], fitness[0])


def test_command_line_run_with_cuda_graphs_gives_the_same_numbers(tmp_path):
    argv = ["--algo", "neat", "--reg", "2", "--preset", "smoke", "--device", "cuda", "--out", str(tmp_path),
            "--no-record", "--quiet"]
    assert main([*argv, "--name", "plain"]) == 0
    assert main([*argv, "--name", "graphed", "--cuda-graphs"]) == 0
    assert (tmp_path / "plain/metrics.csv").read_text() == (tmp_path / "graphed/metrics.csv").read_text()


def test_evaluations_together_on_cuda_give_each_its_fitness_alone():
    """Two populations of other sizes in one batch on the device: each gets the fitness it gets
    alone (both with one evaluation thread)."""
    from lifelong_evo.evaluate import Evaluation, evaluate_together

    config = ForagingConfig(duration=200)
    evaluations = [Evaluation(_random_mlp(size, config, "cuda"), config, tasks, 3,
                              torch.Generator().manual_seed(seed), "cuda")
                   for size, tasks, seed in ((12, [TASKS["red"]], 1), (20, [TASKS["green"], TASKS["red"]], 2))]
    alone = [Evaluation(e.policy, config, e.tasks, 3, torch.Generator().manual_seed(seed), "cuda").run()
             for e, seed in zip(evaluations, (1, 2))]
    for together, want in zip(evaluate_together(evaluations), alone):
        assert torch.equal(together, want)
