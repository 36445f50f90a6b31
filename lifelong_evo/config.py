"""The resolved configuration of a lifelong run: defaults, presets, TOML files and validation."""
from __future__ import annotations

import tomllib
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any

from envs import ConfigError, ForagingConfig

from .schedule import ScheduleError, arena_colors, parse_schedule


@dataclass(frozen=True)
class RunConfig:
    """Everything that determines a lifelong run (the paper's main experiment by default)."""

    algo: str = "neat"
    """Optimiser from the registry: neat, cmaes, sep-cmaes, openai-es, pgpe, snes."""
    reg: float = 0.0
    """Regularisation strength lambda (0 = off): genetic distance for NEAT, L2/EWC for the ES."""
    schedule: str = "red-green-red"
    """red-green-red, four-tasks, or a list like red:200,green:100,red:50."""
    generations: int = 200
    """Generations per task where the schedule gives no count."""
    population: int = 300
    """Population size (for an ES: sampled solutions; the centre is scored too)."""
    evals: int = 10
    """Environments per controller and task each generation (N)."""
    seed: int = 42
    """Seed of everything: environments, the optimiser, respawns."""
    retention_every: int = 10
    """Score every controller on earlier tasks every this many generations (and at task ends)."""
    checkpoint_every: int = 10
    """Write a checkpoint every this many generations (and at every task end)."""
    device: str = "cpu"
    """Torch device for environments and controllers."""
    threads: int = 1
    """Torch CPU threads per evaluation thread (one is faster for these small tensors)."""
    eval_threads: int = 2
    """Evaluation threads, each playing its own slice of the population with its own env (ask
    and tell get threads x eval_threads torch threads); a fixed count, not the machine's core
    count, because the count can change the rounding of a run's numbers. Use 1 on a GPU: the
    threads share the one device, and two ran the NEAT generation at half the speed of one."""
    compile: bool = True
    """torch.compile the environment's step: about 2.5x faster steps after 20-60 s of compiling
    per batch shape; needs a C++ compiler."""
    record: bool = True
    """Write recording.rrd (Rerun)."""
    episodes_every: int = 0
    """Also record top-individual episodes every this many generations (0: only at task ends)."""
    env: dict = field(default_factory=dict)
    """Environment overrides (ForagingConfig fields); the arena colours follow the schedule."""
    algo_options: dict = field(default_factory=dict)
    """Optimiser options, e.g. sigma, learning_rate, hidden, importance, references."""

    def phases(self):
        return parse_schedule(self.schedule, self.generations)

    def env_config(self) -> ForagingConfig:
        phases = self.phases()
        values = {"colors": arena_colors(phases), **self.env}
        return ForagingConfig.from_dict(values)

    def validate(self) -> "RunConfig":
        from algorithms import REGISTRY

        if self.algo not in REGISTRY:
            raise ConfigError(f"unknown algorithm {self.algo!r}: choose one of {', '.join(REGISTRY)}")
        if self.reg < 0:
            raise ConfigError(f"--reg must be >= 0, got {self.reg}")
        if self.reg and not REGISTRY[self.algo].has_regularizer:
            raise ConfigError(f"algorithm {self.algo!r} has no regulariser: drop --reg")
        for name in ("generations", "population", "evals", "retention_every", "checkpoint_every", "threads",
                     "eval_threads"):
            if getattr(self, name) < 1:
                raise ConfigError(f"--{name.replace('_', '-')} must be >= 1, got {getattr(self, name)}")
        if self.episodes_every < 0:
            raise ConfigError(f"--episodes-every must be >= 0, got {self.episodes_every}")
        try:
            phases = self.phases()
        except ScheduleError as error:
            raise ConfigError(str(error)) from None
        env = self.env_config()
        for phase in phases:
            env.check_task(phase.task)
        if self.compile:
            require_cpp_compiler()
        return self

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, values: dict[str, Any], source: str = "config") -> "RunConfig":
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise ConfigError(f"unknown option(s) {unknown} in {source}: valid ones are {sorted(known)}")
        return cls(**values)


PRESETS: dict[str, dict[str, Any]] = {
    "paper": {},
    "smoke": {"generations": 5, "population": 20, "evals": 2, "retention_every": 2, "checkpoint_every": 2,
              "compile": False, "eval_threads": 1, "env": {"duration": 200}},
}
"""``paper``: the paper's protocol. ``smoke``: a first look in seconds (eager: nothing to
compile), with episodes long enough for the robots to reach boxes: at 60 steps the ES, which start
near the zero controller, scored 0.00 everywhere; at 200 steps and 5 generations per task every
algorithm scores and its best fitness moves within a task."""


def require_cpp_compiler() -> None:
    """Fail at once, not at the first step, where ``--compile`` would find no C++ compiler
    (the search is inductor's own, so it finds what compiling would use)."""
    from torch._inductor.cpp_builder import get_cpp_compiler
    from torch._inductor.exc import InvalidCxxCompiler

    try:
        get_cpp_compiler()
    except InvalidCxxCompiler:
        raise ConfigError("--compile needs a C++ compiler and none was found: install g++ (or set CXX), "
                          "or run eagerly with --no-compile") from None


def load_toml(path: str | Path) -> dict[str, Any]:
    """Read a run configuration file (the keys of RunConfig; [env] and [algo_options] tables)."""
    try:
        with open(path, "rb") as handle:
            return tomllib.load(handle)
    except FileNotFoundError:
        raise ConfigError(f"config file {path} does not exist") from None
    except tomllib.TOMLDecodeError as error:
        raise ConfigError(f"config file {path} is not valid TOML: {error}") from None


def resolve(preset: str = "paper", file_values: dict | None = None, overrides: dict | None = None) -> RunConfig:
    """Defaults < preset < TOML file < command-line flags; nested tables merge key by key."""
    return replace(RunConfig(), **merge_layers(preset, file_values, overrides)).validate()


def merge_layers(preset: str = "paper", file_values: dict | None = None, overrides: dict | None = None) -> dict:
    """The values the preset, the TOML file and the flags set (flags win), without the defaults:
    what a command states, e.g. to compare with a stored run's configuration."""
    if preset not in PRESETS:
        raise ConfigError(f"unknown preset {preset!r}: choose one of {', '.join(PRESETS)}")
    merged: dict[str, Any] = {}
    for layer, source in ((PRESETS[preset], f"preset {preset}"), (file_values or {}, "the config file"),
                          (overrides or {}, "the command line")):
        RunConfig.from_dict(layer, source)  # reject unknown keys early, naming where they came from
        for key, value in layer.items():
            if key in ("env", "algo_options"):
                merged[key] = {**merged.get(key, {}), **value}
            else:
                merged[key] = value
    return merged
