"""Playing episodes: ``rollout``, the one loop in which controllers drive environments (for
fitness, for the recording's and replay's episodes, for the benchmark), ``evaluate``, which
scores a whole population on several tasks in one batched environment call (or one per
evaluation thread, each over a slice of the population), and ``evaluate_together``, which plays
several runs' evaluations in one batch, each giving the fitness ``evaluate`` gives it alone.
``BesideReference`` plays a population with a reference controller beside it, for the functional
regulariser."""
from __future__ import annotations

import functools
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Callable, Iterator, Sequence

import torch

from algorithms.base import BatchedPolicy
from envs import numerics
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


def sample_episodes(config: ForagingConfig, tasks: Sequence[Task], n_envs: int | Sequence[int],
                    generator: torch.Generator, device: str | torch.device = "cpu",
                    dtype: torch.dtype = torch.float32) -> ForagingState:
    """``n_envs`` fresh initial states per task (or ``n_envs[i]`` for task i), task-major."""
    samplers: dict[int, ForagingEnv] = {}
    states = []
    for task, n in zip(tasks, episode_counts(tasks, n_envs)):
        sampler = samplers.setdefault(n, ForagingEnv(config, batch_size=n, device=device, dtype=dtype))
        states.append(sampler.sample_state(task, generator))
    return ForagingState.cat(states)


def episode_counts(tasks: Sequence[Task], n_envs: int | Sequence[int]) -> list[int]:
    """Episodes per task: ``n_envs`` for each, or one count per task."""
    counts = [n_envs] * len(tasks) if isinstance(n_envs, int) else list(n_envs)
    if len(counts) != len(tasks):
        raise ValueError(f"{len(counts)} episode counts for {len(tasks)} tasks")
    return counts


def task_means(totals: torch.Tensor, counts: Sequence[int]) -> torch.Tensor:
    """``(tasks, population)`` mean rewards from the summed rewards ``(population, episodes)``,
    task-major with ``counts[i]`` episodes of task i."""
    if len(set(counts)) == 1:  # one reshape: the same reduction, and so the same bits, as ever
        return totals.view(totals.shape[0], len(counts), counts[0]).mean(dim=-1).T
    return torch.stack([part.mean(dim=-1) for part in totals.split(list(counts), dim=1)])


@contextmanager
def update_threads(threads: int, eval_threads: int, arithmetic: str) -> Iterator[None]:
    """Run the block (an optimiser's ``ask`` and ``tell``) with one torch thread under the
    ``portable`` arithmetic (``envs.numerics``), with ``threads * eval_threads`` under ``native``,
    then go back to ``threads``. The update's linear algebra (MKL's: full CMA-ES's
    eigendecomposition and covariance update, which grow as d^3 and d^2 x population with the
    parameter count d) splits its sums by the thread count, so on more threads it samples other
    populations (by up to 4e-7 after one update at the paper's size), which evolution turns into
    another run: portable runs keep it on one thread, so that no speed setting changes a number.
    Native runs let the idle evaluation threads' cores share it (their numbers follow the speed
    settings anyway); at the paper's size it takes milliseconds either way (docs/performance.md)."""
    torch.set_num_threads(threads * eval_threads if arithmetic == "native" else 1)
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
    shards run in parallel. Each shard scores exactly as it would alone, and with the portable
    arithmetic (``envs.numerics``) a controller scores the same in any shard, so every
    ``eval_threads`` gives the same numbers. A policy without ``shard`` is played in one thread
    whatever ``eval_threads`` says.
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
    environment, ``(population * E,)``.

    An episode that has ended stays as it ended, but the policy is still called on its (frozen)
    observations until every episode has ended. A policy with an ``ongoing(mask)`` method is told,
    before every call, which environments' episodes are still going: ``mask`` ``(population * E,)``
    bool, all true at the first step (the episodes of a reset), then the negation of the last
    step's done flags."""
    config = env.config
    shape = (policy.population_size, -1, config.n_agents, config.obs_dim)
    totals = torch.zeros(observations.shape[0], dtype=observations.dtype, device=observations.device)
    ongoing = getattr(policy, "ongoing", None)
    if ongoing is not None:
        ongoing(torch.ones(observations.shape[0], dtype=torch.bool, device=observations.device))
    for step in range(config.duration if steps is None else steps):
        outputs = policy(observations.view(shape))
        observations, rewards, done, _ = env.step(outputs_to_wheels(outputs, config).view(-1, config.n_agents, 3))
        if ongoing is not None:
            ongoing(~done)  # a new tensor: an in-place step overwrites its done buffer at the next step
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


def evaluate(policy: BatchedPolicy, config: ForagingConfig, tasks: Sequence[Task], n_envs: int | Sequence[int],
             generator: torch.Generator, device: str | torch.device = "cpu",
             dtype: torch.dtype = torch.float32, compiled: bool = False, eval_threads: int = 1,
             cuda_graphs: bool = False) -> torch.Tensor:
    """Fitness ``(len(tasks), population)``: the mean episode reward of every controller over
    ``n_envs`` fresh environments per task (or ``n_envs[i]`` for task i), drawn from ``generator``
    and shared by all controllers (``eval_threads``, ``cuda_graphs``: see ``run_episodes``)."""
    episodes = sample_episodes(config, tasks, n_envs, generator, device, dtype)
    totals = run_episodes(policy, config, episodes, device, dtype, compiled, eval_threads, cuda_graphs)
    return task_means(totals, episode_counts(tasks, n_envs))


@dataclass
class Evaluation:
    """One generation's evaluation of one run: ``evaluate``'s arguments."""

    policy: BatchedPolicy
    config: ForagingConfig
    tasks: Sequence[Task]
    n_envs: int | Sequence[int]
    """Episodes per task: one count for all, or one per task."""
    generator: torch.Generator
    device: str = "cpu"
    compiled: bool = False
    eval_threads: int = 1
    cuda_graphs: bool = False
    numerics: str = "portable"
    """The arithmetic (``envs.numerics.use``) the evaluation is played in."""

    def run(self) -> torch.Tensor:
        numerics.use(self.numerics)
        return evaluate(self.policy, self.config, self.tasks, self.n_envs, self.generator, self.device,
                        compiled=self.compiled, eval_threads=self.eval_threads, cuda_graphs=self.cuda_graphs)

    def batch(self) -> tuple:
        """What evaluations must share to be played in one environment batch."""
        return self.config, str(self.device), self.compiled, self.cuda_graphs, self.numerics


def evaluate_together(evaluations: Sequence[Evaluation]) -> list[torch.Tensor]:
    """The fitness of every evaluation (as ``Evaluation.run`` returns it with one evaluation
    thread), with those that share an environment configuration, device and step settings played
    in one batch: each draws its episodes from its own generator, as ``evaluate`` does, and its
    controllers see only its environments, in the shapes they would see alone. Environments never
    affect each other, so each fitness is the one its run gets alone. Meant for a GPU, which one
    run's batch leaves mostly idle (``eval_threads`` is not used: one batch is one thread)."""
    fitness: list[torch.Tensor | None] = [None] * len(evaluations)
    batches: dict[tuple, list[int]] = {}
    for index, evaluation in enumerate(evaluations):
        batches.setdefault(evaluation.batch(), []).append(index)
    for indices in batches.values():
        members = [evaluations[i] for i in indices]
        numerics.use(members[0].numerics)
        for i, result in zip(indices, _play_together(members)):
            fitness[i] = result
    return fitness


def _play_together(evaluations: Sequence[Evaluation]) -> list[torch.Tensor]:
    first = evaluations[0]
    states, parts = [], []
    for evaluation in evaluations:
        episodes = sample_episodes(evaluation.config, evaluation.tasks, evaluation.n_envs, evaluation.generator,
                                   evaluation.device)
        n_episodes = sum(episode_counts(evaluation.tasks, evaluation.n_envs))
        states.append(episodes.index(torch.arange(n_episodes).repeat(evaluation.policy.population_size)))
        parts.append((evaluation.policy, n_episodes))
    together = _Together(parts)
    env = _env(first.config, together.n_envs, str(first.device), torch.float32, first.compiled, 0, first.cuda_graphs)
    totals = rollout(together, env, env.reset(state=ForagingState.cat(states)))
    fitness, start = [], 0
    for evaluation, (policy, n_episodes) in zip(evaluations, parts):
        size = policy.population_size * n_episodes
        per_controller = totals[start:start + size].view(policy.population_size, n_episodes)
        fitness.append(task_means(per_controller, episode_counts(evaluation.tasks, evaluation.n_envs)))
        start += size
    return fitness


class BesideReference:
    """``policy``, played as it is, with ``reference`` (a one-controller policy) run beside it on
    the very observations each controller sees, step by step in the same rollout: ``penalty`` is
    then, per controller, the mean over its live agent-steps (every agent of every step its
    episodes were still going, in every episode it played) of the summed absolute difference
    between its 3 outputs and the reference's (the functional regulariser's penalty).

    Only live steps count: ``rollout`` keeps calling the policy on the frozen last observation of
    an episode that has ended until every episode of the batch has, and tells it which are still
    going (``ongoing``). Each controller's sum is divided by its own count of live agent-steps,
    which depends only on its own episodes, not on when the rollout stops (which differs between
    shards and between a run played alone or with others).

    The differences are computed in the policies' own arithmetic, rounded to multiples of
    ``GRID`` and summed as integers (exact, so in no particular order), so the penalty is the same
    bits in any shard of the population (evaluation threads), alone or played with other runs.
    ``shard`` exists where ``policy`` has one; each shard keeps its own sums, which ``penalty``
    joins in order."""

    GRID = 2.0 ** -24

    def __init__(self, policy: BatchedPolicy, reference: BatchedPolicy):
        self.policy, self.reference = policy, reference
        self.population_size = policy.population_size
        self._sums: torch.Tensor | None = None  # (population, episodes) int64, in GRID units
        self._agent_steps: torch.Tensor | None = None  # (population, episodes) int64: live agent-steps
        self._ongoing: torch.Tensor | None = None  # (population * episodes,) bool, from rollout
        self._shards: list[BesideReference] = []
        if callable(getattr(policy, "shard", None)):
            self.shard = self._shard

    def _shard(self, start: int, stop: int) -> "BesideReference":
        part = BesideReference(self.policy.shard(start, stop), self.reference)
        self._shards.append(part)
        return part

    def ongoing(self, mask: torch.Tensor) -> None:
        """``rollout``'s mask of the environments whose episode is still going at the next call."""
        self._ongoing = mask

    def __call__(self, observations: torch.Tensor) -> torch.Tensor:
        if self._ongoing is None:
            raise RuntimeError("BesideReference is played by rollout, which says which episodes are going")
        outputs = self.policy(observations)
        population, episodes, agents, width = observations.shape
        theirs = self.reference(observations.reshape(1, population * episodes, agents, width))
        difference = (outputs - theirs.view(outputs.shape)).abs()
        live = self._ongoing.view(population, episodes)
        counts = torch.round(difference.double() / self.GRID).long().sum(dim=(2, 3)) * live
        agent_steps = live.long() * agents
        if self._sums is None:
            self._sums, self._agent_steps = counts, agent_steps
        else:
            self._sums, self._agent_steps = self._sums + counts, self._agent_steps + agent_steps
        return outputs

    def penalty(self, episodes: int) -> torch.Tensor:
        """``(population,)`` float64: each controller's mean, over the live agent-steps of its first
        ``episodes`` episodes (a generation's training episodes come first), of
        ``sum_k |output_k - reference output_k|``: its own summed differences over its own count."""
        parts = self._shards or [self]
        if any(part._sums is None for part in parts):
            raise RuntimeError("penalty() before the population was played")
        sums = torch.cat([part._sums[:, :episodes] for part in parts]).sum(dim=1)
        agent_steps = torch.cat([part._agent_steps[:, :episodes] for part in parts]).sum(dim=1)
        return sums.double() * self.GRID / agent_steps.double()


class _Together:
    """Several runs' policies as one over a batch that holds each run's environments in turn
    (``rollout`` sees one controller driving them all): each policy gets its own environments'
    observations, population-major as ``rollout`` hands them to it alone."""

    population_size = 1

    def __init__(self, parts: Sequence[tuple[BatchedPolicy, int]]):
        self.parts = parts  # (policy, episodes per controller)
        self.n_envs = sum(policy.population_size * n for policy, n in parts)
        # rollout tells only a batch with a policy that wants to know which episodes are going
        if any(callable(getattr(policy, "ongoing", None)) for policy, _ in parts):
            self.ongoing = self._ongoing

    def _ongoing(self, mask: torch.Tensor) -> None:
        """``rollout``'s ``ongoing``: each policy that has one gets its own environments' part of ``mask``."""
        start = 0
        for policy, n_episodes in self.parts:
            size = policy.population_size * n_episodes
            if callable(getattr(policy, "ongoing", None)):
                policy.ongoing(mask[start:start + size])
            start += size

    def __call__(self, observations: torch.Tensor) -> torch.Tensor:
        flat = observations[0]  # (n_envs, agents, obs_dim)
        outputs, start = [], 0
        for policy, n_episodes in self.parts:
            size = policy.population_size * n_episodes
            own = flat[start:start + size].view(policy.population_size, n_episodes, *flat.shape[1:])
            outputs.append(policy(own).reshape(size, *flat.shape[1:-1], -1))
            start += size
        return torch.cat(outputs)[None]
