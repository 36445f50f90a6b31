"""Playing single episodes with full state traces, for recordings and replays."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from algorithms.base import BatchedPolicy
from envs import ForagingConfig, ForagingEnv, Task, outputs_to_wheels


@dataclass
class Episode:
    """The trace of one episode (numpy arrays; T steps were played)."""

    task: str
    target: int
    agent_pos: np.ndarray       # (T + 1, A, 2)
    carried_colour: np.ndarray  # (T + 1, A): colour id of the carried box, 0 for none
    box_pos: np.ndarray         # (T + 1, K, 2)
    box_present: np.ndarray     # (T + 1, K) bool
    box_colour: np.ndarray      # (K,)
    rewards: np.ndarray         # (T,)

    @property
    def total_reward(self) -> float:
        return float(self.rewards.sum())


def play_episodes(policy: BatchedPolicy, config: ForagingConfig, task: Task, seeds: list[int],
                  device: str | torch.device = "cpu") -> list[Episode]:
    """A one-controller ``policy`` plays one episode per seed (all at once, as one batch)."""
    env = ForagingEnv(config, batch_size=len(seeds), device=device)
    observations = env.reset(state=_states(env, task, seeds))
    traces = [env.state]
    rewards = []
    for _ in range(config.duration):
        outputs = policy(observations[None])[0]
        observations, reward, done, _ = env.step(outputs_to_wheels(outputs, config))
        traces.append(env.state)
        rewards.append(reward)
        if bool(done.all()):
            break
    reward = torch.stack(rewards).cpu().numpy()
    episodes = []
    for b in range(len(seeds)):
        colour = traces[0].box_color[b].cpu().numpy()
        carried = np.stack([np.where(s.carrying[b].cpu().numpy() >= 0, colour[s.carrying[b].clamp(min=0).cpu().numpy()], 0)
                            for s in traces])
        steps = int(traces[-1].steps[b])
        episodes.append(Episode(
            task=task.name, target=task.target,
            agent_pos=np.stack([s.agent_pos[b].cpu().numpy() for s in traces])[: steps + 1],
            carried_colour=carried[: steps + 1],
            box_pos=np.stack([s.box_pos[b].cpu().numpy() for s in traces])[: steps + 1],
            box_present=np.stack([s.box_present[b].cpu().numpy() for s in traces])[: steps + 1],
            box_colour=colour, rewards=reward[:steps, b]))
    return episodes


def _states(env: ForagingEnv, task: Task, seeds: list[int]):
    from envs import ForagingState

    single = ForagingEnv(env.config, batch_size=1, device=env.device)
    return ForagingState.cat([single.sample_state(task, seed) for seed in seeds])
