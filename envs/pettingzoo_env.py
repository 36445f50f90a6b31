"""PettingZoo adapter: one foraging arena as a ``pettingzoo.ParallelEnv``, one agent per robot.

Built on ``SwarmForagingEnv`` (same options, seeding, bounds and info), which sits on
``ForagingEnv``: agents ``agent_0 .. agent_{n-1}``, each observing its own ``(obs_dim,)`` vector
and sending its 3 wheel speeds; every agent receives the team's reward (the sum over agents, as
in the paper). All agents end together and are then removed from ``agents``.
"""
from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from .config import Task
from .gym_env import DEFAULT_TASK, SwarmForagingEnv


class ForagingParallelEnv(ParallelEnv):
    """``parallel_env(**options)``: options as ``gymnasium.make("lifelong_evo/SwarmForaging-v0")``.

    ``reset(seed, options)``: ``options`` may hold ``task``; other keys are ignored (PettingZoo's
    API test passes arbitrary ones). ``step`` needs an action for every live agent. ``infos``
    per agent: its ``picked`` / ``dropped`` box index (-1 none), ``drop_correct`` and
    ``respawn_cell`` (-1 none) of the step. ``state()`` is every agent's observation, stacked.
    """

    metadata = {"name": "swarm_foraging_v0", "render_modes": ["rgb_array"], "render_fps": 10,
                "is_parallelizable": True}

    def __init__(self, render_mode: str | None = None, task: str | Task = DEFAULT_TASK, **options):
        self.env = SwarmForagingEnv(render_mode=render_mode, task=task, **options)
        self.config = self.env.config
        self.render_mode = render_mode
        self.metadata = {**type(self).metadata, "render_fps": self.env.metadata["render_fps"]}
        self.possible_agents = [f"agent_{i}" for i in range(self.config.n_agents)]
        self.agents: list[str] = []
        box, act = self.env.observation_space, self.env.action_space
        # one space object per agent, always returned as is (seeding one agent's space leaves the others alone)
        self.observation_spaces = {a: spaces.Box(box.low[0], box.high[0], (self.config.obs_dim,), np.float32)
                                   for a in self.possible_agents}
        self.action_spaces = {a: spaces.Box(act.low[0], act.high[0], (3,), np.float32) for a in self.possible_agents}
        self.state_space = self.env.observation_space
        self._obs: np.ndarray | None = None

    def observation_space(self, agent: str) -> spaces.Box:
        return self.observation_spaces[agent]

    def action_space(self, agent: str) -> spaces.Box:
        return self.action_spaces[agent]

    @property
    def task(self) -> Task:
        return self.env.task

    def reset(self, seed: int | None = None, options: dict[str, Any] | None = None):
        task_option = {"task": options["task"]} if options and "task" in options else None
        obs, _ = self.env.reset(seed=seed, options=task_option)
        self._obs = obs
        self.agents = list(self.possible_agents)
        return ({a: obs[i].copy() for i, a in enumerate(self.agents)},
                {a: {} for a in self.agents})

    def step(self, actions: dict[str, Any]):
        if not self.agents:
            raise RuntimeError("the episode has ended (no live agents): call reset")
        missing = [a for a in self.agents if a not in actions]
        extra = [a for a in actions if a not in self.agents]
        if missing or extra:
            raise ValueError(f"step needs one action per live agent: missing {missing}, unknown or ended {extra}")
        wheels = np.stack([np.asarray(actions[a], dtype=np.float32).reshape(3) for a in self.possible_agents])
        obs, reward, terminated, truncated, info = self.env.step(wheels)
        self._obs = obs
        agents = self.agents
        observations = {a: obs[i].copy() for i, a in enumerate(agents)}
        rewards = {a: reward for a in agents}
        terminations = {a: terminated for a in agents}
        truncations = {a: truncated for a in agents}
        infos = {a: {"picked": int(info["picked"][i]), "dropped": int(info["dropped"][i]),
                     "drop_correct": bool(info["drop_correct"][i]),
                     "respawn_cell": info["respawn_cell"][i].copy()} for i, a in enumerate(agents)}
        if terminated or truncated:
            self.agents = []
        return observations, rewards, terminations, truncations, infos

    def set_task(self, task: str | Task) -> None:
        """Change the task of the running episode and of later resets (a drift)."""
        self.env.set_task(task)

    def state(self) -> np.ndarray:
        if self._obs is None:
            raise RuntimeError("call reset first")
        return self._obs.copy()

    def render(self):
        return self.env.render()

    def close(self):
        self.env.close()


def parallel_env(**options) -> ForagingParallelEnv:
    """A ``ForagingParallelEnv`` (PettingZoo's conventional constructor name)."""
    return ForagingParallelEnv(**options)
