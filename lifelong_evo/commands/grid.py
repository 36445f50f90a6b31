"""The grid of a sweep: its axes and fixed values, from the run's own flags (comma-separated
values) and a sweep file's ``[grid]`` and ``[grid.<algo>]`` tables, expanded into trials, each a
``RunConfig`` named from its axes (``neat-reg5-seed13``). ``lifelong_evo.commands.sweep`` runs them."""
from __future__ import annotations

import argparse
import hashlib
import itertools
import json
import re
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from envs import ConfigError

from ..config import PRESETS, RunConfig, load_tasks, load_toml, resolve
from ..errors import UserError
from ..options import flag, parse_value, schema
from ..run_names import check_run_name
from ..tasks import TASK_TABLES
from .flags import NESTED, check_once

RUN_FIELDS = [f.name for f in fields(RunConfig) if f.name not in NESTED]
"""Run options with a flag of their own."""
_TYPES = schema(RunConfig)
_LABELS = {"reg": "reg", "seed": "seed", "population": "pop", "generations": "gen", "evals": "evals",
           "retention_every": "ret", "checkpoint_every": "ckpt", "threads": "threads", "eval_threads": "evalthreads",
           "episodes_every": "ep", "rehearsal": "rehearsal", "reference_every": "refevery", "gap_window": "gap"}
_SWITCHES = {"joint": "joint", "from_scratch": "scratch", "archive": "archive"}
"""Boolean run settings named in a trial's name by themselves (``neat-joint-seed42``)."""
@dataclass
class Trial:
    name: str
    values: dict[str, Any]
    """This trial's value of every axis (keys like ``reg`` or ``algo_options.sigma``)."""
    config: RunConfig
    status: str = "pending"
    error: str = ""
    wall_time_s: float | None = None
    first_task_from: str = ""
    """The run whose first task this trial took over (``sweep --share-first-task``), if any."""


@dataclass
class Grid:
    axes: dict[str, list[Any]]
    fixed: dict[str, Any]
    preset: str
    name: str | None = None
    by_algo: dict[str, tuple[dict[str, list[Any]], dict[str, Any]]] = field(default_factory=dict)
    """Per algorithm: axes and fixed values for its trials only (a sweep file's ``[grid.<algo>]``),
    so that algorithms whose options or lambdas differ share one grid."""
    trials: list[Trial] = field(default_factory=list)

    @property
    def columns(self) -> list[str]:
        """Every axis, shared or one algorithm's, variants' keys included, in trial-name order."""
        keys: dict[str, None] = {}
        for axes in (self.axes, *(axes for axes, _ in self.by_algo.values())):
            keys.update(dict.fromkeys(k for k in axes if k != VARIANTS))
            for variant in axes.get(VARIANTS, []):
                keys.update(dict.fromkeys(variant))
        return sorted(keys, key=_axis_rank)


def _coerce(key: str, value: Any, where: str) -> Any:
    """A sweep file's value of run option ``key``, typed as the run's flag types it."""
    try:
        return parse_value(_TYPES[key], value, flag(key))
    except ConfigError as error:
        raise UserError(f"{error} ({where})") from None


def _split_assignment(item: str, what: str) -> tuple[str, list[str]]:
    """``KEY=V1,V2`` -> (KEY, ["V1", "V2"]), split at the commas outside brackets (``[16],[32,32]``
    is two lists); the values stay text, typed when each trial's configuration is validated."""
    key, sep, text = item.partition("=")
    if not sep or not key.strip():
        raise UserError(f"{what} {item!r} is not KEY=VALUE (or KEY=V1,V2 for an axis)")
    pieces, depth, start = [], 0, 0
    for i, char in enumerate(text):
        depth += {"[": 1, "]": -1}.get(char, 0)
        if char == "," and depth == 0:
            pieces.append(text[start:i])
            start = i + 1
    return key.strip(), [*pieces, text[start:]]


def _file_layer(path: str):
    """A sweep TOML: run options (fixed), ``[tasks.NAME]`` tables (every trial's, as a run's
    --config holds them), a [grid] table of lists (axes) with optional ``[grid.<algo>]`` tables
    (axes and fixed values for that algorithm's trials only), each table with optional
    ``variants`` (sets of values given together: one axis), and preset/name.
    Returns (axes, fixed, by_algo, preset, name)."""
    from algorithms import REGISTRY

    values = load_toml(path)
    allowed = set(RUN_FIELDS) | set(NESTED) | {"grid", "preset", "name"}
    unknown = sorted(set(values) - allowed)
    if unknown:
        raise UserError(f"unknown key(s) {unknown} in {path}: use run options, [env], [algo_options], "
                       "[tasks.NAME], [grid], preset and name")

    def no_tasks_axis(where: str) -> None:
        raise UserError(f"tasks in {where} of {path}: every trial defines the same tasks: write them as "
                        "[tasks.NAME] tables outside [grid] (or give --tasks FILE), and vary the schedule that "
                        "names them")
    axes: dict[str, list[Any]] = {}
    fixed: dict[str, Any] = {}
    by_algo: dict[str, tuple[dict[str, list[Any]], dict[str, Any]]] = {}

    def put(key: str, value: Any, in_grid: bool, axes: dict, fixed: dict) -> None:
        name = key.split(".")[-1]
        if in_grid:
            listed = value if isinstance(value, list) else [value]
            if not listed:
                raise UserError(f"[grid] {key} in {path} is an empty list: give at least one value")
            typed = [_coerce(name, v, f"in {path}") if "." not in key else v for v in listed]
            if len(typed) > 1:
                axes[key] = typed
            else:
                fixed[key] = typed[0]
        else:
            fixed[key] = _coerce(name, value, f"in {path}") if "." not in key else value

    def variants(listed: Any, where: str) -> list[dict[str, Any]]:
        """``variants = [{reg = 0}, {reg = 10, algo_options = {importance = "l2"}}]``: each table
        a set of values given together, flattened to keys like ``algo_options.importance``."""
        if not isinstance(listed, list) or not listed or not all(isinstance(v, dict) and v for v in listed):
            raise UserError(f"{where} variants in {path} must be a list of tables, each giving values "
                           "together, e.g. variants = [{reg = 0}, {reg = 10, algo_options = {importance = \"l2\"}}]")
        flat = []
        for variant in listed:
            values: dict[str, Any] = {}
            for key, value in variant.items():
                if key == "tasks":
                    no_tasks_axis(f"{where} variants")
                if key in NESTED and isinstance(value, dict):
                    values.update((f"{key}.{sub}", subvalue) for sub, subvalue in value.items())
                elif key in RUN_FIELDS and key != "algo":
                    values[key] = _coerce(key, value, f"in {where} variants of {path}")
                else:
                    raise UserError(f"unknown key {key!r} in {where} variants of {path}: use run options "
                                   "(not algo), env or algo_options")
            flat.append(values)
        return flat

    def grid_table(table: dict, axes: dict, fixed: dict, algo: str | None) -> None:
        where = f"[grid.{algo}]" if algo else "[grid]"
        for gkey, gvalue in table.items():
            if gkey == VARIANTS:
                axes[VARIANTS] = variants(gvalue, where)
            elif gkey == "tasks":
                no_tasks_axis(where)
            elif gkey in NESTED and isinstance(gvalue, dict):
                for sub, subvalue in gvalue.items():
                    put(f"{gkey}.{sub}", subvalue, True, axes, fixed)
            elif gkey in RUN_FIELDS and not (algo and gkey == "algo"):
                put(gkey, gvalue, True, axes, fixed)
            elif algo is None and gkey in REGISTRY and isinstance(gvalue, dict):
                by_algo[gkey] = ({}, {})
                grid_table(gvalue, *by_algo[gkey], gkey)
            else:
                raise UserError(f"unknown {where} key {gkey!r} in {path}: use run options, "
                                f"{where[:-1]}.env], {where[:-1]}.algo_options], variants"
                                + ("" if algo else ", or [grid.<algo>] for one algorithm's trials"))
        given_twice = sorted(set(axes) & set().union(*axes.get(VARIANTS, [])))
        if given_twice:
            raise UserError(f"{', '.join(given_twice)} in {path} is an axis of {where} and set by its variants too: "
                            "give it in one")

    for key, value in values.items():
        if key in ("preset", "name"):
            continue
        if key == "grid":
            if not isinstance(value, dict):
                raise UserError(f"grid in {path} must be a table: write [grid] with lists, e.g. seed = [1, 2]")
            grid_table(value, axes, fixed, None)
        elif key in NESTED:
            if not isinstance(value, dict):
                raise UserError(f"{key} in {path} must be a table: write [{key}]")
            for sub, subvalue in value.items():
                put(f"{key}.{sub}", subvalue, False, axes, fixed)
        elif key == "tasks":  # a table of tables, taken whole: each trial's configuration defines them
            if not isinstance(value, dict):
                raise UserError(f"tasks in {path} {TASK_TABLES}")
            fixed[key] = value
        else:
            put(key, value, False, axes, fixed)
    return axes, fixed, by_algo, values.get("preset"), values.get("name")


_FIRST_AXES = ["algo", "schedule", "regulariser", "reg"]  # as in RunConfig.default_name
VARIANTS = "variants"
"""The axis of a grid table whose values are sets of values given together (dicts by key)."""


def _expand(values: dict[str, Any]) -> dict[str, Any]:
    """One trial's axis values with its variant's values in place of the variant."""
    variant = values.get(VARIANTS, {})
    return {**{k: v for k, v in values.items() if k != VARIANTS}, **variant}


def _axis_rank(key: str) -> tuple[int, str]:
    """Trial names list the axes in this order: algo, schedule, reg, the other run options,
    environment and optimiser options, then the seed."""
    if key in _FIRST_AXES:
        return (0, f"{_FIRST_AXES.index(key)}")
    if key == "seed":
        return (4, key)
    if key in RUN_FIELDS:
        return (1, f"{RUN_FIELDS.index(key):03d}")
    return (2, key)


def build_grid(args: argparse.Namespace) -> Grid:
    """Axes and fixed values from the sweep file and the flags (flags win, key by key), and the
    trials: every combination, each resolved and validated like a ``run`` (preset < file < flags)."""
    axes, fixed, by_algo, preset, name = _file_layer(args.config) if args.config else ({}, {}, {}, None, None)
    if args.config and name is None:
        name = Path(args.config).stem

    def put(key: str, values: list[Any]) -> None:
        for table in (axes, fixed, *(t for tables in by_algo.values() for t in tables)):  # a flag wins everywhere
            table.pop(key, None)
            if VARIANTS in table:  # variants that differed only in this key are one now
                kept = [{k: v for k, v in variant.items() if k != key} for variant in table[VARIANTS]]
                table[VARIANTS] = [v for i, v in enumerate(kept) if v not in kept[:i]]
        if len(values) != len(set(map(repr, values))):
            raise UserError(f"{key} lists a value twice ({values}): give each value once")
        if len(values) > 1:
            axes[key] = values
        else:
            fixed[key] = values[0]

    for key in RUN_FIELDS:
        value = getattr(args, key, None)  # a list of typed values (flags.add_run_options), a boolean flag's value
        if value is not None:
            put(key, value if isinstance(value, list) else [value])
    for nested, setter in NESTED.items():
        given: dict[str, str] = {}
        for item in getattr(args, setter[2:]):
            sub, values = _split_assignment(item, setter)
            check_once(setter, sub, ",".join(values), given)
            given[sub] = ",".join(values)
            put(f"{nested}.{sub}", values)
    if getattr(args, "tasks_file", None):  # every trial defines the file's tasks, and the sweep file's others
        put("tasks", [{**fixed.get("tasks", {}), **load_tasks(args.tasks_file)}])
    preset = args.preset or preset or "paper"
    if preset not in PRESETS:
        raise UserError(f"unknown preset {preset!r}: choose one of {', '.join(PRESETS)}")
    if args.gpus_per_trial < 0:
        raise UserError(f"--gpus-per-trial must be >= 0, got {args.gpus_per_trial}")
    if args.gpus_per_trial > 0:
        gpus = f"--gpus-per-trial {args.gpus_per_trial:g}"
        # a cluster's nodes, not this machine, must have CUDA; here, --device cannot give it
        if args.address is None and not _cuda_available():
            raise UserError(f"{gpus} runs the trials on CUDA, and this machine has no CUDA device that torch can "
                            "use: drop --gpus-per-trial to run them on the CPU, or give --address of a cluster "
                            "with GPUs")
        devices = axes.get("device", [fixed.get("device", "cuda")])
        other = next((d for d in devices if not str(d).startswith("cuda")), None)
        if other is not None:
            raise UserError(f"{gpus} runs the trials on CUDA, but --device is {other}: drop --gpus-per-trial to "
                            f"run them on {other}, or drop --device")
        if "device" not in axes:
            fixed["device"] = "cuda"
    algos = axes.get("algo", [fixed.get("algo", RunConfig().algo)])
    if getattr(args, "algo", None) is not None:  # --algo picks some of the file's algorithms: drop the others' tables
        by_algo = {algo: tables for algo, tables in by_algo.items() if algo in algos}
    for algo, (algo_axes, _) in by_algo.items():
        if algo not in algos:
            raise UserError(f"[grid.{algo}] is for {algo}'s trials, but no trial runs {algo}: add it to algo")
        shared = sorted((set(algo_axes) | set().union(*algo_axes.get(VARIANTS, [])))
                        & (set(axes) | set().union(*axes.get(VARIANTS, []))))
        if shared:
            raise UserError(f"{', '.join(shared)} is an axis of every trial and of [grid.{algo}] too: give it in one")
    axes = {k: axes[k] for k in sorted(axes, key=_axis_rank)}
    if args.name is not None:
        name = check_run_name(args.name)
    elif name is not None:
        name = check_run_name(name, f"name in {args.config}")
    grid = Grid(axes, fixed, preset, name, by_algo)
    givens: list[dict[str, Any]] = []  # each trial's axis values as given
    for combo in itertools.product(*axes.values()):
        common = dict(zip(axes, combo))
        algo_axes, algo_fixed = by_algo.get(common.get("algo", fixed.get("algo", RunConfig().algo)), ({}, {}))
        for algo_combo in itertools.product(*algo_axes.values()):
            values = _expand({**_expand(common), **dict(zip(algo_axes, algo_combo))})
            values = {k: values[k] for k in sorted(values, key=_axis_rank)}
            # a cluster's machines, not this one, must have the device and compiler its trials need
            config = _resolve(preset, {**fixed, **algo_fixed, **values}, values, machine=args.address is None)
            given, values = values, {key: _typed_value(config, key) for key in values}
            twin = next((i for i, trial in enumerate(grid.trials) if trial.values == values), None)
            if twin is not None:  # two spellings of one value (a schedule's: red:2 and red:02)
                raise UserError(f"the trials of {givens[twin]} and of {given} are one trial, {values}: give each "
                                "value once")
            givens.append(given)
            grid.trials.append(Trial(trial_name(values, config), values, config))
    seen: dict[str, Trial] = {}
    for trial in grid.trials:
        if trial.name in seen:
            raise UserError(f"trials {seen[trial.name].values} and {trial.values} are both named {trial.name!r}: "
                           "give the axis values distinct spellings")
        seen[trial.name] = trial
        check_run_name(trial.name, "the trial name", fix="spell the values it is made of (axis values, --algo) "
                                                          "differently")
    return grid


def _cuda_available() -> bool:
    import torch  # here, not above: a sweep that reserves no GPU asks nothing of torch here

    return torch.cuda.is_available()


def _resolve(preset: str, values: dict[str, Any], axis_values: dict[str, Any], machine: bool) -> RunConfig:
    """One trial's RunConfig (``config.resolve``); ``values`` as the flags and the file gave them."""
    overrides: dict[str, Any] = {}
    for key, value in values.items():
        nested, _, sub = key.rpartition(".")
        if nested:
            overrides.setdefault(nested, {})[sub] = value
        else:
            overrides[key] = value
    try:
        return resolve(preset, {}, overrides, machine=machine)
    except ConfigError as error:
        where = f" (trial {axis_values})" if axis_values else ""
        raise UserError(f"{error}{where}") from None


def _typed_value(config: RunConfig, key: str) -> Any:
    """The value of ``key`` (``reg``, ``algo_options.sigma``) in a validated configuration."""
    nested, _, sub = key.rpartition(".")
    return getattr(config, nested)[sub] if nested else getattr(config, key)


def _slug(value: Any) -> str:
    text = f"{value:g}" if isinstance(value, float) else str(value)
    return re.sub(r"[^A-Za-z0-9.]+", "-", text).strip("-")


def trial_name(values: dict[str, Any], config: RunConfig) -> str:
    """From the varying axes, e.g. ``neat-reg5-seed13``, ``neat-wp-reg0.4-lambda_2=0.3-seed1``; a grid
    without axes: ``RunConfig.default_name``."""
    if not values:
        return config.default_name()
    parts = []
    for key, value in values.items():
        if key in ("algo", "schedule", "device", "regulariser"):
            parts.append(_slug(value))
        elif key == "record":
            parts.append("rec" if value else "norec")
        elif key in _SWITCHES:  # a baseline on or off: its name or nothing
            parts.append(_SWITCHES[key] if value is True else f"no-{_SWITCHES[key]}")
        else:  # an option whose name ends in a digit takes an = before its value: lambda_2=0.003, not lambda_20.003
            label = _LABELS.get(key, key.split(".")[-1])
            parts.append(label + ("=" if label[-1].isdigit() else "") + _slug(value))
    return "-".join(parts)


def default_sweep_name(grid: Grid) -> str:
    blob = json.dumps({"axes": grid.axes, "fixed": grid.fixed, "preset": grid.preset}, sort_keys=True, default=str)
    return "sweep-" + "-".join(k.split(".")[-1] for k in grid.axes) + "-" + hashlib.sha1(blob.encode()).hexdigest()[:6]
