"""The foraging arena's rules (docs/environment.md) for a batch of environments, in pure torch.

Top to bottom it follows docs/environment.md: the robots' kinematics and actions, tasks, the
initial state (reset), sensing and the observation, the step (move, pick, drop, rewards,
respawn, count and end) and the respawn stream. Every environment carries its own task (target
colour, season colours, nest edge, reward values, failed robots, motor gain) as per-environment
tensors, so one call can score a population on several tasks. The step has no Python loop over
environments or agents.

Coordinates are ``(x, y)`` with x the vertical axis: x = 0 is the top edge, where the paper's
drop zone is. Another nest edge is the paper's arena mirrored or transposed (``ZONE_FRAMES``):
initial states and respawn cells are drawn in the paper's frame and carried over, and the drop
test reads the distance to the nest edge (``NEST_DEPTH``), which for the top edge is ``x`` itself,
so that the paper's task computes the very same numbers. Boxes always sit on integer cells
(placement and respawn draw integers), which is what makes the vectorised pick resolution
(``_move_and_reach``, ``_resolve_conflicts``) exact.

Beside the rules: the state in its two layouts (``envs/state.py``), the sensing helpers
(``envs/sensing.py``) and how the step runs, eagerly, compiled or as a CUDA graph
(``envs/execution.py``, whose ``StepExecution`` ``ForagingEnv`` inherits).
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

import torch

from .config import AGENT, DROP_ZONES, WALL, ConfigError, ForagingConfig, Task
from .execution import StepExecution
from . import numerics
from .sensing import OrderKeys, batch_first, distance, one_hot_rows
from .state import Arena, ForagingState

KINEMATICS = ((-0.28867513, -0.57735027, 0.8660254), (0.5, -1.0, 0.5), (0.5, 0.0, 0.5))
"""(vx, vy, r) = KINEMATICS @ wheel speeds, for the three omni-wheels."""
WHEEL_RADIUS_FACTOR = 12.5
"""r / 12.5 is the angular velocity (the original code divides by half the robot size in cm)."""
BOX_LOW = (6, 2)
"""Lowest (x, y) cell a box is placed or respawned on; the highest is size - 2."""
MIN_BOX_SPACING = 2.0
"""Initial boxes are redrawn until this far from every earlier box."""
_HASH_MASK = 0x7FFFFFFF
ZONE_FRAMES = ((1, 0, 0, 0, 1, 0), (-1, 0, 1, 0, 1, 0), (0, 1, 0, 1, 0, 0), (0, 1, 0, -1, 0, 1))
"""Per nest edge (``DROP_ZONES`` order), how a cell ``(x, y)`` of the paper's frame (nest on top)
lies in the task's arena: ``x' = a x + b y + c m``, ``y' = d x + e y + f m`` for the row
``(a, b, c, d, e, f)``, with ``m = floor(size)``: top as it is, bottom mirrored (``m - x``), left
transposed (``(y, x)``), right transposed and mirrored (``(y, m - x)``). Integer cells stay integer."""
ZONE_HEADINGS = ((1, 0), (-1, 180), (-1, 90), (1, -90))
"""Per nest edge, a heading ``h`` of the paper's frame becomes ``(s h + o) mod 360`` for ``(s, o)``."""
NEST_DEPTH = ((1, 0, 0), (-1, 0, 1), (0, 1, 0), (0, -1, 1))
"""Per nest edge, a robot's distance to the nest edge is ``(a x + b y) + c size`` for ``(a, b, c)``:
``x``, ``size - x``, ``y``, ``size - y``. The robot is in the nest when it is below 1."""


def outputs_to_wheels(outputs: torch.Tensor, config: ForagingConfig) -> torch.Tensor:
    """Controller outputs in [0, 1] -> wheel speeds ``(2 * out - 1) * max_wheel_velocity``."""
    return (2.0 * outputs - 1.0) * config.max_wheel_velocity


class ForagingEnv(StepExecution):
    """A batch of ``batch_size`` foraging arenas on ``device``.

    ``reset`` samples (or takes) initial states and returns observations ``(B, A, obs_dim)``;
    ``step(wheels)`` takes wheel speeds ``(B, A, 3)`` and returns
    ``(observations, rewards (B,), done (B,), info)``; ``state`` reads the full state out.
    ``compile`` and ``graph_step`` (from ``StepExecution``) change how the step runs, not what it
    computes.
    """

    def __init__(self, config: ForagingConfig | None = None, batch_size: int = 1,
                 device: str | torch.device = "cpu", dtype: torch.dtype = torch.float32):
        self.config = config or ForagingConfig()
        if batch_size < 1:
            raise ConfigError(f"batch_size must be >= 1, got {batch_size}")
        if dtype not in (torch.float32, torch.float64):
            raise ConfigError(f"dtype must be torch.float32 or torch.float64, got {dtype}")
        self.batch_size = batch_size
        self.device = torch.device(device)
        self.dtype = dtype
        c = self.config
        self._kinematics_t = torch.tensor(KINEMATICS, dtype=dtype, device=self.device).T.contiguous()
        self._slot_type_offsets = (torch.arange(c.n_neighbors, device=self.device) * c.n_types)[:, None, None]
        self._box_ids = torch.arange(c.n_boxes, dtype=torch.int32, device=self.device)[:, None]
        self._cells_per_row = math.ceil(c.size) + 1  # box coordinates are integers in [0, size]
        self._cell_count = self._cells_per_row ** 2
        self._earlier_agents = torch.ones(c.n_agents, c.n_agents, dtype=torch.int32, device=self.device).tril(-1)[..., None]
        self._color_ids = torch.arange(3, 3 + c.n_colors, dtype=torch.int32, device=self.device)[:, None]
        self._agent_ids = torch.arange(c.n_agents, dtype=torch.int32, device=self.device)[:, None]
        mirror = math.floor(c.size)
        self._zone_frames = torch.tensor([[a, b, c_ * mirror, d, e, f * mirror] for a, b, c_, d, e, f in ZONE_FRAMES],
                                         dtype=torch.int32, device=self.device)
        self._nest_depth = torch.tensor([[a, b, k * c.size] for a, b, k in NEST_DEPTH], dtype=dtype, device=self.device)
        # candidates: 4 walls (whose distances go down to -1: the spec's "- 1"), agents, boxes;
        # farther than the sensor range nothing is sensed or picked, so distances clamp above it
        self._first_agent = 4
        self._first_box = 4 + (c.n_agents if c.see_other_agents else 0)
        self._keys = OrderKeys(self._first_box + c.n_boxes, low=-1.0, high=max(c.sensor_range, c.sensitivity) + 0.5)
        self._arena: Arena | None = None

    # ------------------------------------------------------------------ tasks and reset
    def task_tensors(self, tasks: Task | Sequence[Task], n: int | None = None) -> dict[str, torch.Tensor]:
        """The task fields of a ``ForagingState`` (``target``, ``season``, ``drop_zone``,
        ``rewards``, ``failed_robots``, ``motor_gain``), batch first, for one task or one task per
        environment, on the CPU (the state's floats in the environment's dtype)."""
        n = self.batch_size if n is None else n
        if isinstance(tasks, Task):
            tasks = [tasks] * n
        tasks = list(tasks)
        if len(tasks) != n:
            raise ConfigError(f"got {len(tasks)} tasks for {n} environments: give one task or one per environment")
        for task in set(tasks):
            self.config.check_task(task)
        season = torch.zeros(n, self.config.n_colors, dtype=torch.bool)
        for i, task in enumerate(tasks):
            season[i, [color - 3 for color in task.season]] = True
        return {"target": torch.tensor([t.target for t in tasks], dtype=torch.long), "season": season,
                "drop_zone": torch.tensor([t.drop_zone_id for t in tasks], dtype=torch.long),
                "rewards": torch.tensor([t.rewards.values() for t in tasks], dtype=torch.float64).to(self.dtype),
                "failed_robots": torch.tensor([t.failed_robots for t in tasks], dtype=torch.long),
                "motor_gain": torch.tensor([t.motor_gain for t in tasks], dtype=torch.float64).to(self.dtype)}

    def set_tasks(self, tasks: Task | Sequence[Task]) -> None:
        """Change the task of running episodes (a drift); boxes keep their colours and robots
        their places: a new nest edge applies from the next step, respawns included."""
        if self._arena is None:
            raise ConfigError("set_tasks changes running episodes: call reset first")
        for name, value in self.task_tensors(tasks).items():
            current = getattr(self._arena, name)
            if self._in_place:
                current.copy_(value)  # a captured CUDA graph reads these very buffers
            else:  # a new tensor: the state given to reset may share the current one
                setattr(self._arena, name, value.to(current.device, current.dtype))

    def sample_state(self, tasks: Task | Sequence[Task], generator: torch.Generator | int | None = None,
                     n: int | None = None) -> ForagingState:
        """Draw ``n`` (default: the batch size) initial states by the spec's reset rules."""
        generator = _as_generator(generator)
        n = self.batch_size if n is None else n
        task = self.task_tensors(tasks, n)
        target = task["target"]
        c = self.config
        box_pos = self._sample_box_cells(generator, n)
        n_target = int(c.n_boxes * c.rate_target)
        others = task["season"].clone()
        others[torch.arange(n), target - 3] = False
        colors = torch.empty(n, c.n_boxes, dtype=torch.long)
        colors[:, :n_target] = target[:, None]
        if n_target < c.n_boxes:
            drawn = torch.multinomial(others.double(), c.n_boxes - n_target, replacement=True, generator=generator)
            colors[:, n_target:] = drawn + 3
        colors = colors.gather(1, torch.rand(n, c.n_boxes, generator=generator).argsort(dim=1))
        u = torch.rand(n, c.n_agents, 3, generator=generator, dtype=torch.float64) * 2 - 1
        slots = torch.arange(1, c.n_agents + 1, dtype=torch.float64) * c.size / (c.n_agents + 1)
        agent_pos = torch.stack((2 + u[..., 0], slots + u[..., 1]), dim=-1)
        heading = 180 + 10 * u[..., 2]
        key = torch.randint(0, _HASH_MASK, (n,), generator=generator)
        agent_pos, heading, box_pos = self._to_nest_frames(task["drop_zone"], agent_pos, heading, box_pos)
        dev = self.device
        return ForagingState(
            agent_pos=agent_pos.to(dev, self.dtype), heading=heading.to(dev, self.dtype),
            carrying=torch.full((n, c.n_agents), -1, dtype=torch.long, device=dev),
            box_pos=box_pos.to(dev, self.dtype), box_color=colors.to(dev),
            box_present=torch.ones(n, c.n_boxes, dtype=torch.bool, device=dev),
            **{name: value.to(dev) for name, value in task.items()},
            steps=torch.zeros(n, dtype=torch.long, device=dev),
            retrieved=torch.zeros(n, dtype=torch.long, device=dev),
            done=torch.zeros(n, dtype=torch.bool, device=dev),
            respawn_key=key.to(dev))

    def _to_nest_frames(self, drop_zone, agent_pos, heading, box_pos):
        """Initial positions and headings drawn in the paper's frame (float64, CPU), carried into
        each environment's frame by its nest edge (``ZONE_FRAMES``, ``ZONE_HEADINGS``).
        Environments with the nest on top keep the drawn values as they are."""
        if not bool((drop_zone != 0).any()):
            return agent_pos, heading, box_pos
        frame = self._zone_frames.cpu()[drop_zone].double()[:, None, :]                 # (n, 1, 6)
        turn = torch.tensor(ZONE_HEADINGS, dtype=torch.float64)[drop_zone][:, None, :]    # (n, 1, 2)

        def carried(points):
            x, y = points[..., 0], points[..., 1]
            return torch.stack((frame[..., 0] * x + frame[..., 1] * y + frame[..., 2],
                                frame[..., 3] * x + frame[..., 4] * y + frame[..., 5]), dim=-1)

        on_top = (drop_zone == 0)[:, None]
        return (torch.where(on_top[..., None], agent_pos, carried(agent_pos)),
                torch.where(on_top, heading, torch.remainder(turn[..., 0] * heading + turn[..., 1], 360.0)),
                torch.where(on_top[..., None], box_pos, carried(box_pos)))

    def _sample_box_cells(self, generator: torch.Generator, n: int) -> torch.Tensor:
        """Integer cells, each redrawn until ``MIN_BOX_SPACING`` from the boxes before it."""
        c = self.config
        high = int(c.size) - 1
        lows = torch.tensor(BOX_LOW, dtype=torch.float64)
        spans = torch.tensor([high - BOX_LOW[0], high - BOX_LOW[1]], dtype=torch.float64)
        cells = torch.empty(n, c.n_boxes, 2, dtype=torch.float64)
        tries = 16  # candidates drawn at once per environment; the first valid one is the draw
        for k in range(c.n_boxes):
            pending = torch.ones(n, dtype=torch.bool)
            while pending.any():
                rows = pending.nonzero().squeeze(1)
                draw = lows + (torch.rand(len(rows), tries, 2, generator=generator, dtype=torch.float64) * spans).floor()
                if k == 0:
                    ok = torch.ones(len(rows), tries, dtype=torch.bool)
                else:
                    ok = (torch.cdist(draw, cells[rows, :k]) >= MIN_BOX_SPACING).all(dim=-1)
                found = ok.any(dim=1)
                chosen = draw[torch.arange(len(rows)), ok.int().argmax(dim=1)]
                cells[rows[found], k] = chosen[found]
                pending[rows[found]] = False
        return cells

    def reset(self, tasks: Task | Sequence[Task] | None = None, generator: torch.Generator | int | None = None,
              state: ForagingState | None = None) -> torch.Tensor:
        """Start new episodes: sampled for ``tasks`` from ``generator`` (or a seed), or the
        explicit ``state`` (validated). Returns the observations ``(B, A, obs_dim)``."""
        if state is None:
            if tasks is None:
                raise ConfigError("reset needs tasks (to sample initial states) or an explicit state")
            state = self.sample_state(tasks, generator)
        else:
            state = self._checked_state(state)
        self._start(Arena.from_state(state))
        return self._observe_arena()

    def reset_done(self, tasks: Task | Sequence[Task], generator: torch.Generator | int | None = None,
                   mask: torch.Tensor | None = None) -> torch.Tensor:
        """Replace environments with fresh episodes (autoreset): those in ``mask`` (B,), by
        default every ended one. ``tasks``: one task, or one per environment of the batch.

        Returns a fresh read of every environment's observation; for an environment that was not
        reset it can differ from what ``step`` returned, since a box dropped in that step is
        visible from now on.
        """
        which = (self._arena.done if mask is None else mask.to(self.device)).nonzero().squeeze(1)
        if len(which):
            if not isinstance(tasks, Task):
                tasks = [tasks[i] for i in which.tolist()]
            self._arena.replace_environments_(which, Arena.from_state(self.sample_state(tasks, generator, n=len(which))))
        return self._observe_arena()

    def observe(self) -> torch.Tensor:
        """The observations of the current state (what the last reset or step returned)."""
        return self._observe_arena()

    @property
    def state(self) -> ForagingState:
        """A copy of the full current state, batch first."""
        return self._arena.to_state()

    def _checked_state(self, state: ForagingState) -> ForagingState:
        c, B = self.config, self.batch_size
        shapes = {"agent_pos": (B, c.n_agents, 2), "heading": (B, c.n_agents), "carrying": (B, c.n_agents),
                  "box_pos": (B, c.n_boxes, 2), "box_color": (B, c.n_boxes), "box_present": (B, c.n_boxes),
                  "target": (B,), "season": (B, c.n_colors), "drop_zone": (B,), "rewards": (B, 4),
                  "failed_robots": (B,), "motor_gain": (B,), "steps": (B,), "retrieved": (B,),
                  "done": (B,), "respawn_key": (B,)}
        for name, shape in shapes.items():
            got = tuple(getattr(state, name).shape)
            if got != shape:
                raise ConfigError(f"state.{name} has shape {got}, expected {shape} for this config and batch")
        state = state.to(self.device)
        state = replace(state, agent_pos=state.agent_pos.to(self.dtype), heading=state.heading.to(self.dtype),
                        box_pos=state.box_pos.to(self.dtype), rewards=state.rewards.to(self.dtype),
                        motor_gain=state.motor_gain.to(self.dtype))
        if not torch.equal(state.box_pos, state.box_pos.round()):
            raise ConfigError("state.box_pos must hold integer cells: the spec places and respawns boxes on cells")
        if ((state.box_pos < 0) | (state.box_pos > c.size)).any():
            raise ConfigError(f"state.box_pos must lie in the arena, [0, size={c.size}]")
        for name in ("box_color", "target"):
            ids = getattr(state, name)
            if ((ids < 3) | (ids > 2 + c.n_colors)).any():
                raise ConfigError(f"state.{name} holds colour ids outside this arena's colors {list(c.colors)}")
        carried = state.carrying[state.carrying >= 0]
        if (carried >= c.n_boxes).any():
            raise ConfigError(f"state.carrying holds box indices >= n_boxes={c.n_boxes}")
        if ((state.drop_zone < 0) | (state.drop_zone >= len(DROP_ZONES))).any():
            raise ConfigError(f"state.drop_zone must index envs.DROP_ZONES (0 to {len(DROP_ZONES) - 1})")
        if not state.rewards.isfinite().all():
            raise ConfigError("state.rewards must be finite")
        if ((state.failed_robots < 0) | (state.failed_robots >= c.n_agents)).any():
            raise ConfigError(f"state.failed_robots must be in 0 to n_agents - 1 = {c.n_agents - 1}")
        if not ((state.motor_gain > 0) & (state.motor_gain <= 1)).all():
            raise ConfigError("state.motor_gain must be in (0, 1]")
        return state

    # ------------------------------------------------------------------ sensing
    def _observe_arena(self) -> torch.Tensor:
        a = self._arena
        return batch_first(self._observe(a.ax, a.ay, a.heading, a.carrying, a.bx, a.by, a.color, a.present, a.target))

    def _box_order_keys(self, ax, ay, bx, by, present) -> torch.Tensor:
        """Every agent's order keys of every box, ``(K, A, B)``, absent boxes marked."""
        dist = distance(ax[None] - bx[:, None], ay[None] - by[:, None])
        return self._keys.keys(dist, (present == 0)[:, None], first=self._first_box)

    def _observe(self, ax, ay, heading, carrying, bx, by, color, present, target) -> torch.Tensor:
        """Observation vectors, feature-major ``(obs_dim, A, B)``, in the spec's order. The box
        keys are computed here, not handed over from ``_move_and_reach``: in the compiled graphs
        recomputing them is cheaper than storing and reloading ``(K, A, B)`` keys."""
        c = self.config
        n, rng = c.n_neighbors, c.sensor_range
        A, B = ax.shape
        wall = torch.stack((ax, c.size - ax - 1, ay, c.size - ay - 1))                      # (4, A, B)
        groups = [self._keys.keys(wall, wall >= rng, first=0),  # walls: strictly in range
                  self._box_order_keys(ax, ay, bx, by, present)]
        ex, ey, kind = bx, by, color                                                      # (N, B) others
        if c.see_other_agents:
            is_self = torch.eye(A, dtype=torch.bool, device=self.device)[..., None]
            dist = distance(ax[None] - ax[:, None], ay[None] - ay[:, None])
            groups.insert(1, self._keys.keys(dist, is_self, first=self._first_agent))
            ex, ey = torch.cat((ax, ex)), torch.cat((ay, ey))
            kind = torch.cat((torch.full((A, B), AGENT, device=self.device, dtype=torch.long), kind))
        slots = self._keys.smallest(groups, n)                                            # (n, A, B)
        number = self._keys.number(slots)
        is_wall = number < 4
        other = (number - 4).clamp(min=0, max=ex.shape[0] - 1).view(n * A, B)
        o_dx = ax - ex.gather(0, other).view(n, A, B)
        o_dy = ay - ey.gather(0, other).view(n, A, B)
        o_dist = distance(o_dx, o_dy)
        wall_side = number.clamp(max=3)
        w_dist = wall.gather(0, wall_side)
        s_dist = w_dist * is_wall + o_dist * ~is_wall
        present = ~self._keys.is_absent(slots)
        wall_seen = present & is_wall
        other_seen = present & ~is_wall & (o_dist <= rng)  # boxes and agents: range inclusive
        seen = wall_seen | other_seen
        # sin and cos of atan2(dy, dx) are dy/d and dx/d; an entity on the agent reads angle 0
        # sums of masked terms, not torch.where (several times slower on CPU); exact, since every
        # term but one is multiplied by zero and all are finite
        on_top = o_dist == 0
        safe = o_dist + on_top  # 1 where the entity sits on the agent
        # the walls top, bottom, left, right lie at 0, 180, 90, 270 degrees
        wall_sin = ((wall_side == 2).to(self.dtype) - (wall_side == 3).to(self.dtype)) * wall_seen
        wall_cos = ((wall_side == 0).to(self.dtype) - (wall_side == 1).to(self.dtype)) * wall_seen
        s_sin = wall_sin + (o_dy / safe) * (other_seen & ~on_top)
        s_cos = wall_cos + (o_dx / safe) * (other_seen & ~on_top) + (other_seen & on_top)
        s_kind = WALL * wall_seen + kind.gather(0, other).view(n, A, B) * other_seen
        carried = (color.gather(0, carrying.clamp(min=0)) - 2) * (carrying >= 0)           # (A, B)
        parts = torch.cat((
            one_hot_rows(s_kind + self._slot_type_offsets, n * c.n_types, self.dtype),
            s_dist * (seen / rng),
            s_sin,
            s_cos,
            *(part[None] for part in numerics.sin_cos_degrees(heading)),
            one_hot_rows(carried[None], c.n_colors + 1, self.dtype),
            (target == self._color_ids)[:, None].to(self.dtype).expand(-1, A, -1),
        ))                                                                                 # (obs_dim, A, B)
        return parts

    # ------------------------------------------------------------------ step
    def step(self, wheels: torch.Tensor):
        """Advance every environment one step with wheel speeds ``(B, A, 3)``.

        Returns ``(observations (B, A, obs_dim), rewards (B,), done (B,), info)``; ``info`` holds,
        per environment and agent, ``picked`` / ``dropped`` box indices (-1 for none),
        ``drop_correct`` and ``respawn_cell`` (the cell a dropped box went to, -1 otherwise), and
        per environment ``terminated`` (max retrievals reached) and ``truncated`` (duration reached).
        """
        return self._run_step(wheels)

    def _move_and_reach(self, wheels, ax, ay, heading, carrying, bx, by, present, done, failed_robots, motor_gain):
        """Steps 1 and 2 of the spec: the moved agents, and the box each agent picks, -1 for none,
        right unless two agents reach one cell. ``rank`` (A, B) > 0 marks agents that share their
        reachable cell with an earlier agent, ``top_rank`` is its largest value (then see
        ``_resolve_conflicts``); ``nearest`` is a valid box index throughout."""
        c = self.config
        # an ended environment stays frozen, and so does a failed robot
        acting = self._working(failed_robots) & ~done
        # kinematics in the arena frame; the worn motors' gain scales the motion (the kinematics
        # are linear, so this is the gain on every wheel speed): applied to the time step, not to
        # the wheels, it leaves native arithmetic's small matrix product fused into the compiled
        # step, and at the paper's gain of 1 it changes no bit
        velocity = self._kinematics(wheels.to(self.dtype).permute(2, 1, 0))                # (3, A, B)
        moving = acting.to(self.dtype) * (motor_gain * c.time_step)
        ax = (ax + velocity[0] * moving).clamp(0.0, c.size)
        ay = (ay + velocity[1] * moving).clamp(0.0, c.size)
        turn = torch.rad2deg(velocity[2] * (moving / WHEEL_RADIUS_FACTOR))
        heading = torch.remainder(heading + turn, 360.0)
        # boxes sit on integer cells and sensitivity <= 0.5, so an agent reaches at most one cell,
        # and its nearest box (lowest index on a tie) is the lowest-index box there
        K = bx.shape[0]
        nearest_key = self._box_order_keys(ax, ay, bx, by, present).amin(dim=0)          # (A, B)
        nearest = (self._keys.number(nearest_key) - self._first_box).clamp(min=0, max=K - 1)
        cx, cy = bx.gather(0, nearest), by.gather(0, nearest)
        wants = ((carrying < 0) & ~self._keys.is_absent(nearest_key)
                 & (distance(ax - cx, ay - cy) < c.sensitivity) & acting).to(torch.int32)
        wanted_cell = ((cx * self._cells_per_row + cy).to(torch.int32) + 1) * wants - 1  # -1: wants none
        same_cell = (wanted_cell[:, None] == wanted_cell[None]).to(torch.int32)            # (A, A, B)
        rank = (same_cell * self._earlier_agents).sum(1, dtype=torch.int32) * wants
        picked = (nearest + 1) * wants - 1
        return ax, ay, heading, picked, nearest, wants, rank, rank.amax()

    def _resolve_conflicts(self, nearest, wants, rank, top_rank, bx, by, present) -> torch.Tensor:
        """Box index each agent picks, -1 for none, ``(A, B)``, when agents share a cell.

        Sequential semantics (agents in index order, each taking its nearest present box) without
        a loop: the agents that reach the same cell take the boxes stacked there one each, the
        agent with rank r among them (by agent index) the r-th box after its nearest in the boxes'
        (cell, index) order, if the cell holds that many.
        """
        K = bx.shape[0]
        # unique keys ordering the boxes by (cell, index), absent boxes after every cell
        cell = (bx * self._cells_per_row + by).to(torch.int32) + self._cell_count * (1 - present)
        order = cell * K + self._box_ids                                                   # (K, B)
        nearest_order = order.gather(0, nearest)
        chosen = successor = nearest_order
        for r in range(1, top_rank + 1):  # the r-th successor, for the agents of rank r
            successor = OrderKeys.next_min(order[:, None], successor)
            chosen = chosen + (rank == r) * (successor - chosen)
        got = wants * (chosen // K == nearest_order // K)  # still in the same cell
        return (chosen % K + 1) * got - 1

    def _settle_and_sense(self, ax, ay, heading, picked, carrying, bx, by, color, present, target,
                          drop_zone, rewards, failed_robots, steps, retrieved, done, respawn_key):
        """Steps 3 to 5 of the spec once the picks are known: drops, rewards, respawns, the new
        observations and the termination. Returns ``(observations, rewards, changed arena
        fields, info)``."""
        c = self.config
        active = ~done
        picking = picked >= 0
        present = present * (self._box_flags(picked) == 0)
        carrying = torch.maximum(picked, carrying)  # an agent picks only when it carries nothing (-1)
        is_target = color.gather(0, carrying.clamp(min=0)) == target
        nest = self._nest_depth[drop_zone].T[..., None, :]                                  # (3, 1, B)
        # the top edge's depth is (x * 1 + y * 0) + 0, exactly x: the paper's x < 1
        in_nest = (ax * nest[0] + ay * nest[1]) + nest[2] < 1
        dropping = (carrying >= 0) & in_nest & self._working(failed_robots) & active
        drop_correct = dropping & is_target
        # event counts times each environment's values, added in a fixed order (the same bits on
        # every CPU, eager or compiled); integer values, the paper's, are exact
        picks_target = (picking & is_target).sum(dim=0, dtype=torch.int32)
        delivered_target = drop_correct.sum(dim=0, dtype=torch.int32)
        counts = (picks_target, picking.sum(dim=0, dtype=torch.int32) - picks_target,
                  delivered_target, dropping.sum(dim=0, dtype=torch.int32) - delivered_target)
        values = rewards.T
        reward = counts[0] * values[0]
        for count, value in zip(counts[1:], values[1:]):
            reward = reward + count * value
        # (x + 1) * flag - 1 is x where flag is set and -1 elsewhere
        dropped = (carrying + 1) * dropping - 1
        carrying = (carrying + 1) * ~dropping - 1
        # a box dropped this step stays absent until the next one
        observations = self._observe(ax, ay, heading, carrying, bx, by, color, present, target)
        respawn = torch.full((c.n_agents, ax.shape[1], 2), -1, dtype=torch.int32, device=self.device)
        # with repositioning off, a dropped box is gone; _must_respawn may skip a respawn that
        # places nothing
        if c.repositioning and self._must_respawn(dropping):
            cells = self._to_nest_frame(respawn_cells(respawn_key, steps, c.n_agents, int(c.size)), drop_zone)
            respawn = (cells + 1) * dropping[..., None] - 1
            bx, by, present = self._respawn(dropped, respawn, bx, by, present)
        retrieved = retrieved + delivered_target
        steps = steps + active.long()
        terminated, truncated = retrieved >= c.max_retrieves, steps >= c.duration
        arena = {"carrying": carrying, "bx": bx, "by": by, "present": present, "steps": steps,
                 "retrieved": retrieved, "done": done | terminated | truncated}
        info = {"picked": picked.T.long(), "dropped": dropped.T.long(), "drop_correct": drop_correct.T,
                "respawn_cell": respawn.transpose(0, 1).long(), "terminated": terminated, "truncated": truncated}
        return observations, reward, arena, info

    def _working(self, failed_robots: torch.Tensor) -> torch.Tensor:
        """(A, B) bool: the robots that work, all but the ``failed_robots`` (B,) highest-index ones."""
        return self._agent_ids < self.config.n_agents - failed_robots

    def _to_nest_frame(self, cells: torch.Tensor, drop_zone: torch.Tensor) -> torch.Tensor:
        """Cells ``(A, B, 2)`` int32 of the paper's frame in each environment's frame (``ZONE_FRAMES``)."""
        frame = self._zone_frames[drop_zone].T[..., None, :]                               # (6, 1, B)
        x, y = cells[..., 0], cells[..., 1]
        return torch.stack(((x * frame[0] + y * frame[1]) + frame[2], (x * frame[3] + y * frame[4]) + frame[5]), dim=-1)

    def _kinematics(self, wheels: torch.Tensor) -> torch.Tensor:
        """``KINEMATICS @ wheels`` for wheel speeds ``(3, A, B)``, summed term by term in a fixed
        order (a matrix product's order is its BLAS's choice, which differs between CPUs); under
        native numerics, the matrix product."""
        if numerics.native():
            return (wheels.permute(2, 1, 0) @ self._kinematics_t).permute(2, 1, 0)
        k = KINEMATICS
        return torch.stack([(wheels[0] * k[row][0] + wheels[1] * k[row][1]) + wheels[2] * k[row][2]
                            for row in range(3)])

    def _box_flags(self, box_index: torch.Tensor) -> torch.Tensor:
        """(A, B) box indices (-1 for none) -> (K, B) int32: 1 where some agent names the box."""
        flags = torch.zeros(self.config.n_boxes + 1, box_index.shape[1], dtype=torch.int32, device=self.device)
        return flags.scatter_(0, (box_index + 1).long(), 1)[1:]

    def _respawn(self, dropped, respawn, bx, by, present):
        """Put each dropped box on its respawn cell (row K collects the agents that dropped nothing)."""
        K, B = bx.shape
        slot = (dropped + (K + 1) * (dropped < 0)).long()
        spare = torch.zeros(1, B, dtype=self.dtype, device=self.device)
        bx = torch.cat((bx, spare)).scatter_(0, slot, respawn[..., 0].to(self.dtype))[:K]
        by = torch.cat((by, spare)).scatter_(0, slot, respawn[..., 1].to(self.dtype))[:K]
        return bx, by, present | self._box_flags(dropped)


def hash31(x: torch.Tensor) -> torch.Tensor:
    """A 31-bit integer mixer of non-negative 31-bit integers, identical on every device and in
    Python. In int32 the products wrap, which keeps their low 31 bits, all the mask keeps."""
    x = ((x >> 16) ^ x) * 0x45D9F3B & _HASH_MASK
    x = ((x >> 16) ^ x) * 0x45D9F3B & _HASH_MASK
    return (x >> 16) ^ x


def respawn_cells(key: torch.Tensor, steps: torch.Tensor, n_agents: int, size: int) -> torch.Tensor:
    """Cell where a box dropped by each agent at this step respawns: ``(A, B, 2)`` int32.

    A counter-based stream keyed by (environment key, step, agent): the k-th respawn of an
    environment does not depend on what else is in the batch, so every controller of a
    generation sees the same environments.
    """
    # int32 throughout: compiled CPU code handles int64 at half the vector width
    agents = torch.arange(n_agents, dtype=torch.int32, device=key.device)[:, None]
    base = hash31(hash31((key & _HASH_MASK).to(torch.int32)) ^ steps.to(torch.int32))[None, :] ^ (agents * 2)
    hx, hy = hash31(base), hash31(base ^ 1)
    high = size - 1
    x = BOX_LOW[0] + _remainder(hx, high - BOX_LOW[0])
    y = BOX_LOW[1] + _remainder(hy, high - BOX_LOW[1])
    return torch.stack((x, y), dim=-1)


def _remainder(h: torch.Tensor, n: int) -> torch.Tensor:
    """``h % n`` for int32 ``h >= 0`` and ``0 < n < 2**22``, by float64 division: exact here
    (the quotient's fraction, at least ``1 / n`` from the next integer, outlasts the rounding),
    and compiled CPU code vectorises it, while integer ``%`` runs element by element."""
    return h - (torch.floor(h.to(torch.float64) / n) * n).to(torch.int32)


def _as_generator(generator: torch.Generator | int | None) -> torch.Generator:
    if isinstance(generator, torch.Generator):
        return generator
    fresh = torch.Generator()
    if generator is None:
        fresh.seed()
    else:
        fresh.manual_seed(int(generator))
    return fresh
