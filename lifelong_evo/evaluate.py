"""Playing episodes: ``rollout``, the one loop in which controllers drive environments (for
fitness, for the recording's and replay's episodes, for the benchmark), and ``evaluate``, which
scores a whole population on several tasks in one batched environment call (or one per
evaluation thread, each over a slice of the population)."""
from __future__ import annotations

import functools
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from typing import Callable, Iterator, Sequence

import torch

from algorithms.base import BatchedPolicy
from envs import ConfigError, ForagingConfig, ForagingEnv, ForagingState, Task, outputs_to_wheels


@functools.lru_cache(maxsize=16)
def _env(config: ForagingConfig, batch_size: int, device: str, dtype: torch.dtype, compiled: bool,
         thread: int, cuda_graphs: bool = False) -> ForagingEnv:
    """One environment object per batch shape and evaluation thread (each steps its own), so
    that a compiled step is compiled, and a CUDA graph captured, once per shape."""
    env = ForagingEnv(config, batch_size=batch_size, device=device, dtype=dtype)
    if compiled:
        env.compile()
    if cuda_graphs:
        env.graph_step(capture=True)
    return env


def sample_episodes(config: ForagingConfig, tasks: Sequence[Task], n_envs: int, generator: torch.Generator,
                    device: str | torch.device = "cpu", dtype: torch.dtype = torch.float32) -> ForagingState:
    """``n_envs`` fresh initial states per task, task-major: ``(len(tasks) * n_envs)`` environments."""
    sampler = ForagingEnv(config, batch_size=n_envs, device=device, dtype=dtype)
    return ForagingState.cat([sampler.sample_state(task, generator) for task in tasks])


@contextmanager
def update_threads(threads: int, eval_threads: int) -> Iterator[None]:
    """Run the block (an optimiser's ``ask`` and ``tell``) with ``threads * eval_threads`` torch
    threads, then go back to ``threads``. Between evaluations the evaluation threads are idle,
    so their cores can share the update's linear algebra (full CMA-ES's Cholesky factorisation
    and covariance update, which grow as d^3 and d^2 x population with the parameter count d)."""
    torch.set_num_threads(threads * eval_threads)
    try:
        yield
    finally:
        torch.set_num_threads(threads)


def shard_bounds(population: int, eval_threads: int) -> list[tuple[int, int]]:
    """Contiguous ``(start, stop)`` slices of the population, one per thread (at most one per
    controller), sizes differing by at most one (so at most two batch shapes to compile)."""
    if eval_threads < 1:
        raise ConfigError(f"evaluation threads must be >= 1, got {eval_threads}")
    n = min(eval_threads, population)
    edges = [population * i // n for i in range(n + 1)]
    return list(zip(edges[:-1], edges[1:]))


def run_episodes(policy: BatchedPolicy, config: ForagingConfig, episodes: ForagingState,
                 device: str | torch.device = "cpu", dtype: torch.dtype = torch.float32,
                 compiled: bool = False, eval_threads: int = 1, cuda_graphs: bool = False) -> torch.Tensor:
    """Every controller of ``policy`` plays every episode of ``episodes`` (E initial states);
    returns the summed rewards ``(population, E)``; ``cuda_graphs``: the environments replay
    their step as a CUDA graph (``ForagingEnv.graph_step``), with the same numbers.

    With ``eval_threads > 1`` the population is split into that many shards (``policy.shard``), each
    played in its own thread by its own environment. The compiled step releases the GIL, so the
    shards run in parallel. Each shard scores exactly as it would alone, so a given ``eval_threads``
    always gives the same numbers; another count can round the last bit of a float differently
    (vectorised maths handles the tail of each tensor apart). A policy without ``shard`` is played
    in one thread whatever ``eval_threads`` says.
    """
    bounds = shard_bounds(policy.population_size, eval_threads)
    if len(bounds) == 1 or not callable(getattr(policy, "shard", None)):
        return _play(policy, config, episodes, device, dtype, compiled, 0, cuda_graphs)
    shards = [policy.shard(start, stop) for start, stop in bounds]
    with ThreadPoolExecutor(len(shards), thread_name_prefix="evaluate") as pool:
        totals = pool.map(lambda thread: _play(shards[thread], config, episodes, device, dtype, compiled, thread,
                                               cuda_graphs),
                          range(len(shards)))
        return torch.cat(list(totals))


DONE_CHECK_EVERY = 25
"""Steps between checks whether every episode has ended: a check waits for the device."""


def rollout(policy: BatchedPolicy, env: ForagingEnv, observations: torch.Tensor, steps: int | None = None,
            observer: Callable[[ForagingEnv, torch.Tensor], None] | None = None) -> torch.Tensor:
    """The controllers of ``policy`` drive ``env`` from ``observations`` (what its reset returned)
    for ``steps`` steps (default: an episode's length) or until every episode has ended. The
    batch is population-major: controller p drives environments p*E to (p+1)*E - 1, so the policy
    sees ``(population, E, agents, obs_dim)`` observations. ``observer(env, rewards)`` is called
    after every step (the recordings trace episodes with it). Returns the rewards summed per
    environment, ``(population * E,)``."""
    config = env.config
    shape = (policy.population_size, -1, config.n_agents, config.obs_dim)
    totals = torch.zeros(observations.shape[0], dtype=observations.dtype, device=observations.device)
    for step in range(config.duration if steps is None else steps):
        outputs = policy(observations.view(shape))
        observations, rewards, done, _ = env.step(outputs_to_wheels(outputs, config).view(-1, config.n_agents, 3))
        totals += rewards
        if observer is not None:
            observer(env, rewards)
        if step % DONE_CHECK_EVERY == DONE_CHECK_EVERY - 1 and bool(done.all()):
            break
    return totals


def _play(policy: BatchedPolicy, config: ForagingConfig, episodes: ForagingState, device, dtype,
          compiled: bool, thread: int, cuda_graphs: bool) -> torch.Tensor:
    """``run_episodes`` for one evaluation thread: every controller meets the same E episodes."""
    population = policy.population_size
    n_episodes = episodes.target.shape[0]
    env = _env(config, population * n_episodes, str(device), dtype, compiled, thread, cuda_graphs)
    observations = env.reset(state=episodes.index(torch.arange(n_episodes).repeat(population)))
    return rollout(policy, env, observations).view(population, n_episodes)


def evaluate(policy: BatchedPolicy, config: ForagingConfig, tasks: Sequence[Task], n_envs: int,
             generator: torch.Generator, device: str | torch.device = "cpu",
             dtype: torch.dtype = torch.float32, compiled: bool = False, eval_threads: int = 1,
             cuda_graphs: bool = False) -> torch.Tensor:
    """Fitness ``(len(tasks), population)``: the mean episode reward of every controller over
    ``n_envs`` fresh environments per task, drawn from ``generator`` and shared by all controllers
    (``eval_threads``, ``cuda_graphs``: see ``run_episodes``)."""
    episodes = sample_episodes(config, tasks, n_envs, generator, device, dtype)
    totals = run_episodes(policy, config, episodes, device, dtype, compiled, eval_threads, cuda_graphs)
    return totals.view(policy.population_size, len(tasks), n_envs).mean(dim=-1).T
