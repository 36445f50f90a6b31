"""The resolved configuration of a lifelong run: defaults, presets, TOML files and validation."""
from __future__ import annotations

import json
import re
import tomllib
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any, ClassVar

from envs import ConfigError, ForagingConfig
from envs.numerics import Numerics

from .options import LISTED_BY, flag, parse_table, parse_value, schema
from .schedule import (MAX_GENERATIONS, ScheduleError, arena_colors, canonical_schedule, distinct_tasks,
                       parse_schedule, rehearsal_episodes, schedule_of, training_episodes)
from .tasks import TASK_TABLES, task_catalogue

DEFAULT_REGULARISER = "default"
"""``RunConfig.regulariser`` before it is resolved: the optimiser's own (``resolve_regulariser``)."""


@dataclass(frozen=True)
class RunConfig:
    """Everything that determines a lifelong run (the paper's main experiment by default). Each
    field's docstring is its line in ``--help``."""

    algo: str = "neat"
    """Optimiser: a name in algorithms.REGISTRY, yours included (python -m lifelong_evo options lists them)."""
    reg: float = field(default=0.0, metadata={"min": 0, "max": 1e9})
    """Regularisation strength lambda (0 = off) of --regulariser."""
    regulariser: str = DEFAULT_REGULARISER
    """The regulariser: gd or wp (NEAT), l2 or ewc (the ES; --option importance is a synonym), functional
    (NEAT, the ES, an optimiser with a reference); default: the optimiser's own (NEAT gd, the ES l2), or
    the one the options given choose (docs/algorithms.md)."""
    schedule: str = "red-green-red"
    """red-green-red, four-tasks, nest-relocation, robot-failure, or a list like red:200,green:100,red:50
    of built-in tasks and those --tasks defines; a>b:N blends task a into task b over N generations
    (red:200,red>green:50,green:150)."""
    generations: int = field(default=200, metadata={"min": 1, "max": MAX_GENERATIONS})
    """Generations per task where the schedule gives no count."""
    population: int = field(default=300, metadata={"min": 1, "max": 1_000_000})
    """Population size (for an ES: sampled solutions; the centre is scored too); each optimiser may
    need more (NEAT: 5, 10 with genetics 2.0; an ES: 2)."""
    evals: int = field(default=10, metadata={"min": 1, "max": 100_000})
    """Environments per controller and task each generation (N)."""
    seed: int = field(default=42, metadata={"min": 0, "max": 2**32 - 1})
    """Seed of everything: environments, the optimiser, respawns (below 2**32: held-out episodes and
    recorded ones draw from seeds that no run's seed reaches)."""
    retention_every: int = field(default=10, metadata={"min": 1, "max": MAX_GENERATIONS})
    """Score every controller on earlier tasks every this many generations (and at task ends)."""
    checkpoint_every: int = field(default=10, metadata={"min": 1, "max": MAX_GENERATIONS})
    """Write a checkpoint every this many generations (and at every task end)."""
    device: str = "cpu"
    """Torch device for environments and controllers (cpu, cuda, ...)."""
    threads: int = field(default=1, metadata={"min": 1, "max": 1024})
    """Torch CPU threads per evaluation thread (one is faster for these small tensors)."""
    eval_threads: int = field(default=2, metadata={"min": 1, "max": 1024})
    """Evaluation threads, each playing a slice of the population with its own env (the count
    changes no number: docs/usage.md, Reproducibility); 1 on a GPU, where threads share the one
    device (docs/performance.md)."""
    compile: bool = True
    """torch.compile the environment's step: faster steps after a compile per batch shape; needs a
    C++ compiler (docs/performance.md)."""
    cuda_graphs: bool = False
    """Replay the environment's step as one CUDA graph (needs --device cuda): the same numbers in
    one launch instead of many small kernels. With --compile the capture hung on the one GPU it
    was tried on (docs/performance.md)."""
    numerics: Numerics = "portable"
    """Arithmetic of the fitness: portable (the same numbers on every x86-64 CPU, whatever the speed
    settings) or native (torch's own: faster, but the numbers follow the CPU and the speed
    settings) (docs/usage.md, Reproducibility)."""
    record: bool = True
    """Write recording.rrd (Rerun)."""
    episodes_every: int = field(default=0, metadata={"min": 0, "max": MAX_GENERATIONS})
    """Also record top-individual episodes every this many generations (0: only at task ends)."""
    held_out_episodes: int = field(default=100, metadata={"min": 1, "max": 100_000})
    """Held-out episodes per task on which every exported controller is scored at each task end
    (a fixed test set, the same for every run: docs/metrics.md)."""
    rehearsal: float = field(default=0.0, metadata={"min": 0, "max": 1})
    """Rehearsal baseline: this share of each controller's --evals episodes (rounded half up, split
    evenly, at least one left on the current task) is played on earlier tasks of the schedule, and
    fitness is the mean over all of them (0: off; docs/metrics.md, Baselines)."""
    joint: bool = False
    """Joint (multi-task) upper bound: from generation 0 fitness is the mean over every task of the
    schedule, --evals split evenly over them."""
    from_scratch: bool = False
    """From-scratch baseline: at every task end the optimiser starts again from a fresh random
    population (seeded from --seed and the phase), so each task is learnt without transfer."""
    reference_every: int = field(default=0, metadata={"min": 0, "max": MAX_GENERATIONS})
    """Take the regulariser's reference every this many generations instead of at task ends (0):
    a rule that needs no task boundary, for schedules with blends (a>b:N)."""
    archive: bool = False
    """Skill archive: keep each task's top controller at its end, and put it back into the
    population when the task returns (NEAT: in place of the newest offspring, not yet evaluated, so
    the elites are kept; an ES: as the centre); composes with lambda and every baseline
    (docs/algorithms.md, The skill archive)."""
    gap_window: int = field(default=20, metadata={"min": 0, "max": MAX_GENERATIONS})
    """Stability gap: score every earlier task in each of the first this many generations after a
    switch, on episodes of their own (0: off; docs/metrics.md)."""
    env: dict = field(default_factory=dict)
    """Environment overrides (ForagingConfig fields); the arena colours follow the schedule."""
    algo_options: dict = field(default_factory=dict)
    """Optimiser options, e.g. sigma, learning_rate, hidden, importance, references."""
    tasks: dict = field(default_factory=dict)
    """Tasks defined as data, [tasks.NAME] tables (target, season, drop_zone, rewards, failed_robots,
    motor_gain), which --schedule can name: a TOML file of them, or the tables in --config."""

    WRITTEN_BEFORE: ClassVar[dict[str, Any]] = {"numerics": "native"}
    """Settings a config.json written before they existed ran at, where that is not today's default."""
    SEED_SETTINGS: ClassVar[tuple[str, ...]] = ("seed",)
    """Which repetition of a configuration a run is."""
    SPEED_SETTINGS: ClassVar[tuple[str, ...]] = ("device", "threads", "eval_threads", "compile", "cuda_graphs",
                                                 "checkpoint_every")
    """How a run is computed, not what: they change none of its numbers (docs/usage.md,
    Reproducibility), so runs that differ only in them (and in the seed) are one configuration;
    a resumed run keeps them, but for ``PORTABLE_SPEED_SETTINGS`` under the portable arithmetic."""
    PORTABLE_SPEED_SETTINGS: ClassVar[tuple[str, ...]] = ("threads", "eval_threads", "compile", "checkpoint_every")
    """The speed settings that change no byte of a run under the portable arithmetic on any x86-64
    CPU (``tests/test_same_numbers_anywhere.py``): a portable run may be resumed, or its first task
    taken over, under others (a busy machine's thread count, another node's compiler). Under the
    native arithmetic another thread count or compiled code rounds otherwise, so a resumed run
    keeps them; and a run keeps its device, whose arithmetic is not the CPU's."""
    OUTPUT_SETTINGS: ClassVar[tuple[str, ...]] = ("record", "episodes_every", "gap_window")
    """What a run records besides its numbers, which they never change: a resumed run may change them."""
    BASELINE_SETTINGS: ClassVar[tuple[str, ...]] = ("rehearsal", "joint", "from_scratch", "reference_every", "archive")
    """The continual-learning baselines and the boundary-free reference (docs/metrics.md,
    Baselines): each is off at its default, and a run with all of them off (and lambda 0) is
    fine-tuning."""
    AFTER_FIRST_TASK_SETTINGS: ClassVar[tuple[str, ...]] = ("reg", "regulariser", "rehearsal", "from_scratch",
                                                            "archive")
    """Settings that act only at or after the first task's end (the regulariser takes its first
    reference there, whichever it is and whatever lambda is: what tells one regulariser from another
    before that end is in the options that choose it, compared by themselves; rehearsal has no
    earlier task before it; from scratch starts afresh there; the archive puts a controller back
    only when a task returns): runs that differ only in them, and in the optimiser's
    ``after_first_task_options``, share their first task, number for number (``--start-from``,
    ``sweep --share-first-task``; the run that takes it over does at its end what it does).
    ``after_first_task`` gives them for a run."""
    REGULARISER_SETTINGS: ClassVar[tuple[str, ...]] = ("reg", "regulariser")
    """The regulariser's own settings: with a reference taken before the first task's end
    (``reference_every``), they act in the first task."""

    @classmethod
    def outcome_settings(cls, values: dict[str, Any]) -> dict[str, Any]:
        """The settings among ``values`` (fields of a RunConfig, as ``to_dict`` or config.json
        hold them) that a resumed run must keep, as JSON compares them (tuples are lists). A
        field that ``values`` lacks (a config.json written before the field existed) counts at
        its default, which is how such a run ran."""
        filled = {**asdict(cls()), **values} if values else {}
        if filled:
            filled["regulariser"] = cls.regulariser_of(filled)
            filled["schedule"] = cls.schedule_spelling(filled)
        free = cls.free_settings(values) if values else cls.OUTPUT_SETTINGS
        return {k: v for k, v in json.loads(json.dumps(filled)).items() if k not in free}

    @classmethod
    def free_settings(cls, values: dict[str, Any]) -> tuple[str, ...]:
        """The settings a run of ``values`` (as config.json holds them) may change when resumed or
        when another run takes over its first task: the output settings and, under the portable
        arithmetic, ``PORTABLE_SPEED_SETTINGS`` (a config.json without ``numerics`` ran native)."""
        numerics = values.get("numerics", cls.WRITTEN_BEFORE["numerics"])
        return (*cls.OUTPUT_SETTINGS, *(cls.PORTABLE_SPEED_SETTINGS if numerics == "portable" else ()))

    @staticmethod
    def regulariser_of(values: dict[str, Any]) -> str:
        """The regulariser a run of ``values`` (RunConfig's fields, as config.json holds them)
        applies: its ``regulariser``, or where that is the default (a config.json written before
        the setting existed) the optimiser's own that its options choose (``resolve_regulariser``);
        ``default`` where the optimiser or its options are not known here."""
        regulariser = values.get("regulariser", DEFAULT_REGULARISER)
        if regulariser != DEFAULT_REGULARISER:
            return regulariser
        try:
            return resolve_regulariser(values.get("algo"), regulariser, values.get("algo_options") or {})[0]
        except (ConfigError, KeyError, TypeError, ValueError):
            return regulariser

    @staticmethod
    def schedule_spelling(values: dict[str, Any]) -> Any:
        """The schedule of ``values`` (RunConfig's fields, as config.json or a checkpoint holds
        them) in its one spelling (``schedule.canonical_schedule``): a run written with another
        spelling of it is the same run; as it stands where it does not parse."""
        try:
            return canonical_schedule(schedule_of(values), values["generations"])
        except (ConfigError, KeyError, TypeError, ValueError):  # ScheduleError is a ValueError
            return values.get("schedule")

    @classmethod
    def first_task_settings(cls, values: dict[str, Any]) -> dict[str, Any]:
        """``outcome_settings`` but those that act only after the first task's end
        (``after_first_task``): runs with equal ones play the same first task."""
        settings = cls.outcome_settings(values)
        after = cls.from_dict(values).after_first_task()
        first = {k: v for k, v in settings.items() if k not in after}
        if isinstance(first.get("algo_options"), dict):
            first["algo_options"] = {k: v for k, v in first["algo_options"].items() if f"algo_options.{k}" not in after}
        return first

    def after_first_task(self) -> frozenset[str]:
        """The settings of this run that act only from its first task's end, named as
        ``RunDir.setting_differences`` names them: ``AFTER_FIRST_TASK_SETTINGS`` and
        ``algo_options.KEY`` for each of the optimiser's ``after_first_task_options``; but none of
        the regulariser's where it takes a reference before that end (``reference_every`` shorter
        than the first task)."""
        from algorithms import REGISTRY

        options = getattr(REGISTRY.get(self.algo), "after_first_task_options", ())
        after = {*self.AFTER_FIRST_TASK_SETTINGS, *(f"algo_options.{name}" for name in options)}
        if self.reference_every and self.reference_every < self.phases()[0].generations:
            after -= {*self.REGULARISER_SETTINGS, *(f"algo_options.{name}" for name in options)}
        return frozenset(after)

    @classmethod
    def configuration_settings(cls, values: dict[str, Any]) -> dict[str, Any]:
        """The settings among ``values`` that make runs different configurations, not repetitions
        of one: all but the seed, speed and output settings."""
        ignored = (*cls.SEED_SETTINGS, *cls.SPEED_SETTINGS, *cls.OUTPUT_SETTINGS)
        return {k: v for k, v in values.items() if k not in ignored}

    def default_name(self) -> str:
        """The run directory's name when none is given: ``neat-red-green-red-reg11-seed42``, with a
        regulariser other than the optimiser's default before lambda (``neat-red-green-red-wp-reg0.4-seed42``)."""
        return f"{name_stem(self.algo, self.schedule, self.regulariser, self.reg)}-seed{self.seed}"

    def phases(self):
        return parse_schedule(self.schedule, self.generations, task_catalogue(self.tasks))

    def task_definitions(self) -> dict[str, dict[str, Any]]:
        """Every task of the schedule by name, with all its fields (config.json's
        ``task_definitions``: a built-in task's too, so that the file says what ran)."""
        return {task.name: task.definition() for task in distinct_tasks(self.phases())}

    def algo_options_resolved(self) -> dict[str, Any]:
        """Every option of the algorithm, the defaults included: the options the run evolves with."""
        from algorithms import REGISTRY

        return asdict(REGISTRY[self.algo].Options(**self.algo_options))

    def env_config(self) -> ForagingConfig:
        phases = self.phases()
        values = {"colors": arena_colors(phases), **self.env}
        return ForagingConfig.from_dict(values)

    def validate(self, machine: bool = True) -> "RunConfig":
        """This configuration with every value parsed to its declared type (``lifelong_evo.options``),
        checked before anything is built or written: ConfigError, naming the option, otherwise.
        ``machine``: also check what the machine that runs it needs (the device, and a C++
        compiler for ``compile``); a sweep planned for other machines leaves that to them."""
        from algorithms import REGISTRY

        typed = {name: parse_value(kind, getattr(self, name), flag(name))
                 for name, kind in schema(RunConfig).items() if name not in ("env", "algo_options", "tasks")}
        algo = typed["algo"]
        if algo not in REGISTRY:
            raise ConfigError(f"unknown algorithm {algo!r}: choose one of {', '.join(REGISTRY)}")
        optimizer = REGISTRY[algo]
        config = replace(self, **typed,
                         env=parse_table(ForagingConfig, self.env, "environment", "--env", LISTED_BY),
                         algo_options=parse_table(optimizer.Options, self.algo_options, algo, "--option",
                                                  f"{LISTED_BY} --algo {algo}"))
        if config.reg and not optimizer.has_regularizer:
            raise ConfigError(f"algorithm {algo!r} has no regulariser: drop --reg")
        if config.archive and not optimizer.can_adopt():
            raise ConfigError(f"--archive: algorithm {algo!r} cannot take a controller back (it has no "
                              "Optimizer.adopt): drop --archive")
        if config.cuda_graphs and not config.device.startswith("cuda"):
            raise ConfigError(f"--cuda-graphs needs --device cuda, not {config.device!r}: drop --cuda-graphs "
                              "or run on a GPU")
        try:
            options = optimizer.Options(**config.algo_options)
        except ValueError as error:
            raise ConfigError(f"--option {error}") from None
        regulariser, algo_options = resolve_regulariser(algo, config.regulariser, config.algo_options)
        config = replace(config, regulariser=regulariser, algo_options=algo_options)
        weights = [f"--option {k}={v}" for k, v in algo_options.items() if k in optimizer.lambda_options]
        if weights and not config.reg:
            raise ConfigError(f"{weights[0]} weighs --regulariser {regulariser}'s penalty beside lambda, and at --reg 0 "
                              "no regulariser plays (the run is fine-tuning): give --reg above 0, or drop the option")
        try:
            optimizer.check_population(config.population, options)
        except ValueError as error:
            raise ConfigError(f"--population: {error}") from None
        try:
            phases = config.phases()
        except ScheduleError as error:
            raise ConfigError(str(error)) from None
        config = replace(config, schedule=canonical_schedule(phases, config.generations))
        env = config.env_config()
        scheduled = distinct_tasks(phases)
        for task in scheduled:
            env.check_task(task)
        # every task the run defines must fit the swarm, the ones the schedule does not use too
        # (but for their colours: the arena holds the schedule's)
        defined = task_catalogue(config.tasks)
        for name in config.tasks:
            if name not in {task.name for task in scheduled}:
                env.check_task(defined[name], colours=False)
        config._check_baselines(phases)
        if machine:
            check_device(config.device)
            if config.compile:
                require_cpp_compiler()
        return config

    def _check_baselines(self, phases) -> None:
        """The baselines are one each: rehearsal, joint and from scratch exclude each other, and
        each must change what the run plays."""
        chosen = [flag for flag, on in (("--rehearsal", self.rehearsal > 0), ("--joint", self.joint),
                                        ("--from-scratch", self.from_scratch)) if on]
        if len(chosen) > 1:
            raise ConfigError(f"{' and '.join(chosen)} are different baselines: choose one of them")
        if self.rehearsal >= 1:
            raise ConfigError(f"--rehearsal {self.rehearsal:g} leaves no episode on the current task: give a share "
                              "below 1 (e.g. 0.3)")
        if self.rehearsal > 0 and rehearsal_episodes(self.rehearsal, self.evals) == 0:
            raise ConfigError(f"--rehearsal {self.rehearsal:g} of --evals {self.evals} rounds to no episode: raise "
                              "--rehearsal or --evals")
        tasks = len(distinct_tasks(phases))
        if self.joint and self.evals < tasks:
            raise ConfigError(f"--joint splits --evals {self.evals} over the schedule's {tasks} tasks: give "
                              f"--evals {tasks} or more")

    def training_plan(self) -> list[dict[str, Any]]:
        """Per phase, the episodes per controller each task gets in training (config.json's
        ``training_episodes``): a blend's at its first and its last generation."""
        phases = self.phases()
        plan = []
        for index, phase in enumerate(phases):
            ends = (0, phase.generations - 1) if phase.source is not None else (0,)
            episodes = [{task.name: n for task, n in training_episodes(phases, index, in_task, self.evals,
                                                                      self.rehearsal, self.joint)} for in_task in ends]
            plan.append({"task": phase.name, **({"blend_from": phase.source.name, "first": episodes[0],
                                                  "last": episodes[1]} if phase.source else {"episodes": episodes[0]})})
        return plan

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, values: dict[str, Any], source: str = "config") -> "RunConfig":
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise ConfigError(f"unknown option(s) {unknown} in {source}: valid ones are {sorted(known)}")
        return cls(**values)


def default_regulariser(algo: Any) -> str:
    """The regulariser a run of ``algo`` applies where it names none and its options choose none
    (NEAT ``gd``, an ES ``l2``); ``default`` for an optimiser that names none or is not registered."""
    from algorithms import REGISTRY

    return resolve_regulariser(algo, DEFAULT_REGULARISER, {})[0] if algo in REGISTRY else DEFAULT_REGULARISER


def name_stem(algo: Any, schedule: Any, regulariser: Any, reg: float) -> str:
    """``neat-red-green-red-reg11``, with a regulariser other than the algorithm's default before
    lambda (``neat-red-green-red-wp-reg0.4``): a run's default name without its seed, and the
    prefix of ``plot``'s files."""
    schedule = re.sub(r"[^A-Za-z0-9]+", "-", str(schedule)).strip("-")
    named = "" if regulariser in (default_regulariser(algo), DEFAULT_REGULARISER) else f"-{regulariser}"
    return f"{algo}-{schedule}{named}-reg{reg:g}"


def resolve_regulariser(algo: str, regulariser: str, algo_options: dict[str, Any]) -> tuple[str, dict[str, Any]]:
    """The regulariser a run of ``algo`` applies, and its options with those that choose it
    (``Optimizer.regularisers``): ``default`` is the first of the optimiser's regularisers that its
    options choose (``--option importance=ewc``: ``ewc``), the functional one only where no other
    is, or stays ``default`` for an optimiser that names none; a named one adds the options that
    choose it where they are not their defaults, so that ``--regulariser ewc`` and ``--option
    importance=ewc`` are one configuration. ConfigError where the optimiser cannot apply it, an
    option given chooses another regulariser (``--regulariser functional --option penalty=wp``), or
    only another reads it (``Optimizer.options_used_by``: ``--regulariser gd --option lambda_2=0.5``)."""
    from algorithms import REGISTRY
    from algorithms.base import FUNCTIONAL

    optimizer = REGISTRY[algo]
    names = optimizer.regularisers
    if regulariser == DEFAULT_REGULARISER:
        resolved = asdict(optimizer.Options(**algo_options))
        chosen = [name for name, options in names.items() if all(resolved[k] == v for k, v in options.items())]
        chosen = [name for name in chosen if name != FUNCTIONAL] or chosen
        if not chosen:
            return regulariser, algo_options
        regulariser = chosen[0]
    elif regulariser not in names:
        applies = f"applies {', '.join(names)}" if names else "names no regulariser: drop --regulariser"
        raise ConfigError(f"--regulariser {regulariser!r}: {algo} {applies}")
    else:
        clash = [f"--option {k}={v}" for k, v in algo_options.items()
                 if k in optimizer.choosing_options() and names[regulariser].get(k) != v]
        if clash:
            raise ConfigError(f"--regulariser {regulariser!r} and {' and '.join(clash)} choose different "
                              "regularisers: give one of them")
    for key, value in algo_options.items():
        users = optimizer.options_used_by.get(key, (regulariser,))
        if regulariser not in users:
            raise ConfigError(f"--option {key}={value} is read only by --regulariser {' or '.join(users)}, and this "
                              f"run's is {regulariser!r}: drop the option, or give --regulariser {users[0]}")
    defaults = asdict(optimizer.Options())
    return regulariser, {**algo_options, **{k: v for k, v in names[regulariser].items() if defaults[k] != v}}


PRESETS: dict[str, dict[str, Any]] = {
    "paper": {},
    "smoke": {"generations": 5, "population": 20, "evals": 2, "retention_every": 2, "checkpoint_every": 2,
              "compile": False, "eval_threads": 1, "held_out_episodes": 10, "env": {"duration": 200}},
}
"""``paper``: the paper's protocol. ``smoke``: a first look in seconds (eager: nothing to
compile), with episodes long enough for the robots to reach boxes, so that every algorithm scores
and its best fitness moves within a task."""


def check_device(name: str) -> None:
    """Fail at once, not inside the first tensor operation, where ``name`` is no torch device or
    one this machine does not have."""
    import torch

    try:
        device = torch.device(name)
    except RuntimeError:
        raise ConfigError(f"--device {name!r} is not a torch device: use cpu, cuda or cuda:N") from None
    if device.type == "cuda":
        if not torch.cuda.is_available():
            raise ConfigError(f"--device {name}: this machine has no CUDA device that torch can use "
                              "(torch.cuda.is_available() is False): use --device cpu")
        if device.index is not None and device.index >= torch.cuda.device_count():
            raise ConfigError(f"--device {name}: this machine has {torch.cuda.device_count()} CUDA device(s), "
                              f"numbered from 0")
    elif device.type == "mps":
        if not torch.backends.mps.is_available():
            raise ConfigError(f"--device {name}: MPS is not available on this machine: use --device cpu")
    elif device.type != "cpu":
        raise ConfigError(f"--device {name}: only cpu, cuda and mps devices are supported")


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


def load_toml(path: str | Path, what: str = "config file") -> dict[str, Any]:
    """Read a run configuration file (the keys of RunConfig; [env], [algo_options] and [tasks.NAME]
    tables); ``what`` names the file in errors (``task file`` for ``--tasks``). UTF-8 text, as TOML
    is; a leading byte-order mark (which some Windows editors write, and tomllib refuses) is skipped."""
    try:
        with open(path, "rb") as handle:
            text = handle.read().decode("utf-8")
        return tomllib.loads(text.removeprefix("\ufeff"))
    except FileNotFoundError:
        raise ConfigError(f"{what} {path} does not exist") from None
    except tomllib.TOMLDecodeError as error:
        raise ConfigError(f"{what} {path} is not valid TOML: {error}") from None
    except UnicodeDecodeError as error:  # TOML is UTF-8 text
        raise ConfigError(f"{what} {path} is not UTF-8 text (byte {error.start} cannot be decoded): "
                          "save it as UTF-8") from None
    except OSError as error:
        raise ConfigError(f"{what} {path} cannot be read: {error.strerror}") from None


def load_tasks(path: str | Path) -> dict[str, Any]:
    """The ``[tasks.NAME]`` tables of a task file (``--tasks``), which holds nothing else."""
    values = load_toml(path, "task file")
    others = sorted(set(values) - {"tasks"})
    if others:
        raise ConfigError(f"task file {path} holds {others}: it may hold only [tasks.NAME] tables "
                          "(put other settings in --config)")
    if not values.get("tasks"):
        raise ConfigError(f"task file {path} defines no task: write [tasks.NAME] tables")
    if not isinstance(values["tasks"], dict):
        raise ConfigError(f"tasks in task file {path} {TASK_TABLES}")
    return values["tasks"]


def resolve(preset: str = "paper", file_values: dict | None = None, overrides: dict | None = None,
            machine: bool = True) -> RunConfig:
    """Defaults < preset < TOML file < command-line flags; nested tables merge key by key; the
    result validated (``RunConfig.validate``, which ``machine`` is passed to)."""
    return configure(merge_layers(preset, file_values, overrides), machine)


def configure(stated: dict[str, Any], machine: bool = True) -> RunConfig:
    """The configuration of the settings a command states (``merge_layers``) over the defaults,
    validated (``RunConfig.validate``, which ``machine`` is passed to)."""
    return replace(RunConfig(), **stated).validate(machine)


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
            if key in ("env", "algo_options", "tasks"):  # tasks merge by name, a task's table whole
                if not isinstance(value, dict):
                    raise ConfigError(f"{key} in {source} " + (TASK_TABLES if key == "tasks" else
                                                               f"must be a table: write [{key}] and KEY = VALUE lines"))
                merged[key] = {**merged.get(key, {}), **value}
            else:
                merged[key] = value
    return merged
