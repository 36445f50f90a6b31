"""Gymnasium adapters over the batched ``ForagingEnv``: a single environment and a vector one.

``gymnasium.make("lifelong_evo/SwarmForaging-v0", **options)`` gives ``SwarmForagingEnv`` (one arena,
every agent's observation stacked, ``(n_agents, obs_dim)``, wheel speeds ``(n_agents, 3)``), and
``gymnasium.make_vec(..., num_envs=N, vectorization_mode="vector_entry_point")`` gives
``SwarmForagingVectorEnv`` (N arenas in one torch batch, numpy in and out, next-step autoreset).

Options are the ``ForagingConfig`` fields plus ``task`` (a task name such as ``"red"``, or a
``Task``; the vector environment also takes one task per sub-environment) and ``render_mode``;
the vector environment also takes ``device``. Unknown names raise one ``ConfigError``.

Seeding follows Gymnasium: ``reset(seed=s)`` reseeds ``np_random``; every draw of initial states
(reset and autoreset) seeds a fresh torch generator with ``torch_seed(self.np_random)``, so all
randomness flows from ``np_random``. Nothing here re-implements the arena: it only converts.
"""
from __future__ import annotations

import difflib
import math
from dataclasses import fields
from typing import Any, Sequence

import gymnasium
import numpy as np
import torch
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from .config import DROP_ZONES, TASKS, ConfigError, ForagingConfig, Task, color_rgb, task_by_name
from .foraging import ForagingEnv
from .state import ForagingState

ENV_ID = "lifelong_evo/SwarmForaging-v0"
DEFAULT_TASK = "red"
_CONFIG_FIELDS = tuple(f.name for f in fields(ForagingConfig))
_INFO_KEYS = ("picked", "dropped", "drop_correct", "respawn_cell")


# ---------------------------------------------------------------------- options and spaces
def split_options(options: dict[str, Any], extra: Sequence[str] = ()) -> ForagingConfig:
    """Validate adapter options: ``ForagingConfig`` fields only (``extra`` names are the adapter's
    own, already taken out by the caller, listed in the error so that it names every valid one)."""
    unknown = sorted(set(options) - set(_CONFIG_FIELDS))
    if unknown:
        valid = sorted((*_CONFIG_FIELDS, *extra))
        hints = [f"{name!r} -> {close[0]!r}" for name in unknown
                 if (close := difflib.get_close_matches(name, valid, n=1))]
        if "max_episode_steps" in unknown:
            hints.append("the episode length is 'duration'")
        hint = f" (did you mean: {', '.join(hints)})" if hints else ""
        raise ConfigError(f"unknown environment option(s) {unknown}{hint}: valid ones are {valid}")
    return ForagingConfig.from_dict(options)


def as_task(task: str | Task, config: ForagingConfig) -> Task:
    """A task name or ``Task`` -> a ``Task`` checked against ``config`` (one clear ``ConfigError``)."""
    if isinstance(task, str):
        task = task_by_name(task)
    elif not isinstance(task, Task):
        raise ConfigError(f"task must be a task name ({', '.join(TASKS)}) or a Task, got {task!r}")
    config.check_task(task)
    return task


def torch_seed(np_random: np.random.Generator) -> int:
    """The torch generator seed that the adapters draw from ``np_random`` for one sampling."""
    return int(np_random.integers(0, 2**63 - 1, dtype=np.int64))


def observation_bounds(config: ForagingConfig) -> tuple[np.ndarray, np.ndarray]:
    """Per-element (low, high) of one agent's observation vector, float32, in the spec's order.

    One-hots lie in [0, 1]; sin and cos in [-1, 1]; distances / sensor_range in [-1/sensor_range, 1]:
    the bottom and right walls read ``size - x - 1``, down to -1 at the edge (the spec keeps that
    ``- 1``), and boxes and agents are sensed up to ``<= sensor_range``.
    """
    c, n, r = config.n_colors, config.n_neighbors, config.sensor_range
    low = np.zeros(config.obs_dim, dtype=np.float32)
    high = np.ones(config.obs_dim, dtype=np.float32)
    start = (c + 3) * n
    # the env divides in float32 (or float64, then cast): the lower of both roundings of -1/r
    low[start:start + n] = min(np.float32(-1.0) / np.float32(r), np.float32(-1.0 / r))
    low[start + n:start + 3 * n + 2] = -1.0   # neighbour sin, cos; own heading sin, cos
    return low, high


def observation_space(config: ForagingConfig) -> spaces.Box:
    """``Box((n_agents, obs_dim), float32)``: every agent's observation, stacked."""
    low, high = observation_bounds(config)
    shape = (config.n_agents, config.obs_dim)
    return spaces.Box(np.broadcast_to(low, shape), np.broadcast_to(high, shape), shape, np.float32)


def action_space(config: ForagingConfig) -> spaces.Box:
    """``Box(-max_wheel_velocity, max_wheel_velocity, (n_agents, 3), float32)``: wheel speeds."""
    v = np.float32(config.max_wheel_velocity)
    return spaces.Box(-v, v, (config.n_agents, 3), np.float32)


def _numpy(t: torch.Tensor, dtype=None) -> np.ndarray:
    """A fresh numpy copy (never a view of a torch buffer)."""
    return np.array(t.detach().cpu().numpy(), dtype=dtype, copy=True)


# ---------------------------------------------------------------------- rendering
def render_arena(state: ForagingState, index: int, config: ForagingConfig, scale: int = 16) -> np.ndarray:
    """An ``(H, W, 3)`` uint8 picture of environment ``index`` of ``state`` (x down, y right; the
    drop zone shaded along its edge; agents grey disks, failed ones dark red, with a heading tick
    and their load)."""
    side = int(math.ceil(config.size * scale))
    img = np.full((side, side, 3), 200, dtype=np.uint8)
    rows, cols = np.mgrid[0:side, 0:side]
    px, py = (rows + 0.5) / scale, (cols + 0.5) / scale               # pixel centres, arena units
    depth = {"top": px, "bottom": config.size - px, "left": py, "right": config.size - py}
    img[depth[DROP_ZONES[int(state.drop_zone[index])]] < 1] = (170, 200, 170)  # the nest, 1 unit deep
    box_pos = state.box_pos[index].cpu().numpy()
    box_color = state.box_color[index].cpu().numpy()
    present = state.box_present[index].cpu().numpy()
    for (bx, by), color, here in zip(box_pos, box_color, present):
        if here:
            img[(np.abs(px - bx) < 0.3) & (np.abs(py - by) < 0.3)] = color_rgb(color)
    pos = state.agent_pos[index].cpu().double().numpy()
    heading = np.deg2rad(state.heading[index].cpu().double().numpy())
    carrying = state.carrying[index].cpu().numpy()
    working = config.n_agents - int(state.failed_robots[index])
    for agent, ((ax, ay), h, load) in enumerate(zip(pos, heading, carrying)):
        d2 = (px - ax) ** 2 + (py - ay) ** 2
        img[d2 < 0.25] = (90, 90, 90) if agent < working else (120, 30, 30)
        if load >= 0:
            img[d2 < 0.04] = color_rgb(box_color[load])
        # heading 0 points to the top (x decreasing), 90 to the left (the spec's directions)
        for t in np.linspace(0.3, 0.6, 4):
            r_, c_ = int((ax - t * math.cos(h)) * scale), int((ay - t * math.sin(h)) * scale)
            if 0 <= r_ < side and 0 <= c_ < side:
                img[r_, c_] = (0, 0, 0)
    return img


# ---------------------------------------------------------------------- single environment
class SwarmForagingEnv(gymnasium.Env):
    """One foraging arena as a ``gymnasium.Env`` (a ``ForagingEnv`` with a batch of 1 inside).

    Observation ``(n_agents, obs_dim)`` float32; action ``(n_agents, 3)`` wheel speeds, clipped to
    the action space. Reward: the team's summed reward of the step. ``terminated``: the correct
    retrievals reached ``max_retrieves``; ``truncated``: ``duration`` steps were taken (both can be
    true on the same step). ``info``: the step's ``picked`` / ``dropped`` box per agent (-1 none),
    ``drop_correct`` per agent and ``respawn_cell`` ``(n_agents, 2)`` (-1 none), as numpy.
    ``reset(options={"task": ...})`` switches the task from this episode on; ``set_task`` changes
    it mid-episode (boxes keep their colours).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(self, render_mode: str | None = None, task: str | Task = DEFAULT_TASK, **options):
        self.config = split_options(options, extra=("task", "render_mode"))
        self.task = as_task(task, self.config)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ConfigError(f"render_mode must be None or one of {self.metadata['render_modes']}, got {render_mode!r}")
        self.render_mode = render_mode
        self.metadata = {**type(self).metadata, "render_fps": 1.0 / self.config.time_step}
        self.foraging = ForagingEnv(self.config, batch_size=1)
        self.observation_space = observation_space(self.config)
        self.action_space = action_space(self.config)
        self._started = False

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        options = dict(options or {})
        if "task" in options:
            self.task = as_task(options.pop("task"), self.config)
        if options:
            raise ConfigError(f"unknown reset option(s) {sorted(options)}: the only one is 'task'")
        obs = self.foraging.reset(self.task, generator=torch_seed(self.np_random))
        self._started = True
        return _numpy(obs[0], np.float32), {}

    def step(self, action):
        wheels = np.asarray(action, dtype=np.float32)
        if wheels.shape != self.action_space.shape:
            raise ValueError(f"action must have shape {self.action_space.shape} (agents, wheels), got {wheels.shape}")
        wheels = np.clip(wheels, self.action_space.low, self.action_space.high)
        obs, reward, _, info = self.foraging.step(torch.from_numpy(wheels)[None])
        terminated, truncated = bool(info["terminated"][0]), bool(info["truncated"][0])
        info = {key: _numpy(info[key][0]) for key in _INFO_KEYS}
        return _numpy(obs[0], np.float32), float(reward[0]), terminated, truncated, info

    def set_task(self, task: str | Task) -> None:
        """Change the task of the running episode and of later resets (a drift)."""
        self.task = as_task(task, self.config)
        if self._started:
            self.foraging.set_tasks(self.task)

    def render(self):
        if self.render_mode == "rgb_array":
            return render_arena(self.foraging.state, 0, self.config)
        return None


# ---------------------------------------------------------------------- vector environment
class SwarmForagingVectorEnv(VectorEnv):
    """``num_envs`` arenas in one torch ``ForagingEnv`` batch, as a ``gymnasium.vector.VectorEnv``.

    Numpy in and out: observations ``(num_envs, n_agents, obs_dim)`` float32, actions
    ``(num_envs, n_agents, 3)``, rewards float64, terminations / truncations bool, as in
    ``SwarmForagingEnv``. Autoreset is ``AutoresetMode.NEXT_STEP`` (as ``SyncVectorEnv``): the step
    after a sub-environment ended resets it instead of stepping it, returning its first
    observation with reward 0 and terminated / truncated False (and its info entries masked out).
    ``info`` holds ``picked``, ``dropped``, ``drop_correct``, ``respawn_cell`` with a leading
    ``num_envs`` axis, each with its ``_key`` mask. ``task``: one task or one per sub-environment.
    ``reset(options=...)`` takes ``task`` and ``reset_mask`` (reset only those sub-environments).
    """

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(self, num_envs: int = 1, render_mode: str | None = None,
                 task: str | Task | Sequence[str | Task] = DEFAULT_TASK, device: str | torch.device = "cpu",
                 **options):
        self.config = split_options(options, extra=("task", "render_mode", "device", "num_envs"))
        if int(num_envs) < 1:
            raise ConfigError(f"num_envs must be >= 1, got {num_envs}")
        self.num_envs = int(num_envs)
        self.tasks = self._as_tasks(task)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ConfigError(f"render_mode must be None or one of {self.metadata['render_modes']}, got {render_mode!r}")
        self.render_mode = render_mode
        self.metadata = {**type(self).metadata, "render_fps": 1.0 / self.config.time_step}
        self.foraging = ForagingEnv(self.config, batch_size=self.num_envs, device=device)
        self.single_observation_space = observation_space(self.config)
        self.single_action_space = action_space(self.config)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._autoreset = np.zeros(self.num_envs, dtype=np.bool_)
        self._last_obs: np.ndarray | None = None

    def _as_tasks(self, task) -> list[Task]:
        if isinstance(task, (str, Task)):
            return [as_task(task, self.config)] * self.num_envs
        tasks = [as_task(t, self.config) for t in task]
        if len(tasks) != self.num_envs:
            raise ConfigError(f"got {len(tasks)} tasks for {self.num_envs} environments: give one task or one per environment")
        return tasks

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        if seed is not None and not isinstance(seed, (int, np.integer)):
            raise TypeError(f"seed must be an int or None (one seed for the whole batch), got {seed!r}")
        super().reset(seed=None if seed is None else int(seed))
        options = dict(options or {})
        if "task" in options:
            self.tasks = self._as_tasks(options.pop("task"))
        mask = options.pop("reset_mask", None)
        if options:
            raise ConfigError(f"unknown reset option(s) {sorted(options)}: valid ones are 'task' and 'reset_mask'")
        if mask is None:
            obs = _numpy(self.foraging.reset(self.tasks, generator=torch_seed(self.np_random)), np.float32)
            self._autoreset[:] = False
        else:
            mask = np.asarray(mask)
            if mask.shape != (self.num_envs,) or mask.dtype != np.bool_ or not mask.any():
                raise ValueError(f"options['reset_mask'] must be a bool array of shape ({self.num_envs},) "
                                 f"with at least one True, got {mask!r}")
            if self._last_obs is None:
                raise RuntimeError("reset the whole batch (no reset_mask) before a partial reset")
            # as SyncVectorEnv: the other sub-environments keep the observation they last returned
            obs = self._last_obs.copy()
            obs[mask] = _numpy(self._reset_rows(mask), np.float32)[mask]
            self._autoreset[mask] = False
        self._last_obs = obs
        return obs.copy(), {}

    def _reset_rows(self, mask: np.ndarray) -> torch.Tensor:
        """Fresh initial states for the sub-environments in ``mask``, the others untouched.
        Returns the whole batch's observations (only the rows of ``mask`` are meant to be used:
        the others are a fresh read of the arena)."""
        return self.foraging.reset_done(self.tasks, torch_seed(self.np_random),
                                        mask=torch.as_tensor(mask, device=self.foraging.device))

    def step(self, actions):
        if self._last_obs is None:
            raise RuntimeError("call reset before step")
        wheels = np.asarray(actions, dtype=np.float32)
        if wheels.shape != self.action_space.shape:
            raise ValueError(f"actions must have shape {self.action_space.shape} (envs, agents, wheels), got {wheels.shape}")
        wheels = np.clip(wheels, self.action_space.low, self.action_space.high)
        pending = self._autoreset.copy()
        # ended environments are frozen by ForagingEnv (no motion, reward 0): step the whole
        # batch, then replace the ones that had ended before this step by fresh episodes
        obs, reward, done, info = self.foraging.step(torch.as_tensor(wheels, device=self.foraging.device))
        obs = _numpy(obs, np.float32)
        reward = _numpy(reward, np.float64)
        done = _numpy(done, np.bool_)
        ended = done & ~pending
        terminated = ended & _numpy(info["terminated"], np.bool_)
        truncated = ended & _numpy(info["truncated"], np.bool_)
        info = {key: _numpy(info[key]) for key in _INFO_KEYS}
        if pending.any():
            # only the reset rows of the fresh read are used: the others keep the step's
            # observations, in which a box dropped this step is still unseen (the spec)
            obs[pending] = _numpy(self._reset_rows(pending), np.float32)[pending]
            reward[pending] = 0.0
        for key in _INFO_KEYS:
            info[f"_{key}"] = ~pending
        self._autoreset = terminated | truncated
        self._last_obs = obs
        return obs.copy(), reward, terminated, truncated, info

    def set_task(self, task: str | Task | Sequence[str | Task]) -> None:
        """Change the task of the running episodes and of later resets (a drift)."""
        self.tasks = self._as_tasks(task)
        if self._last_obs is not None:
            self.foraging.set_tasks(self.tasks)

    def render(self):
        if self.render_mode == "rgb_array":
            state = self.foraging.state
            return tuple(render_arena(state, i, self.config) for i in range(self.num_envs))
        return None


# ---------------------------------------------------------------------- registration
def register_envs() -> None:
    """Register ``lifelong_evo/SwarmForaging-v0`` (entry point and vector entry point) once."""
    if ENV_ID not in gymnasium.registry:
        gymnasium.register(id=ENV_ID, entry_point="envs.gym_env:SwarmForagingEnv",
                           vector_entry_point="envs.gym_env:SwarmForagingVectorEnv")
