"""Single episodes with full state traces, for recordings and replays (played by ``evaluate.rollout``)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from algorithms.base import BatchedPolicy
from envs import ForagingConfig, ForagingEnv, ForagingState, Task

from .evaluate import rollout


@dataclass
class Episode:
    """The trace of one episode (numpy arrays; T steps were played)."""

    task: str
    target: int
    agent_pos: np.ndarray       # (T + 1, A, 2)
    carried_color: np.ndarray   # (T + 1, A): colour id of the carried box, 0 for none
    box_pos: np.ndarray         # (T + 1, K, 2)
    box_present: np.ndarray     # (T + 1, K) bool
    box_color: np.ndarray       # (K,)
    rewards: np.ndarray         # (T,)
    drop_zone: str = "top"      # the nest's edge (envs.DROP_ZONES)
    failed_robots: int = 0      # the highest-index robots that do nothing

    @property
    def total_reward(self) -> float:
        return float(self.rewards.sum())


def play_episodes(policy: BatchedPolicy, config: ForagingConfig, task: Task, seeds: list[int],
                  device: str | torch.device = "cpu") -> list[Episode]:
    """A one-controller ``policy`` plays one episode per seed (all at once, as one batch)."""
    env = ForagingEnv(config, batch_size=len(seeds), device=device)
    single = ForagingEnv(config, batch_size=1, device=device)
    observations = env.reset(state=ForagingState.cat([single.sample_state(task, seed) for seed in seeds]))
    traces = [env.state]
    rewards = []

    def trace(env: ForagingEnv, reward: torch.Tensor) -> None:
        traces.append(env.state)
        rewards.append(reward)

    rollout(policy, env, observations, observer=trace)
    reward = torch.stack(rewards).cpu().numpy()
    episodes = []
    for b in range(len(seeds)):
        color = traces[0].box_color[b].cpu().numpy()
        carried = np.stack([np.where(s.carrying[b].cpu().numpy() >= 0, color[s.carrying[b].clamp(min=0).cpu().numpy()], 0)
                            for s in traces])
        steps = int(traces[-1].steps[b])  # steps after an episode's end leave its state as it was
        episodes.append(Episode(
            task=task.name, target=task.target,
            agent_pos=np.stack([s.agent_pos[b].cpu().numpy() for s in traces])[: steps + 1],
            carried_color=carried[: steps + 1],
            box_pos=np.stack([s.box_pos[b].cpu().numpy() for s in traces])[: steps + 1],
            box_present=np.stack([s.box_present[b].cpu().numpy() for s in traces])[: steps + 1],
            box_color=color, rewards=reward[:steps, b], drop_zone=task.drop_zone,
            failed_robots=task.failed_robots))
    return episodes
