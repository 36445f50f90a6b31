"""Held-out scores: every exported controller played on a fixed test set of episodes.

A controller's training fitness is the mean over the N episodes of the generation that selected
it, so the top individual's training score is biased upwards (it is the best of a population on
exactly those episodes). Its held-out score is its mean summed reward over ``episodes`` initial
states per task that no training evaluation ever draws, the same for every run in the same arena
whatever its seed, algorithm or settings: a test split, as a data set has one.

The held-out episodes of a task come from a torch generator seeded with ``held_out_seed(task)``,
``2**63`` plus the CRC-32 of the task's name. Training streams are seeded with the run's seed
(below ``2**32``: ``RunConfig`` refuses larger ones) and recorded episodes with seeds below
``2**63``, so no training or recording stream is ever the held-out one. Episodes are played
eagerly on the CPU with one torch thread, whatever device and step the run uses, so that
``score`` on any machine gives the bytes the loop wrote.

``score_controllers`` is used by the loop at every task end (and at generation 0, the baseline of
forward transfer) and by the ``score`` verb; ``metrics.held_out_summary`` turns the scores into
summary.json's ``held_out`` block.
"""
from __future__ import annotations

import zlib
from contextlib import contextmanager
from typing import Any, Iterator, Sequence

import torch

from algorithms import policy_from_export
from envs import ForagingConfig, ForagingEnv, ForagingState, Task

from .evaluate import run_episodes

HELD_OUT_SEED_BASE = 2 ** 63
"""Held-out generators are seeded from here up; every training and recording seed lies below."""

def held_out_seed(task: str) -> int:
    """The seed of task ``task``'s held-out episodes (stable across processes, unlike ``hash``)."""
    return HELD_OUT_SEED_BASE + zlib.crc32(task.encode())


def held_out_episodes(config: ForagingConfig, tasks: Sequence[Task], episodes: int) -> ForagingState:
    """``episodes`` held-out initial states per task, task-major, on the CPU."""
    sampler = ForagingEnv(config, batch_size=episodes, device="cpu")
    return ForagingState.cat([sampler.sample_state(task, torch.Generator().manual_seed(held_out_seed(task.name)))
                              for task in tasks])


@contextmanager
def _one_thread() -> Iterator[None]:
    """One torch thread (the rounding of a reduction may depend on the thread count), then as before."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(before)


def score_controllers(controllers: dict[str, dict[str, Any]], config: ForagingConfig, tasks: Sequence[Task],
                      episodes: int) -> dict[str, dict[str, float]]:
    """Each exported controller's mean summed reward over the held-out episodes of every task:
    ``{controller: {task: score}}``, in the order given."""
    states = held_out_episodes(config, tasks, episodes)
    scores = {}
    with _one_thread():
        for name, exported in controllers.items():
            totals = run_episodes(policy_from_export(exported, "cpu"), config, states).view(len(tasks), episodes)
            scores[name] = {task.name: value.item() for task, value in zip(tasks, totals.double().mean(dim=1))}
    return scores
