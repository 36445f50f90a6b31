"""The batched swarm-foraging environment (its rules: docs/environment.md), in pure torch.

The state a user sees (``ForagingState``) has the batch of ``B`` environments as its first
dimension. Inside, the arena is kept batch-last (``(agents, B)``, ``(boxes, B)``), because the
per-step reductions over boxes then vectorise across environments; ``step`` has no Python loop
over environments or agents. Every environment carries its own task
(target colour and season colours), so one call can score a population on several tasks.

Coordinates are ``(x, y)`` with x the vertical axis: x = 0 is the top edge, where the drop zone
is. Boxes always sit on integer cells (placement and respawn draw integers), which is what makes
the vectorised pick resolution (``_move_and_reach``, ``_resolve_conflicts``) exact.
"""
from __future__ import annotations

import functools
import math
import threading
from dataclasses import dataclass, fields, replace
from typing import Sequence

import torch

from .config import AGENT, WALL, ConfigError, ForagingConfig, Task

KINEMATICS = ((-0.28867513, -0.57735027, 0.8660254), (0.5, -1.0, 0.5), (0.5, 0.0, 0.5))
"""(vx, vy, r) = KINEMATICS @ wheel speeds, for the three omni-wheels."""
WHEEL_RADIUS_FACTOR = 12.5
"""r / 12.5 is the angular velocity (the original code divides by half the robot size in cm)."""
BOX_LOW = (6, 2)
"""Lowest (x, y) cell a box is placed or respawned on; the highest is size - 2."""
MIN_BOX_SPACING = 2.0
"""Initial boxes are redrawn until this far from every earlier box."""
_HASH_MASK = 0x7FFFFFFF
_CAPTURE_LOCK = threading.Lock()
GRAPH_WARM_UP_STEPS = 3
"""Steps run (and undone) before a CUDA graph is captured: capture needs warmed-up kernels."""


@dataclass
class ForagingState:
    """The full state of a batch; every field has the batch as its first dimension."""

    agent_pos: torch.Tensor
    """(B, A, 2) float: agent (x, y)."""
    heading: torch.Tensor
    """(B, A) float: heading in degrees, [0, 360)."""
    carrying: torch.Tensor
    """(B, A) long: index of the carried box, -1 for none."""
    box_pos: torch.Tensor
    """(B, K, 2) float: box cell (meaningless while carried or gone)."""
    box_color: torch.Tensor
    """(B, K) long: colour id of each box."""
    box_present: torch.Tensor
    """(B, K) bool: the box lies in the arena (not carried, not gone)."""
    target: torch.Tensor
    """(B,) long: target colour id."""
    season: torch.Tensor
    """(B, n_colors) bool: colours the season may draw (index = colour - 3)."""
    steps: torch.Tensor
    """(B,) long: steps taken in this episode."""
    retrieved: torch.Tensor
    """(B,) long: correct retrievals in this episode."""
    done: torch.Tensor
    """(B,) bool: the episode has ended (max retrievals or duration)."""
    respawn_key: torch.Tensor
    """(B,) long: key of the counter-based stream that places respawned boxes."""

    def clone(self) -> "ForagingState":
        return ForagingState(**{f.name: getattr(self, f.name).clone() for f in fields(self)})

    def index(self, which) -> "ForagingState":
        """The sub-batch ``which`` (an index, slice, list or mask) of every field."""
        return ForagingState(**{f.name: getattr(self, f.name)[which] for f in fields(self)})

    def to(self, device) -> "ForagingState":
        return ForagingState(**{f.name: getattr(self, f.name).to(device) for f in fields(self)})

    @staticmethod
    def cat(states: Sequence["ForagingState"]) -> "ForagingState":
        return ForagingState(**{f.name: torch.cat([getattr(s, f.name) for s in states])
                                for f in fields(ForagingState)})


def outputs_to_wheels(outputs: torch.Tensor, config: ForagingConfig) -> torch.Tensor:
    """Controller outputs in [0, 1] -> wheel speeds ``(2 * out - 1) * max_wheel_velocity``."""
    return (2.0 * outputs - 1.0) * config.max_wheel_velocity


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


@dataclass
class _Arena:
    """The working state, batch-last; see ``ForagingState`` for the meaning of each field.
    Box and colour ids are int32 here: compiled CPU code handles them in half the vector
    width of int64 (and indexing accepts them). ``present`` is int32 0/1, not bool, because
    compiled CPU code loads and stores bool vectors element by element."""

    ax: torch.Tensor          # (A, B) agent x
    ay: torch.Tensor          # (A, B) agent y
    heading: torch.Tensor     # (A, B)
    carrying: torch.Tensor    # (A, B) int32, -1 for none
    bx: torch.Tensor          # (K, B) box x
    by: torch.Tensor          # (K, B) box y
    color: torch.Tensor       # (K, B) int32
    present: torch.Tensor     # (K, B) int32 0/1
    target: torch.Tensor      # (B,) int32
    season: torch.Tensor      # (B, n_colors)
    steps: torch.Tensor       # (B,)
    retrieved: torch.Tensor   # (B,)
    done: torch.Tensor        # (B,)
    respawn_key: torch.Tensor  # (B,)

    @staticmethod
    def from_state(s: ForagingState) -> "_Arena":
        return _Arena(
            ax=s.agent_pos[..., 0].T.contiguous(), ay=s.agent_pos[..., 1].T.contiguous(),
            heading=s.heading.T.contiguous(), carrying=s.carrying.T.to(torch.int32).contiguous(),
            bx=s.box_pos[..., 0].T.contiguous(), by=s.box_pos[..., 1].T.contiguous(),
            color=s.box_color.T.to(torch.int32).contiguous(), present=s.box_present.T.to(torch.int32).contiguous(),
            target=s.target.to(torch.int32), season=s.season, steps=s.steps, retrieved=s.retrieved, done=s.done,
            respawn_key=s.respawn_key)

    def clone(self) -> "_Arena":
        return _Arena(**{f.name: getattr(self, f.name).clone() for f in fields(self)})

    def copy_(self, other: "_Arena") -> None:
        """Overwrite every field in place with ``other``'s (the buffers a CUDA graph reads)."""
        for f in fields(self):
            getattr(self, f.name).copy_(getattr(other, f.name))

    def to_state(self) -> ForagingState:
        return ForagingState(
            agent_pos=torch.stack((self.ax.T, self.ay.T), -1), heading=self.heading.T.clone(),
            carrying=self.carrying.T.long(), box_pos=torch.stack((self.bx.T, self.by.T), -1),
            box_color=self.color.T.long(), box_present=self.present.T.bool(),
            target=self.target.long(), season=self.season.clone(), steps=self.steps.clone(),
            retrieved=self.retrieved.clone(), done=self.done.clone(), respawn_key=self.respawn_key.clone())


class _OrderKeys:
    """Integer order keys for (distance, candidate index) pairs, so that ``amin`` finds the
    nearest candidate and its index in one vectorised reduction (``argmin``, ``topk`` and sorts
    are far slower).

    Candidates are numbered in the spec's sensing order (walls top, bottom, left, right, then
    other agents, then boxes). A key is the distance in fixed point, clamped to
    ``[low, high]`` and shifted to be >= 0, then shifted left by ``index_bits`` and or-ed with
    the candidate's number: equal distances order by number, as the spec's stable sort does.
    Distances closer than ``1 / scale`` (2**-22, about 2.4e-7 units, for the paper's arena)
    count as tied. Bit 30 marks a candidate absent (never sensed), above every present key.
    """

    def __init__(self, n_candidates: int, low: float, high: float):
        self.index_bits = max(1, (n_candidates - 1).bit_length())
        self.index_mask = (1 << self.index_bits) - 1
        self.low, self.high = low, high
        self.absent = 1 << 30
        room = (self.absent >> self.index_bits) - 1  # the largest fixed-point distance that fits
        self.scale = float(2 ** math.floor(math.log2(room / (high - low))))
        # the scale is a power of two: scaling is exact, so the shift by -low is exact too
        self.origin = math.ceil(-low * self.scale)

    def keys(self, dist: torch.Tensor, absent: torch.Tensor, first: int) -> torch.Tensor:
        """``dist``: (N, A, B) distances of candidates ``first .. first + N - 1``; ``absent``: bool,
        broadcastable to it. Returns (N, A, B) int32 keys."""
        number = torch.arange(first, first + dist.shape[0], dtype=torch.int32, device=dist.device)
        tag = number.view(-1, *([1] * (absent.dim() - 1))) | (absent.to(torch.int32) << 30)
        fixed = (dist.clamp(min=self.low, max=self.high) * self.scale).to(torch.int32) + self.origin
        return (fixed << self.index_bits) | tag

    def number(self, key: torch.Tensor) -> torch.Tensor:
        return key & self.index_mask

    def is_absent(self, key: torch.Tensor) -> torch.Tensor:
        return key >= self.absent

    @staticmethod
    def next_min(keys: torch.Tensor, previous: torch.Tensor) -> torch.Tensor:
        """The smallest key above ``previous``: keys <= previous wrap to the top under the
        sign flip, so one ``amin`` suffices (no masked copy)."""
        shifted = (keys - (previous + 1)) ^ torch.iinfo(torch.int32).min
        found = (shifted.amin(dim=0) ^ torch.iinfo(torch.int32).min) + previous + 1
        # none left above ``previous``: the wrap-around gives ``previous`` back; mark it absent
        return found | ((found <= previous).to(torch.int32) << 30)

    def smallest(self, groups: Sequence[torch.Tensor], n: int) -> torch.Tensor:
        """The ``n`` smallest keys over the candidate groups (each (N_g, A, B)): ``(n, A, B)``."""
        best = [functools.reduce(torch.minimum, [group.amin(dim=0) for group in groups])]
        for _ in range(n - 1):
            best.append(functools.reduce(torch.minimum, [self.next_min(group, best[-1]) for group in groups]))
        return torch.stack(best)


class ForagingEnv:
    """A batch of ``batch_size`` foraging arenas on ``device``.

    ``reset`` samples (or takes) initial states and returns observations ``(B, A, obs_dim)``;
    ``step(wheels)`` takes wheel speeds ``(B, A, 3)`` and returns
    ``(observations, rewards (B,), done (B,), info)``; ``state`` reads the full state out.
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
        # candidates: 4 walls (whose distances go down to -1: the spec's "- 1"), agents, boxes;
        # farther than the sensor range nothing is sensed or picked, so distances clamp above it
        self._first_agent = 4
        self._first_box = 4 + (c.n_agents if c.see_other_agents else 0)
        self._keys = _OrderKeys(self._first_box + c.n_boxes, low=-1.0, high=max(c.sensor_range, c.sensitivity) + 0.5)
        self._arena: _Arena | None = None
        # graph_step: the in-place, sync-free step, and its CUDA graph once captured
        self._in_place = False
        self._capture = False
        self._graph: torch.cuda.CUDAGraph | None = None
        self._graph_wheels: torch.Tensor | None = None
        self._graph_outputs = None

    # ------------------------------------------------------------------ tasks and reset
    def task_tensors(self, tasks: Task | Sequence[Task], n: int | None = None):
        """(target (n,), season (n, n_colors)) for one task or one task per environment."""
        n = self.batch_size if n is None else n
        if isinstance(tasks, Task):
            tasks = [tasks] * n
        tasks = list(tasks)
        if len(tasks) != n:
            raise ConfigError(f"got {len(tasks)} tasks for {n} environments: give one task or one per environment")
        for task in set(tasks):
            self.config.check_task(task)
        target = torch.tensor([t.target for t in tasks], dtype=torch.long, device=self.device)
        season = torch.zeros(n, self.config.n_colors, dtype=torch.bool, device=self.device)
        for i, task in enumerate(tasks):
            season[i, [color - 3 for color in task.season]] = True
        return target, season

    def set_tasks(self, tasks: Task | Sequence[Task]) -> None:
        """Change the task of the running episodes (a drift); boxes keep their colours."""
        if self._arena is None:
            raise ConfigError("set_tasks changes running episodes: call reset first")
        target, self._arena.season = self.task_tensors(tasks)
        self._arena.target = target.to(torch.int32)

    def sample_state(self, tasks: Task | Sequence[Task], generator: torch.Generator | int | None = None,
                     n: int | None = None) -> ForagingState:
        """Draw ``n`` (default: the batch size) initial states by the spec's reset rules."""
        generator = _as_generator(generator)
        n = self.batch_size if n is None else n
        target, season = self.task_tensors(tasks, n)
        c = self.config
        box_pos = self._sample_box_cells(generator, n)
        n_target = int(c.n_boxes * c.rate_target)
        others = season.cpu().clone()
        others[torch.arange(n), target.cpu() - 3] = False
        colors = torch.empty(n, c.n_boxes, dtype=torch.long)
        colors[:, :n_target] = target.cpu()[:, None]
        if n_target < c.n_boxes:
            drawn = torch.multinomial(others.double(), c.n_boxes - n_target, replacement=True, generator=generator)
            colors[:, n_target:] = drawn + 3
        colors = colors.gather(1, torch.rand(n, c.n_boxes, generator=generator).argsort(dim=1))
        u = torch.rand(n, c.n_agents, 3, generator=generator, dtype=torch.float64) * 2 - 1
        slots = torch.arange(1, c.n_agents + 1, dtype=torch.float64) * c.size / (c.n_agents + 1)
        agent_pos = torch.stack((2 + u[..., 0], slots + u[..., 1]), dim=-1)
        key = torch.randint(0, _HASH_MASK, (n,), generator=generator)
        dev = self.device
        return ForagingState(
            agent_pos=agent_pos.to(dev, self.dtype), heading=(180 + 10 * u[..., 2]).to(dev, self.dtype),
            carrying=torch.full((n, c.n_agents), -1, dtype=torch.long, device=dev),
            box_pos=box_pos.to(dev, self.dtype), box_color=colors.to(dev),
            box_present=torch.ones(n, c.n_boxes, dtype=torch.bool, device=dev),
            target=target, season=season,
            steps=torch.zeros(n, dtype=torch.long, device=dev),
            retrieved=torch.zeros(n, dtype=torch.long, device=dev),
            done=torch.zeros(n, dtype=torch.bool, device=dev),
            respawn_key=key.to(dev))

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
        arena = _Arena.from_state(state)
        if self._in_place and self._arena is not None:
            self._arena.copy_(arena)  # the buffers a captured graph reads stay where they are
        else:
            # a copy: from_state shares some of the caller's tensors, which steps in place would change
            self._arena = arena.clone() if self._in_place else arena
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
            fresh = _Arena.from_state(self.sample_state(tasks, generator, n=len(which)))
            for name in fields(_Arena):
                current, new = getattr(self._arena, name.name), getattr(fresh, name.name)
                current.index_copy_(1 if name.name in _BATCH_LAST else 0, which, new)
        return self._observe_arena()

    def observe(self) -> torch.Tensor:
        """The observations of the current state (what the last reset or step returned)."""
        return self._observe_arena()

    def compile(self) -> None:
        """Compile the step with ``torch.compile``, as the two fused graphs around the rare
        pick conflicts: moving and reaching, then settling and sensing (static shapes: each
        batch size compiles once). Observations outside ``step`` stay eager.

        The graphs run under inductor's C++ wrapper, which releases the GIL: several Python
        threads, each stepping its own environment, then run in parallel (see
        ``lifelong_evo.evaluate``)."""
        # every gather index is clamped into range, so inductor's per-element index checks can go
        options = {"assert_indirect_indexing": False, "cpp_wrapper": True}
        self._move_and_reach = torch.compile(self._move_and_reach, dynamic=False, options=options)
        self._settle_and_sense = torch.compile(self._settle_and_sense, dynamic=False, options=options)
        self._graph = None  # a graph captured before would replay the eager step: capture again

    def graph_step(self, capture: bool | None = None) -> None:
        """Step so that a CUDA graph can replay the step: one launch instead of a few hundred
        small kernels. The state then lives in fixed buffers that every step overwrites in place
        (``reset`` copies into them), and nothing in the step waits for the device: pick
        conflicts are always resolved and dropped boxes always respawned, each an exact no-op
        where no agents collide and nobody drops. The numbers are the plain step's, bit for bit,
        and ``step`` still returns fresh tensors.

        ``capture`` (default: where the device is cuda) records the step as a CUDA graph at the
        first step after this call, and replays it from then on (one graph per environment, so
        one per batch shape, as with ``compile``; call ``compile`` first to capture the compiled
        step). ``capture=False`` runs the same in-place step without a graph, on any device."""
        if capture is None:
            capture = self.device.type == "cuda"
        if capture and self.device.type != "cuda":
            raise ConfigError(f"a CUDA graph needs a cuda device, not {self.device}: use graph_step(capture=False)")
        if self._arena is not None and not self._in_place:
            self._arena = self._arena.clone()
        self._in_place, self._capture, self._graph = True, capture, None

    @property
    def state(self) -> ForagingState:
        """A copy of the full current state, batch first."""
        return self._arena.to_state()

    def _checked_state(self, state: ForagingState) -> ForagingState:
        c, B = self.config, self.batch_size
        shapes = {"agent_pos": (B, c.n_agents, 2), "heading": (B, c.n_agents), "carrying": (B, c.n_agents),
                  "box_pos": (B, c.n_boxes, 2), "box_color": (B, c.n_boxes), "box_present": (B, c.n_boxes),
                  "target": (B,), "season": (B, c.n_colors), "steps": (B,), "retrieved": (B,),
                  "done": (B,), "respawn_key": (B,)}
        for name, shape in shapes.items():
            got = tuple(getattr(state, name).shape)
            if got != shape:
                raise ConfigError(f"state.{name} has shape {got}, expected {shape} for this config and batch")
        state = state.to(self.device)
        state = replace(state, agent_pos=state.agent_pos.to(self.dtype), heading=state.heading.to(self.dtype),
                        box_pos=state.box_pos.to(self.dtype))
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
        return state

    # ------------------------------------------------------------------ step
    def step(self, wheels: torch.Tensor):
        """Advance every environment one step with wheel speeds ``(B, A, 3)``.

        Returns ``(observations (B, A, obs_dim), rewards (B,), done (B,), info)``; ``info`` holds,
        per environment and agent, ``picked`` / ``dropped`` box indices (-1 for none),
        ``drop_correct`` and ``respawn_cell`` (the cell a dropped box went to, -1 otherwise), and
        per environment ``terminated`` (max retrievals reached) and ``truncated`` (duration reached).
        """
        if self._in_place:
            if not self._capture:
                return _fresh(self._step_in_place(wheels))
            if self._graph is None:
                self._capture_graph(wheels)
            self._graph_wheels.copy_(wheels)
            self._graph.replay()
            return _fresh(self._graph_outputs)
        a = self._arena
        ax, ay, heading, picked, nearest, wants, rank, top_rank = self._move_and_reach(
            wheels, a.ax, a.ay, a.heading, a.carrying, a.bx, a.by, a.present, a.done)
        top_rank = int(top_rank)
        if top_rank > 0:  # two agents reach one cell: rare, so resolved apart from the fused path
            picked = self._resolve_conflicts(nearest, wants, rank, top_rank, a.bx, a.by, a.present)
        observations, reward, arena, info = self._settle_and_sense(
            ax, ay, heading, picked, a.carrying, a.bx, a.by, a.color, a.present, a.target,
            a.steps, a.retrieved, a.done, a.respawn_key)
        self._arena = replace(a, ax=ax, ay=ay, heading=heading, **arena)
        return _batch_first(observations), reward, arena["done"], info

    def _step_in_place(self, wheels: torch.Tensor):
        """``step`` without waiting for the device, writing the new state into the arena's own
        buffers; returns the step's outputs (fresh tensors only until the next step)."""
        a = self._arena
        ax, ay, heading, picked, nearest, wants, rank, _ = self._move_and_reach(
            wheels, a.ax, a.ay, a.heading, a.carrying, a.bx, a.by, a.present, a.done)
        # an agent's rank is below n_agents; ranks that nobody holds leave every pick as it is
        picked = self._resolve_conflicts(nearest, wants, rank, self.config.n_agents - 1, a.bx, a.by, a.present)
        observations, reward, arena, info = self._settle_and_sense(
            ax, ay, heading, picked, a.carrying, a.bx, a.by, a.color, a.present, a.target,
            a.steps, a.retrieved, a.done, a.respawn_key)
        for name, value in {"ax": ax, "ay": ay, "heading": heading, **arena}.items():
            getattr(a, name).copy_(value)
        return _batch_first(observations), reward, a.done, info

    def _capture_graph(self, wheels: torch.Tensor) -> None:
        """Record ``_step_in_place`` as a CUDA graph reading ``_graph_wheels`` and the arena's
        buffers. The warm-up steps before it (which compile a compiled step and settle the
        allocator, as capture requires) change the state, which is then put back. One capture
        at a time in a process: evaluation threads capture their environments one by one."""
        with _CAPTURE_LOCK:
            self._graph_wheels = wheels.clone()
            saved = self._arena.clone()
            side = torch.cuda.Stream(self.device)
            side.wait_stream(torch.cuda.current_stream(self.device))
            with torch.cuda.stream(side):
                for _ in range(GRAPH_WARM_UP_STEPS):
                    self._step_in_place(self._graph_wheels)
            torch.cuda.current_stream(self.device).wait_stream(side)
            self._arena.copy_(saved)
            graph = torch.cuda.CUDAGraph()
            # records the kernels without running them; thread-local, so that another evaluation
            # thread stepping its own environment meanwhile does not break the capture
            with torch.cuda.graph(graph, capture_error_mode="thread_local"):
                self._graph_outputs = self._step_in_place(self._graph_wheels)
            self._graph = graph

    def _move_and_reach(self, wheels, ax, ay, heading, carrying, bx, by, present, done):
        """Steps 1 and 2 of the spec: the moved agents, and the box each agent picks, -1 for none,
        right unless two agents reach one cell. ``rank`` (A, B) > 0 marks agents that share their
        reachable cell with an earlier agent, ``top_rank`` is its largest value (then see
        ``_resolve_conflicts``); ``nearest`` is a valid box index throughout."""
        c = self.config
        active = ~done
        # kinematics in the arena frame; an ended environment stays frozen
        velocity = (wheels.to(self.dtype) @ self._kinematics_t).permute(2, 1, 0)     # (3, A, B)
        moving = active.to(self.dtype) * c.time_step
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
                 & (_distance(ax - cx, ay - cy) < c.sensitivity) & active).to(torch.int32)
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
            successor = _OrderKeys.next_min(order[:, None], successor)
            chosen = chosen + (rank == r) * (successor - chosen)
        got = wants * (chosen // K == nearest_order // K)  # still in the same cell
        return (chosen % K + 1) * got - 1

    def _settle_and_sense(self, ax, ay, heading, picked, carrying, bx, by, color, present, target,
                          steps, retrieved, done, respawn_key):
        """Steps 3 to 5 of the spec once the picks are known: drops, rewards, respawns, the new
        observations and the termination. Returns ``(observations, rewards, changed arena
        fields, info)``."""
        c = self.config
        active = ~done
        picking = picked >= 0
        present = present * (self._box_flags(picked) == 0)
        carrying = torch.maximum(picked, carrying)  # an agent picks only when it carries nothing (-1)
        is_target = color.gather(0, carrying.clamp(min=0)) == target
        dropping = (carrying >= 0) & (ax < 1) & active
        drop_correct = dropping & is_target
        reward = ((2 * is_target - 1) * picking + 2 * drop_correct).sum(dim=0, dtype=torch.int32)
        # (x + 1) * flag - 1 is x where flag is set and -1 elsewhere
        dropped = (carrying + 1) * dropping - 1
        carrying = (carrying + 1) * ~dropping - 1
        # a box dropped this step stays absent until the next one
        observations = self._observe(ax, ay, heading, carrying, bx, by, color, present, target)
        respawn = torch.full((c.n_agents, ax.shape[1], 2), -1, dtype=torch.int32, device=self.device)
        # with repositioning off, a dropped box is gone. Eagerly, skipping the respawn when nobody
        # drops saves time; in a compiled graph the branch would split the graph, which costs more
        # than the fused respawn
        # (is_compiling first: a compiled graph then never reads, nor guards on, _in_place)
        if c.repositioning and (torch.compiler.is_compiling() or self._in_place or bool(dropping.any())):
            respawn = (respawn_cells(respawn_key, steps, c.n_agents, int(c.size)) + 1) * dropping[..., None] - 1
            bx, by, present = self._respawn(dropped, respawn, bx, by, present)
        retrieved = retrieved + drop_correct.sum(dim=0, dtype=torch.int32)
        steps = steps + active.long()
        terminated, truncated = retrieved >= c.max_retrieves, steps >= c.duration
        arena = {"carrying": carrying, "bx": bx, "by": by, "present": present, "steps": steps,
                 "retrieved": retrieved, "done": done | terminated | truncated}
        info = {"picked": picked.T.long(), "dropped": dropped.T.long(), "drop_correct": drop_correct.T,
                "respawn_cell": respawn.transpose(0, 1).long(), "terminated": terminated, "truncated": truncated}
        return observations, reward.to(self.dtype), arena, info

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

    # ------------------------------------------------------------------ sensing
    def _observe_arena(self) -> torch.Tensor:
        a = self._arena
        return _batch_first(self._observe(a.ax, a.ay, a.heading, a.carrying, a.bx, a.by, a.color, a.present, a.target))

    def _box_order_keys(self, ax, ay, bx, by, present) -> torch.Tensor:
        """Every agent's order keys of every box, ``(K, A, B)``, absent boxes marked."""
        dist = _distance(ax[None] - bx[:, None], ay[None] - by[:, None])
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
            dist = _distance(ax[None] - ax[:, None], ay[None] - ay[:, None])
            groups.insert(1, self._keys.keys(dist, is_self, first=self._first_agent))
            ex, ey = torch.cat((ax, ex)), torch.cat((ay, ey))
            kind = torch.cat((torch.full((A, B), AGENT, device=self.device, dtype=torch.long), kind))
        slots = self._keys.smallest(groups, n)                                            # (n, A, B)
        number = self._keys.number(slots)
        is_wall = number < 4
        other = (number - 4).clamp(min=0, max=ex.shape[0] - 1).view(n * A, B)
        o_dx = ax - ex.gather(0, other).view(n, A, B)
        o_dy = ay - ey.gather(0, other).view(n, A, B)
        o_dist = _distance(o_dx, o_dy)
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
        heading_rad = torch.deg2rad(heading)
        carried = (color.gather(0, carrying.clamp(min=0)) - 2) * (carrying >= 0)           # (A, B)
        parts = torch.cat((
            _one_hot_rows(s_kind + self._slot_type_offsets, n * c.n_types, self.dtype),
            s_dist * (seen / rng),
            s_sin,
            s_cos,
            torch.sin(heading_rad)[None], torch.cos(heading_rad)[None],
            _one_hot_rows(carried[None], c.n_colors + 1, self.dtype),
            (target == self._color_ids)[:, None].to(self.dtype).expand(-1, A, -1),
        ))                                                                                 # (obs_dim, A, B)
        return parts


def _fresh(outputs):
    """Copies of a step's outputs (observations, rewards, done, info), which the in-place step
    and its graph overwrite at the next step."""
    observations, reward, done, info = outputs
    return observations.clone(), reward.clone(), done.clone(), {k: v.clone() for k, v in info.items()}


def _batch_first(features: torch.Tensor) -> torch.Tensor:
    """``(obs_dim, A, B)`` -> ``(B, A, obs_dim)``. Kept out of the compiled graph: torch's copy
    kernel transposes faster than the compiled loop, which also had to write ``features`` first."""
    return features.permute(2, 1, 0).contiguous()


def _one_hot_rows(index: torch.Tensor, n_rows: int, dtype: torch.dtype) -> torch.Tensor:
    """``(n_rows, *index.shape[1:])`` with a 1 in row ``index[j]`` for every ``j``: a scatter, so
    that compiled code computes ``index`` once, not once per row."""
    rows = torch.zeros(n_rows, *index.shape[1:], dtype=dtype, device=index.device)
    return rows.scatter_(0, index.long(), 1.0)


def _distance(dx: torch.Tensor, dy: torch.Tensor) -> torch.Tensor:
    """Euclidean distance; every distance of the env goes through here, so equal inputs give
    equal floats wherever they are computed."""
    return torch.sqrt(dx * dx + dy * dy)


_BATCH_LAST = {"ax", "ay", "heading", "carrying", "bx", "by", "color", "present"}


def _as_generator(generator: torch.Generator | int | None) -> torch.Generator:
    if isinstance(generator, torch.Generator):
        return generator
    fresh = torch.Generator()
    if generator is None:
        fresh.seed()
    else:
        fresh.manual_seed(int(generator))
    return fresh
