"""Scoring a whole population on several tasks in one batched environment call."""
from __future__ import annotations

import functools
from typing import Sequence

import torch

from algorithms.base import BatchedPolicy
from envs import ForagingConfig, ForagingEnv, ForagingState, Task, outputs_to_wheels


@functools.lru_cache(maxsize=8)
def _env(config: ForagingConfig, batch_size: int, device: str, dtype: torch.dtype, compiled: bool) -> ForagingEnv:
    """One environment object per batch shape, so that a compiled sensing is compiled once per shape."""
    env = ForagingEnv(config, batch_size=batch_size, device=device, dtype=dtype)
    if compiled:
        env.compile()
    return env


def sample_episodes(config: ForagingConfig, tasks: Sequence[Task], n_envs: int, generator: torch.Generator,
                    device: str | torch.device = "cpu", dtype: torch.dtype = torch.float32) -> ForagingState:
    """``n_envs`` fresh initial states per task, task-major: ``(len(tasks) * n_envs)`` environments."""
    sampler = ForagingEnv(config, batch_size=n_envs, device=device, dtype=dtype)
    return ForagingState.cat([sampler.sample_state(task, generator) for task in tasks])


def run_episodes(policy: BatchedPolicy, config: ForagingConfig, episodes: ForagingState,
                 device: str | torch.device = "cpu", dtype: torch.dtype = torch.float32,
                 compiled: bool = False) -> torch.Tensor:
    """Every controller of ``policy`` plays every episode of ``episodes`` (E initial states);
    returns the summed rewards ``(population, E)``.

    The batch is population-major, ``(P * E)`` environments, so the policy sees its
    observations as ``(P, E, agents, obs_dim)`` and each controller meets the same E episodes.
    """
    population = policy.population_size
    n_episodes = episodes.target.shape[0]
    env = _env(config, population * n_episodes, str(device), dtype, compiled)
    tiled = episodes.index(torch.arange(n_episodes).repeat(population))
    observations = env.reset(state=tiled)
    totals = torch.zeros(population * n_episodes, dtype=dtype, device=device)
    shape = (population, n_episodes, config.n_agents, config.obs_dim)
    for step in range(config.duration):
        outputs = policy(observations.view(shape))
        observations, rewards, done, _ = env.step(outputs_to_wheels(outputs, config).view(-1, config.n_agents, 3))
        totals += rewards
        if step % 25 == 24 and bool(done.all()):
            break
    return totals.view(population, n_episodes)


def evaluate(policy: BatchedPolicy, config: ForagingConfig, tasks: Sequence[Task], n_envs: int,
             generator: torch.Generator, device: str | torch.device = "cpu",
             dtype: torch.dtype = torch.float32, compiled: bool = False) -> torch.Tensor:
    """Fitness ``(len(tasks), population)``: the mean episode reward of every controller over
    ``n_envs`` fresh environments per task, drawn from ``generator`` and shared by all controllers."""
    episodes = sample_episodes(config, tasks, n_envs, generator, device, dtype)
    totals = run_episodes(policy, config, episodes, device, dtype, compiled)
    return totals.view(policy.population_size, len(tasks), n_envs).mean(dim=-1).T
