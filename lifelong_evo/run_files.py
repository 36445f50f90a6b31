"""The validating readers of a run directory's files: what ``rundir`` read from config.json,
summary.json, metrics.csv and controllers/ is checked here against the contract (README.md, The
run directory) and against the run's own config.json, before any verb uses it.

Contract: every reading verb (``plot``, ``compare``, ``replay``, ``score``, and ``--resume`` and
``--start-from`` where they read a run) meets a damaged or mismatched file as one ``RunDirError``
naming the file, the key or line, the value and what was expected, with the fix (exit status 2,
one ``error:`` line), never as an exception halfway through its work. Nothing here writes.

- ``check_config``: config.json is a JSON object of ``RunConfig`` fields (and the keys written
  beside them), each of its field's type and within its bounds as JSON typed it (a string
  ``"200"`` where an integer belongs is damage, not a value to convert), ``env`` and
  ``algo_options`` objects whose every option is one of the environment's or the optimiser's,
  likewise of its declared type and within its bounds, a regulariser its optimiser applies, a
  schedule that parses (its canonical spelling is the configuration's) and an arena the
  environment accepts; and, where written, the keys written beside the settings that are read:
  ``env_resolved`` and ``algo_options_resolved`` (objects of options, as ``env`` and
  ``algo_options``, holding each option those give at the given value) and ``task_definitions``
  (a definition of each task of the schedule, the one config.json's ``tasks`` table gives where
  one defines it).
- ``check_summary``: summary.json is an object whose ``phases`` are the first tasks of
  config.json's schedule, in order (``metrics.summarise`` writes one per ended phase), and whose
  figures, where present, are numbers (or null) where the readers expect them: the per-phase
  lists, forgetting rows, R matrices, transfer metrics, stability gaps and the held-out block
  (with a skill archive's: each archived controller, one the block scores, and its score).
- ``check_metrics``: metrics.csv has one row per generation from 0 on, in order, each in the
  phase the schedule puts its generation in (``task_index``, ``task``, ``generation_in_task``),
  and rows through the end of every phase summary.json records as ended; ``check_species``
  species.csv's generations in order, through the same end.
- ``check_controller_files``: controllers/ holds each ended phase's top controller and every
  controller summary.json's held-out block scored (or, in a run kept without them, none).
- ``check_controller``: an exported controller as ``algorithms.check_export`` sees it, taking the
  run's arena's observations as inputs.

An algorithm this process does not know (a custom optimiser registered by a script) is no error
here: reading a run needs only its files.
"""
from __future__ import annotations

import json
from bisect import bisect_right
from collections.abc import Iterable
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

from algorithms import REGISTRY, ExportError, check_export
from envs import ConfigError, ForagingConfig

from .config import DEFAULT_REGULARISER, RunConfig
from .errors import RESTORE, RunDirError
from .metrics import controller_key
from .options import LISTED_BY, parse_table, parse_value, schema
from .schedule import Phase, ScheduleError, canonical_schedule
from .summary_json import SummaryLayout
from .tasks import task_from_table

TABLES = ("env", "algo_options", "tasks")
"""config.json's settings that are objects of options (every other one is a single value)."""


def _shown(value: Any) -> str:
    """``value`` for a message, cut to one short line."""
    shown = repr(value)
    return shown if len(shown) <= 60 else shown[:40] + "..." + shown[-10:]


def _kind(value: Any) -> str:
    """What a JSON value is, in words: ``a list``, ``a string``, ..."""
    return {dict: "an object", list: "a list", str: "a string", bool: "a boolean", int: "an integer",
            float: "a number", type(None): "null"}.get(type(value), type(value).__name__)


def as_json(value: Any) -> Any:
    """``value`` as JSON holds it (tuples are lists; 11 and 11.0 compare equal)."""
    return json.loads(json.dumps(value))


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _is_integer(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def check_config(values: Any, path: Path, written_beside: Iterable[str] = ()) -> RunConfig:
    """The ``RunConfig`` that config.json ``values`` (read from ``path``) holds, each setting parsed
    to its field's type within its bounds; RunDirError naming the key otherwise. ``written_beside``:
    config.json's keys that are no setting (the resolved options, versions), left unchecked."""
    if not isinstance(values, dict):
        raise RunDirError(f"{path} holds {_kind(values)}, not a JSON object of run settings: {RESTORE}")
    declared = schema(RunConfig)
    settings = {**RunConfig.WRITTEN_BEFORE,
                **{key: value for key, value in values.items() if key not in set(written_beside)}}
    unknown = sorted(set(settings) - set(declared))
    if unknown:
        raise RunDirError(f"{path} has the key(s) {', '.join(map(repr, unknown))}, which are no run setting (the "
                          f"settings are RunConfig's fields): {RESTORE}")
    typed: dict[str, Any] = {}
    for name, value in settings.items():
        if name in TABLES:
            if not isinstance(value, dict):
                raise RunDirError(f"{path}, key {name!r}: {_shown(value)} is {_kind(value)}, not an object of "
                                  f"options: {RESTORE}")
            typed[name] = value
            continue
        try:
            typed[name] = parse_value(declared[name], value, text=False)
        except ConfigError as error:
            raise RunDirError(f"{path}, key {name!r}: {error}: {RESTORE}") from None
    algo = typed.get("algo", RunConfig.algo)
    optimizer = REGISTRY.get(algo)
    try:
        typed["env"] = parse_table(ForagingConfig, typed.get("env", {}), "environment", "option", LISTED_BY, text=False)
    except ConfigError as error:
        raise RunDirError(f"{path}, key 'env': {error}: {RESTORE}") from None
    if optimizer is not None:  # an optimiser this process does not know: the script that registers it knows its options
        try:
            typed["algo_options"] = parse_table(optimizer.Options, typed.get("algo_options", {}), algo, "option",
                                                f"{LISTED_BY} --algo {algo}", text=False)
            optimizer.Options(**typed["algo_options"])
        except (ConfigError, ValueError) as error:
            raise RunDirError(f"{path}, key 'algo_options': {error}: {RESTORE}") from None
    config = RunConfig(**typed)
    config = replace(config, regulariser=RunConfig.regulariser_of(config.to_dict()))  # an older config.json's
    applies = getattr(REGISTRY.get(config.algo), "regularisers", None)
    if applies is not None and config.regulariser not in (*applies, DEFAULT_REGULARISER):
        raise RunDirError(f"{path}, key 'regulariser': {_shown(config.regulariser)} is no regulariser of "
                          f"{config.algo} (it applies {', '.join(applies) or 'none'}): {RESTORE}")
    try:
        config = replace(config, schedule=canonical_schedule(config.phases(), config.generations))
    except ScheduleError as error:
        raise RunDirError(f"{path}, key 'schedule': {error}: {RESTORE}") from None
    except ConfigError as error:  # a [tasks.NAME] table that defines no task
        raise RunDirError(f"{path}, key 'tasks': {error}: {RESTORE}") from None
    try:
        config.env_config()
    except (ConfigError, TypeError, ValueError) as error:  # an option ForagingConfig does not have or take
        raise RunDirError(f"{path}, key 'env': {error}: {RESTORE}") from None
    _check_resolved(values, path, algo, optimizer, set(written_beside),
                    {"env_resolved": typed["env"], "algo_options_resolved": typed.get("algo_options", {})})
    _check_task_definitions(values, path, config, set(written_beside))
    return config


def _check_resolved(values: dict[str, Any], path: Path, algo: str, optimizer: Any,
                    written_beside: set[str], given: dict[str, dict[str, Any]]) -> None:
    """config.json's resolved environment and optimiser options (``env_resolved``,
    ``algo_options_resolved``), where written: objects whose every option is one of the
    environment's or the optimiser's, of its type and within its bounds, as ``env`` and
    ``algo_options`` are, and holding each option ``env`` and ``algo_options`` give (``given``, by
    resolved key, typed) at its given value (``--resume`` continues with them, ``compare`` reads
    them in place of the given ones: the two must say one thing). A config.json written before one
    existed has none; an option added since is at its default."""
    for key, cls, owner, listed_by in (
            ("env_resolved", ForagingConfig, "environment", LISTED_BY),
            ("algo_options_resolved", getattr(optimizer, "Options", None), algo, f"{LISTED_BY} --algo {algo}")):
        if key not in values or key not in written_beside or cls is None:  # None: an optimiser unknown here
            continue
        value = values[key]
        if not isinstance(value, dict):
            raise RunDirError(f"{path}, key {key!r}: {_shown(value)} is {_kind(value)}, not an object of options: "
                              f"{RESTORE}")
        try:
            resolved = parse_table(cls, value, owner, "option", listed_by, text=False)
        except ConfigError as error:
            raise RunDirError(f"{path}, key {key!r}: {error}: {RESTORE}") from None
        table = key[:-len("_resolved")]
        try:  # the given options as the run resolved them (a class may normalise a value it is given)
            normalised = asdict(cls(**{**resolved, **given[key]}))
        except (ConfigError, TypeError, ValueError) as error:
            raise RunDirError(f"{path}, key {key!r}: {error}: {RESTORE}") from None
        for option in given[key]:
            if option in resolved and as_json(resolved[option]) != as_json(normalised[option]):
                raise RunDirError(f"{path}, key {key!r}: {option} is {_shown(resolved[option])}, where key {table!r} "
                                  f"gives {_shown(given[key][option])}: {RESTORE}")


def _check_task_definitions(values: dict[str, Any], path: Path, config: RunConfig, written_beside: set[str]) -> None:
    """config.json's ``task_definitions``, where written (a run made before it existed has none):
    an object with the full definition of each task of the schedule, and of no other (``--resume``
    and ``--start-from`` compare them field by field)."""
    key = "task_definitions"
    if key not in values or key not in written_beside:
        return
    defined, where = values[key], f"{path}, key {key!r}"
    if not isinstance(defined, dict):
        raise RunDirError(f"{where}: {_shown(defined)} is {_kind(defined)}, not an object of task definitions: "
                          f"{RESTORE}")
    scheduled = list(config.task_definitions())
    if set(defined) != set(scheduled):
        raise RunDirError(f"{where}: defines {_shown(sorted(defined))}, where config.json's schedule "
                          f"{config.schedule!r} plays {_shown(scheduled)}: {RESTORE}")
    tables = config.tasks or {}
    for name, definition in defined.items():
        try:
            task = task_from_table(name, definition)
        except ConfigError as error:
            raise RunDirError(f"{where}: {error}: {RESTORE}") from None
        if name in tables and task.definition() != task_from_table(name, tables[name]).definition():
            # replay and score play the tables' task, --resume compares the definition: they must agree
            raise RunDirError(f"{where}: the definition of {name!r} is not what config.json's tasks table "
                              f"{name!r} defines: {RESTORE}")


def check_summary(values: Any, path: Path, config: RunConfig) -> dict[str, Any]:
    """summary.json ``values`` (read from ``path``), checked against its run's ``config`` (see the
    module docstring); RunDirError naming the key otherwise."""
    if not isinstance(values, dict):
        raise RunDirError(f"{path} holds {_kind(values)}, not a JSON object of a run's figures: {RESTORE}")
    schedule = [phase.name for phase in config.phases()]
    phases = values.get(SummaryLayout.PHASES)
    where = f"{path}, key {SummaryLayout.PHASES!r}"
    if not isinstance(phases, list) or not all(isinstance(task, str) for task in phases):
        raise RunDirError(f"{where}: {_shown(phases)} is not a list of task names: {RESTORE}")
    if len(phases) > len(schedule):
        raise RunDirError(f"{where}: {len(phases)} phases, more than the {len(schedule)} of config.json's schedule "
                          f"{config.schedule!r}: the summary is another run's or damaged: {RESTORE}")
    for index, (task, planned) in enumerate(zip(phases, schedule)):
        if task != planned:
            raise RunDirError(f"{where}, item {index}: {task!r}, where config.json's schedule {config.schedule!r} "
                              f"has {planned!r}: the summary is another run's or damaged: {RESTORE}")
    _check_figures(values, f"{path}", schedule)
    held = values.get(SummaryLayout.HELD_OUT)
    if held is not None:
        _check_held_out(held, f"{path}, key {SummaryLayout.HELD_OUT!r}", schedule)
    gaps = values.get(SummaryLayout.STABILITY_GAP)
    if gaps is not None:
        for index, entry in enumerate(_list(gaps, f"{path}, key {SummaryLayout.STABILITY_GAP!r}")):
            at = f"{path}, key {SummaryLayout.STABILITY_GAP!r}, item {index}"
            _row(entry, at, ("after_switch_to", range(1, len(schedule))), schedule)
    return values


def _check_figures(part: dict[str, Any], where: str, schedule: list[str]) -> None:
    """The training figures of summary.json, or of its held-out block (``where`` names which):
    the ``SummaryLayout.PHASE_FIGURES`` lists, forgetting rows (each at the end of a phase after the first),
    R matrices, transfer metrics and the wall time."""
    for key in SummaryLayout.PHASE_FIGURES:
        if key in part:
            for index, value in enumerate(_list(part[key], f"{where}, key {key!r}")):
                _figure(value, f"{where}, key {key!r}, item {index}")
    forgetting = SummaryLayout.FORGETTING
    for index, row in enumerate(_list(part.get(forgetting, []), f"{where}, key {forgetting!r}")):
        _row(row, f"{where}, key {forgetting!r}, item {index}", ("at_end_of", range(1, len(schedule))), schedule)
    for level in SummaryLayout.LEVELS:
        key = SummaryLayout.matrix(level)
        if key in part:
            for i, row in enumerate(_list(part[key], f"{where}, key {key!r}")):
                for j, value in enumerate(_list(row, f"{where}, key {key!r}, row {i}")):
                    _figure(value, f"{where}, key {key!r}, row {i}, item {j}")
        for metric in SummaryLayout.TRANSFER:
            key = SummaryLayout.transfer(metric, level)
            if key in part:
                _figure(part[key], f"{where}, key {key!r}")
    if SummaryLayout.WALL_TIME in part:
        _figure(part[SummaryLayout.WALL_TIME], f"{where}, key {SummaryLayout.WALL_TIME!r}")


def _check_held_out(held: Any, where: str, schedule: list[str]) -> None:
    """summary.json's ``held_out`` block: its episodes, its phases (the schedule's first tasks), the
    scores of each controller per task and its figures (``_check_figures``)."""
    if not isinstance(held, dict):
        raise RunDirError(f"{where}: {_shown(held)} is {_kind(held)}, not an object: {RESTORE}")
    episodes = held.get(SummaryLayout.EPISODES)
    if not _is_integer(episodes) or episodes < 1:
        raise RunDirError(f"{where}, key 'episodes': {_shown(episodes)} is not a positive integer: {RESTORE}")
    phases = held.get(SummaryLayout.PHASES)
    if not isinstance(phases, list) or phases != schedule[:len(phases)]:
        raise RunDirError(f"{where}, key 'phases': {_shown(phases)} is not the first tasks of config.json's "
                          f"schedule {schedule}: {RESTORE}")
    scores = held.get(SummaryLayout.SCORES, {})
    if not isinstance(scores, dict):
        raise RunDirError(f"{where}, key 'scores': {_shown(scores)} is {_kind(scores)}, not an object: {RESTORE}")
    for name, by_task in scores.items():
        if not isinstance(by_task, dict):
            raise RunDirError(f"{where}, key 'scores', {name!r}: {_shown(by_task)} is not an object of a score per "
                              f"task: {RESTORE}")
        for task, value in by_task.items():
            _figure(value, f"{where}, key 'scores', {name!r}, {task!r}")
    _check_figures(held, where, schedule)
    _check_archive(held, where, phases, scores)


def _check_archive(held: dict[str, Any], where: str, phases: list[str], scores: dict[str, Any]) -> None:
    """The held-out block's skill archive, where the run kept one (``metrics.held_out_summary``): an
    object with, per task of the block's phases, the controller it archived (one the block scores)
    and that controller's score on the task; and the mean of those scores."""
    key = SummaryLayout.ARCHIVE
    if key in held:
        archive, at = held[key], f"{where}, key {key!r}"
        if not isinstance(archive, dict):
            raise RunDirError(f"{at}: {_shown(archive)} is {_kind(archive)}, not an object of each task's archived "
                              f"controller: {RESTORE}")
        for task, kept in archive.items():
            if task not in phases:
                raise RunDirError(f"{at}: {task!r} is not a task of the block's phases {phases}: {RESTORE}")
            named = kept.get("controller") if isinstance(kept, dict) else None
            if not isinstance(named, str) or named not in scores:
                raise RunDirError(f"{at}, {task!r}: {_shown(kept)} is not an object naming a controller the block "
                                  f"scores ('controller') and its score ('score'): {RESTORE}")
            score = kept.get("score")
            if not _is_number(score):
                raise RunDirError(f"{at}, {task!r}, 'score': {_shown(score)} is {_kind(score)}, not a number: "
                                  f"{RESTORE}")
    if SummaryLayout.ARCHIVE_MEAN in held:
        _figure(held[SummaryLayout.ARCHIVE_MEAN], f"{where}, key {SummaryLayout.ARCHIVE_MEAN!r}")


def _list(value: Any, where: str) -> list:
    if not isinstance(value, list):
        raise RunDirError(f"{where}: {_shown(value)} is {_kind(value)}, not a list: {RESTORE}")
    return value


def _figure(value: Any, where: str) -> None:
    """A figure: a number, or null where none was measured."""
    if value is not None and not _is_number(value):
        raise RunDirError(f"{where}: {_shown(value)} is {_kind(value)}, not a number: {RESTORE}")


def _row(row: Any, where: str, phase_key: tuple[str, range], schedule: list[str]) -> None:
    """A forgetting row or a stability-gap entry: an object whose ``phase_key`` names a phase in
    its range, whose ``task`` is a task of the schedule, and whose every other value is a figure."""
    if not isinstance(row, dict):
        raise RunDirError(f"{where}: {_shown(row)} is {_kind(row)}, not an object: {RESTORE}")
    key, phases = phase_key
    if not _is_integer(row.get(key)) or row[key] not in phases:
        raise RunDirError(f"{where}, {key!r}: {_shown(row.get(key))} is not a phase from {phases.start} to "
                          f"{phases.stop - 1} of config.json's schedule: {RESTORE}")
    if row.get("task") not in schedule:
        raise RunDirError(f"{where}, 'task': {_shown(row.get('task'))} is not a task of config.json's schedule "
                          f"({', '.join(dict.fromkeys(schedule))}): {RESTORE}")
    for name, value in row.items():
        if name not in (key, "task"):
            _figure(value, f"{where}, {name!r}")


def check_metrics(rows: list[dict[str, str]], path: Path, config: RunConfig, ended: int = 0) -> list[dict[str, str]]:
    """metrics.csv ``rows`` (``metrics_csv.read_metrics``'s, integer columns already checked), checked
    against config.json's schedule: one row per generation from generation 0 on, in order (a
    generation written twice, missing or out of order is another run's rows or a damaged file),
    each in the phase the schedule puts its generation in (``task_index``, ``task`` and
    ``generation_in_task``), and rows through the last generation of the ``ended`` phases that
    summary.json records (fewer: the file was cut short); RunDirError naming the line."""
    phases = config.phases()
    starts = _phase_starts(phases)
    for line, row in enumerate(rows, start=2):
        index, generation = int(row["task_index"]), int(row["generation"])
        expected = line - 2
        if generation != expected:
            said = f"after generation {expected - 1} on line {line - 1}" if expected else "on the first row"
            raise RunDirError(f"{path} line {line}, column generation: {generation} {said}, where each generation "
                              f"from 0 on has one row, in order: {RESTORE}")
        if generation >= starts[-1]:
            raise RunDirError(f"{path} line {line}, column generation: {generation} is beyond the {starts[-1]} "
                              f"generations of config.json's schedule {config.schedule!r}: {RESTORE}")
        phase = bisect_right(starts, generation) - 1
        found = {"task_index": index, "task": row["task"], "generation_in_task": int(row["generation_in_task"])}
        planned = {"task_index": phase, "task": phases[phase].name, "generation_in_task": generation - starts[phase]}
        for column, value in found.items():
            if value != planned[column]:
                raise RunDirError(f"{path} line {line}, column {column}: {value!r}, where config.json's schedule "
                                  f"{config.schedule!r} has {planned[column]!r} at generation {generation}: {RESTORE}")
    _check_through_ended(len(rows), path, starts, ended)
    return rows


def check_species(rows: list[dict[str, str]], path: Path, config: RunConfig, ended: int = 0) -> list[dict[str, str]]:
    """species.csv ``rows`` (``read_metrics``'s), checked as metrics.csv's are where an optimiser
    that reports no species in some generation allows: each generation's rows together and in
    order, within the schedule's generations, and rows through the last generation of the
    ``ended`` phases."""
    starts = _phase_starts(config.phases())
    generations = 0
    for line, row in enumerate(rows, start=2):
        generation = int(row["generation"])
        if generation < generations - 1 or generation >= starts[-1]:
            raise RunDirError(f"{path} line {line}, column generation: {generation} after generation "
                              f"{generations - 1} on line {line - 1}, where the rows of each of the {starts[-1]} "
                              f"generations of config.json's schedule follow those of the one before: {RESTORE}")
        generations = generation + 1
    _check_through_ended(generations, path, starts, ended)
    return rows


def _phase_starts(phases: list[Phase]) -> list[int]:
    """The first generation of each of a schedule's ``phases``, then the schedule's length."""
    return [sum(phase.generations for phase in phases[:k]) for k in range(len(phases) + 1)]


def _check_through_ended(generations: int, path: Path, starts: list[int], ended: int) -> None:
    """RunDirError unless the file ``path``, holding rows of ``generations`` generations from 0 on,
    reaches the end of the ``ended`` phases summary.json records (phase k starts at ``starts[k]``)."""
    if ended and generations < starts[ended]:
        last = f"ends at generation {generations - 1}" if generations else "has no rows"
        raise RunDirError(f"{path} {last}, where summary.json records {ended} phase(s) of the schedule "
                          f"ended, the last at generation {starts[ended] - 1}: the file is cut short: {RESTORE}")


def check_controller_files(names: Iterable[str], summary: dict[str, Any], folder: Path) -> None:
    """RunDirError unless controllers/ (``folder``, holding the file stems ``names``) holds the top
    controller of every phase ``summary`` (summary.json, checked) records as ended and every
    controller its held-out block scored: without one, ``score`` would write the block anew without
    its scores, and ``compare`` and ``plot`` would leave out its figures, without a word. A run
    kept without its controllers (none at all: summary.json holds its figures) passes."""
    names = set(names)
    if not names:
        return
    wanted = [controller_key(i, task, "top") for i, task in enumerate(summary.get(SummaryLayout.PHASES, []))]
    scored = summary.get(SummaryLayout.HELD_OUT, {}).get(SummaryLayout.SCORES, {})
    missing = [name for name in dict.fromkeys([*wanted, *scored]) if name not in names]
    if missing:
        raise RunDirError(f"{folder} lacks {', '.join(f'{name}.json' for name in missing)}, which summary.json "
                          f"records (a task end's top controller, or one its held-out block scored): {RESTORE}")


def check_controller(exported: Any, path: Path, config: RunConfig) -> dict[str, Any]:
    """An exported controller read from ``path``, if it is one that plays in ``config``'s arena
    (``algorithms.check_export`` with its observation size); RunDirError naming the field otherwise."""
    try:
        check_export(exported, config.env_config().obs_dim)
    except ExportError as error:
        raise RunDirError(f"{path} is not a controller this run can play: {error}: {RESTORE}, or pick another "
                          "controller") from None
    return exported
