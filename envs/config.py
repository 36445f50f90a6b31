"""Environment options and tasks, validated in one place.

Defaults are the paper's (docs/environment.md). Lengths are in robot diameters.
"""
from __future__ import annotations

import math
import numbers
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, fields

COLOR_IDS: dict[str, int] = {
    "red": 3, "blue": 4, "green": 5, "yellow": 6, "purple": 7, "white": 8, "cyan": 9, "black": 10,
}
"""Entity type ids of the box colours (0 nothing, 1 wall, 2 agent)."""
COLOR_NAMES: dict[int, str] = {v: k for k, v in COLOR_IDS.items()}
COLOR_RGB: dict[int, tuple[int, int, int]] = {
    3: (228, 26, 28),     # red
    4: (55, 126, 184),    # blue
    5: (60, 170, 60),     # green
    6: (240, 200, 0),     # yellow
    7: (152, 78, 163),    # purple
    8: (235, 235, 235),   # white
    9: (0, 185, 210),     # cyan
    10: (25, 25, 25),     # black
}
"""Display colour of each colour id: ``render``, the figures and the recordings all draw with it."""
UNKNOWN_RGB = (150, 150, 150)
"""Display colour of an id without one of its own, and of an empty gripper."""
NOTHING, WALL, AGENT = 0, 1, 2


class ConfigError(ValueError):
    """A configuration value that cannot work; the message names the field and the fix."""


DROP_ZONES: tuple[str, ...] = ("top", "bottom", "left", "right")
"""The arena edges a task's nest (drop zone) can lie on; the index is the state's ``drop_zone`` id."""
MAX_REWARD = 1e6
"""The largest magnitude of a reward value. The step sums rewards in the environment's dtype,
float32 by default: an episode holds at most two events per robot and step, so at the options'
bounds (1000 robots, 100000 steps) its sum stays below 2e14, far inside float32's range
(3.4e38), and so do the means and sums the optimisers take over episodes and populations.
Values near float32's range would overflow to infinity or round to another value."""
MIN_MOTOR_GAIN = 1e-6
"""The smallest motor gain: a factor below it leaves every robot as good as still (at the
paper's speeds a step would move one by 2e-7, below a float32 position's resolution), and far
below it float32, the step's dtype, rounds the factor to 0."""


def shown(value) -> str:
    """``repr(value)`` in one readable line: a value of thousands of digits cut in the middle."""
    text = repr(value)
    return text[:40] + "..." + text[-10:] if len(text) > 60 else text


def _number(value: float) -> str:
    """A bound as one writes it: ``1e6``, ``1e-6``."""
    return f"{value:g}".replace("e+0", "e").replace("e-0", "e-")


def _real(value) -> float | None:
    """``value`` as a float if it is a real number (``numbers.Real``, numpy's included; not a
    bool) that a float holds, else None."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        return None
    try:
        return float(value)
    except OverflowError:  # an integer of hundreds of digits
        return None


@dataclass(frozen=True)
class Rewards:
    """The value of each reward event (docs/environment.md, Rewards); the paper's by default.
    Any real numbers from ``-MAX_REWARD`` to ``MAX_REWARD``: a step's reward is each event's count
    times its value, summed."""

    pick_target: float = 1.0
    """Picking up a box of the target colour."""
    pick_other: float = -1.0
    """Picking up a box of any other colour."""
    deliver_target: float = 2.0
    """Dropping a target box in the nest (a correct retrieval)."""
    deliver_other: float = 0.0
    """Dropping a box of another colour in the nest."""

    def __post_init__(self):
        for f in fields(self):
            value = _real(getattr(self, f.name))
            if value is None or not abs(value) <= MAX_REWARD:  # NaN fails the comparison
                raise ConfigError(f"reward {f.name} must be a number from -{_number(MAX_REWARD)} to "
                                  f"{_number(MAX_REWARD)} (the step sums rewards in float32: docs/environment.md, "
                                  f"Rewards), got {shown(getattr(self, f.name))}")
            object.__setattr__(self, f.name, value)

    def values(self) -> tuple[float, float, float, float]:
        """The four values in the order of the state's ``rewards`` columns."""
        return self.pick_target, self.pick_other, self.deliver_target, self.deliver_other


@dataclass(frozen=True)
class Task:
    """A foraging task: the colour to fetch and the colours boxes may have this season, and the
    drifts beyond the paper's (the nest's edge, the reward values, failed robots, worn motors).
    The defaults of the drift fields are the paper's, so ``Task(3, (3, 4))`` is its red task."""

    target: int
    """Colour id of the boxes that earn reward."""
    season: tuple[int, ...]
    """Colour ids boxes are drawn from; must contain ``target``."""
    name: str = ""
    """Display name; defaults to the target colour's name."""
    drop_zone: str = "top"
    """The edge that is the nest: top (the paper's), bottom, left or right, 1 unit deep."""
    rewards: Rewards = Rewards()
    """The reward of each event."""
    failed_robots: int = 0
    """How many robots (the highest-index ones) do nothing: they neither move nor pick nor drop."""
    motor_gain: float = 1.0
    """Factor from ``MIN_MOTOR_GAIN`` to 1 on every robot's wheel speeds."""

    def __post_init__(self):
        object.__setattr__(self, "season", tuple(int(c) for c in self.season))
        if not self.name:
            object.__setattr__(self, "name", COLOR_NAMES.get(self.target, f"colour{self.target}"))
        where = f"task {self.name!r}"
        if self.target not in self.season:  # no box could ever be the target
            target = _colour_name(self.target)
            raise ConfigError(f"{where}: target {target} is not in its season "
                              f"[{', '.join(map(_colour_name, self.season))}]: add {target} to the season")
        if isinstance(self.rewards, Mapping):
            valid = [f.name for f in fields(Rewards)]
            unknown = sorted(set(self.rewards) - set(valid))
            if unknown:
                raise ConfigError(f"{where}: unknown reward(s) {unknown}: valid ones are {', '.join(valid)}")
            try:
                object.__setattr__(self, "rewards", Rewards(**self.rewards))
            except ConfigError as error:
                raise ConfigError(f"{where}: {error}") from None
        if self.drop_zone not in DROP_ZONES:
            raise ConfigError(f"{where}: drop_zone {self.drop_zone!r} is not an edge: choose one of {', '.join(DROP_ZONES)}")
        if not isinstance(self.rewards, Rewards):
            raise ConfigError(f"{where}: rewards must be a table of event values, e.g. rewards = {{ pick_other = -2 }} "
                              f"(in Python a dict or an envs.Rewards), got {shown(self.rewards)}")
        failed = self.failed_robots
        if isinstance(failed, bool) or not isinstance(failed, numbers.Integral) or failed < 0:
            raise ConfigError(f"{where}: failed_robots must be an integer >= 0, got {shown(failed)}")
        object.__setattr__(self, "failed_robots", int(failed))
        gain = _real(self.motor_gain)
        if gain is None or not MIN_MOTOR_GAIN <= gain <= 1:  # NaN fails the comparison
            raise ConfigError(f"{where}: motor_gain must be a number from {_number(MIN_MOTOR_GAIN)} to 1 (a smaller "
                              "factor leaves the robots still: docs/environment.md, Tasks), got "
                              f"{shown(self.motor_gain)}")
        object.__setattr__(self, "motor_gain", gain)

    @property
    def drop_zone_id(self) -> int:
        """The nest edge as the state's ``drop_zone`` id (its index in ``DROP_ZONES``)."""
        return DROP_ZONES.index(self.drop_zone)

    def definition(self) -> dict:
        """Every field but the name, as JSON values (config.json records it; resuming compares it)."""
        return {"target": COLOR_NAMES.get(self.target, self.target),
                "season": [COLOR_NAMES.get(c, c) for c in self.season], "drop_zone": self.drop_zone,
                "rewards": asdict(self.rewards), "failed_robots": self.failed_robots, "motor_gain": self.motor_gain}


TASKS: dict[str, Task] = {
    "red": Task(3, (3, 4)),
    "green": Task(5, (5, 6)),
    "purple": Task(7, (7, 8)),
    "cyan": Task(9, (9, 10)),
    "red-nest-bottom": Task(3, (3, 4), name="red-nest-bottom", drop_zone="bottom"),
    "red-two-failed": Task(3, (3, 4), name="red-two-failed", failed_robots=2),
}
"""The built-in tasks, by name: the paper's four (red, green, purple, cyan) and the drifts of the
named schedules ``nest-relocation`` (the nest moves to the bottom edge) and ``robot-failure``
(robots 3 and 4 of 5 stop working)."""


def _colour_name(color_id: int) -> str:
    """A colour id by its name (``red``), or as ``colour 11`` where it has none."""
    return COLOR_NAMES.get(color_id, f"colour {color_id}")


def color_rgb(color_id: int) -> tuple[int, int, int]:
    """The display colour of colour id ``color_id`` (``UNKNOWN_RGB`` for an id without one)."""
    return COLOR_RGB.get(int(color_id), UNKNOWN_RGB)


def task_rgb(name: str) -> tuple[int, int, int]:
    """The display colour of a task: its target's (``UNKNOWN_RGB`` for a name not in ``TASKS``)."""
    return color_rgb(TASKS[name].target) if name in TASKS else UNKNOWN_RGB


def task_by_name(name: str) -> Task:
    try:
        return TASKS[name]
    except KeyError:
        raise ConfigError(f"unknown task {name!r}: choose one of {', '.join(TASKS)}") from None


@dataclass(frozen=True)
class ForagingConfig:
    """Static options of the foraging arena (the paper's defaults).

    A field's ``metadata`` declares the values the command line accepts (``min``, ``max``,
    ``above``: see ``lifelong_evo.options``): every one the arena can run, with room to spare
    beyond the paper's, none that would overflow its integer keys or ask for absurd memory."""

    size: float = field(default=20.0, metadata={"min": 8, "max": 1000})
    """Side of the square arena."""
    n_agents: int = field(default=5, metadata={"min": 1, "max": 1000})
    """Robots in the swarm; all run the same controller."""
    n_boxes: int = field(default=20, metadata={"min": 1, "max": 10_000})
    """Boxes in the arena."""
    n_neighbors: int = field(default=3, metadata={"min": 1, "max": 100})
    """Nearest sensed entities in each observation."""
    sensor_range: float = field(default=4.0, metadata={"above": 0, "max": 1000})
    """Sensing radius (walls strictly inside, boxes and agents inclusive)."""
    max_wheel_velocity: float = field(default=2.0, metadata={"above": 0, "max": 1000})
    """Wheel speed limit, units per second."""
    sensitivity: float = field(default=0.5, metadata={"above": 0, "max": 0.5})
    """Pick-up radius (strict), in (0, 0.5]."""
    time_step: float = field(default=0.1, metadata={"above": 0, "max": 10})
    """Seconds per step."""
    duration: int = field(default=500, metadata={"min": 1, "max": 100_000})
    """Steps per episode."""
    max_retrieves: int = field(default=20, metadata={"min": 1, "max": 1_000_000})
    """Correct retrievals that end an episode early."""
    rate_target: float = field(default=0.5, metadata={"min": 0, "max": 1})
    """Fraction of boxes with the target colour at reset."""
    repositioning: bool = True
    """Dropped boxes respawn in the arena (else they are gone)."""
    see_other_agents: bool = False
    """Agents sense each other (the paper's table: off; the original driver: on)."""
    colors: tuple[int, ...] = field(default=(3, 4, 5, 6), metadata={"min": 3, "max": 10, "max_items": 8})
    """Colour ids the arena knows: contiguous from 3. Fixes the observation size."""

    def __post_init__(self):
        object.__setattr__(self, "colors", tuple(int(c) for c in self.colors))
        self._validate()

    def _validate(self):
        for name in ("n_agents", "n_boxes", "n_neighbors", "duration", "max_retrieves"):
            if int(getattr(self, name)) < 1:
                raise ConfigError(f"{name} must be an integer >= 1, got {getattr(self, name)}")
        for name in ("sensor_range", "max_wheel_velocity", "sensitivity", "time_step"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"{name} must be > 0, got {getattr(self, name)}")
        if self.sensitivity > 0.5:
            # within a strict 0.5 an agent reaches at most one integer cell, which is what lets
            # the step resolve simultaneous picks without a loop over agents
            raise ConfigError(f"sensitivity must be <= 0.5 (the pick-up radius reaches one box cell), got {self.sensitivity}")
        if self.size < 8:
            # boxes are placed at integer cells x in [6, size-1), y in [2, size-1)
            raise ConfigError(f"size must be >= 8 so that boxes have cells to spawn in, got {self.size}")
        if not 0.0 <= self.rate_target <= 1.0:
            raise ConfigError(f"rate_target must be in [0, 1], got {self.rate_target}")
        expected = tuple(range(3, 3 + len(self.colors)))
        if len(self.colors) < 1 or self.colors != expected:
            raise ConfigError(
                f"colors must be the contiguous ids 3..{2 + max(len(self.colors), 1)} in order "
                f"(they index the observation one-hot), got {list(self.colors)}")
        # every jammed placement of cells >= 2 apart still holds ceil(nx/3) * ceil(ny/3) boxes, so
        # up to that many the spec's redraw-until-free placement always finishes
        nx, ny = math.ceil(self.size - 1) - 6, math.ceil(self.size - 1) - 2
        fits = math.ceil(nx / 3) * math.ceil(ny / 3)
        if self.n_boxes > fits:
            raise ConfigError(f"n_boxes={self.n_boxes} may not fit 2 apart in a size-{self.size} arena: "
                              f"use at most {fits} boxes or a larger size")

    @property
    def n_colors(self) -> int:
        return len(self.colors)

    @property
    def n_types(self) -> int:
        """Entity types in the one-hot: nothing, wall, agent and each colour."""
        return self.n_colors + 3

    @property
    def obs_dim(self) -> int:
        """Length of one agent's observation: 41 for 4 colours and 3 neighbours, 61 for 8."""
        c, n = self.n_colors, self.n_neighbors
        return (c + 3) * n + 3 * n + 2 + (c + 1) + c

    def check_task(self, task: Task, colours: bool = True) -> None:
        """Raise ConfigError unless ``task`` can run in this arena; ``colours=False``: whatever the
        arena's ``colors`` (a run's arena holds the colours of its schedule, not those of every
        task it defines)."""
        if colours:
            for color in (task.target, *task.season):
                if color not in self.colors:
                    raise ConfigError(
                        f"task {task.name!r} uses colour id {color}, which this arena does not know "
                        f"(colors={list(self.colors)}): add it to colors")
        n_target = int(self.n_boxes * self.rate_target)
        if n_target < self.n_boxes and len(set(task.season) - {task.target}) == 0:
            raise ConfigError(
                f"task {task.name!r}: the season has no colour besides the target, but "
                f"{self.n_boxes - n_target} boxes need one: add a colour or set rate_target=1")
        failed, robots = task.failed_robots, self.n_agents
        if failed > robots - 1:
            if TASKS.get(task.name) == task:  # a built-in task cannot be edited
                raise ConfigError(f"task {task.name!r} is built in with {failed} failed robots, and of {robots} "
                                  f"robots (n_agents) none would work: raise n_agents to at least {failed + 1}, or "
                                  f"define a task of your own with failed_robots from 0 to {robots - 1}")
            raise ConfigError(f"task {task.name!r}: failed_robots={failed}, but at least one of the {robots} robots "
                              f"must work: use 0 to {robots - 1}, or raise n_agents to at least {failed + 1}")

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, values: dict) -> "ForagingConfig":
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise ConfigError(f"unknown environment option(s) {unknown}: valid ones are {sorted(known)}")
        return cls(**values)


def colors_for_tasks(tasks) -> tuple[int, ...]:
    """The smallest contiguous colour list (from id 3) that holds every colour of ``tasks``."""
    top = max(max(t.season) for t in tasks)
    return tuple(range(3, top + 1))
