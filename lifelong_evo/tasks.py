"""Tasks by name: the built-in ones (``envs.TASKS``) and those a run defines as data,
``[tasks.NAME]`` tables (a ``--tasks FILE`` or a ``--config`` file), each parsed into an
``envs.Task``.

A table holds ``target`` (a colour name), ``season`` (a list of colour names) and, optionally,
the drift fields of ``envs.Task``: ``drop_zone``, ``rewards`` (a table of event values),
``failed_robots`` and ``motor_gain`` (docs/environment.md, Tasks). A defined task can be used in
``--schedule`` by its name, as a built-in one. A built-in name cannot be defined again: a run's
``red`` is always the paper's red. Nor can a name that differs from a built-in one or from another
defined one only in case or in ``_`` for ``-`` (``folded``): a run's default name writes ``_`` as
``-``, and a case-insensitive file system (macOS's, Windows') holds ``replay-Red.rrd`` and
``replay-red.rrd`` as one file. Every error is a ``ConfigError`` naming the task and the fix.
"""
from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Any

from envs import COLOR_IDS, TASKS, ConfigError, Task

TASK_KEYS = ("target", "season", "drop_zone", "rewards", "failed_robots", "motor_gain")
"""The keys of a ``[tasks.NAME]`` table; ``target`` and ``season`` are required."""
TASK_TABLES = ("must be [tasks.NAME] tables, one per task: write e.g. [tasks.red-south] and below it "
               "target = \"red\" and season = [\"red\", \"blue\"]")
"""How tasks are written, for a message about a ``tasks`` that is no table of tables."""
TASK_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]*")
"""A task name: it appears in schedules (beside ``,``, ``:`` and ``>``) and in file names."""


def _colour(task: str, key: str, name: Any) -> int:
    if not isinstance(name, str) or name not in COLOR_IDS:
        raise ConfigError(f"task {task!r}: {key} {name!r} is no colour: use one of {', '.join(COLOR_IDS)}")
    return COLOR_IDS[name]


def folded(name: str) -> str:
    """Task ``name`` as file names and run names may see it: lower case (a case-insensitive file
    system), ``_`` as ``-`` (``RunConfig.default_name``)."""
    return name.lower().replace("_", "-")


def define_task(name: str, table: Any) -> Task:
    """The ``envs.Task`` a ``[tasks.NAME]`` table defines (ConfigError, naming it, otherwise)."""
    if not isinstance(name, str) or not TASK_NAME.fullmatch(name):
        raise ConfigError(f"task name {name!r} is not a name a schedule can hold: use letters, digits, - and _")
    built_in = next((other for other in TASKS if folded(other) == folded(name)), None)
    if built_in is not None:
        same = "is built in" if built_in == name else (f"differs from the built-in task {built_in!r} only in case or "
                                                        "in _ for -, which run and file names do not tell apart,")
        raise ConfigError(f"task {name!r} {same} and cannot be defined again: give your task another name, "
                          f"e.g. {name}-2")
    return task_from_table(name, table)


def task_from_table(name: str, table: Any) -> Task:
    """The ``envs.Task`` named ``name`` that ``table`` (a ``[tasks.NAME]`` table, or a definition
    config.json's ``task_definitions`` holds, a built-in task's among them) defines; ConfigError,
    naming the task, otherwise. ``define_task`` checks the name first."""
    if not isinstance(table, Mapping):
        raise ConfigError(f"task {name!r} must be a table: write [tasks.{name}] and KEY = VALUE lines")
    unknown = sorted(set(table) - set(TASK_KEYS))
    if unknown:
        raise ConfigError(f"task {name!r}: unknown key(s) {unknown}: valid ones are {', '.join(TASK_KEYS)}")
    missing = [key for key in ("target", "season") if key not in table]
    if missing:
        raise ConfigError(f"task {name!r} needs {' and '.join(missing)}: e.g. target = \"red\", "
                          f"season = [\"red\", \"blue\"]")
    season = table["season"]
    if not isinstance(season, (list, tuple)) or not season:
        raise ConfigError(f"task {name!r}: season must be a list of colour names, e.g. [\"red\", \"blue\"]")
    fields = {key: table[key] for key in TASK_KEYS[2:] if key in table}
    return Task(_colour(name, "target", table["target"]), tuple(_colour(name, "season", c) for c in season),
                name=name, **fields)


def task_catalogue(tables: Mapping[str, Any] | None = None) -> dict[str, Task]:
    """Every task a run can name: the built-in ones and those ``tables`` (``{NAME: table}``) define."""
    if tables is None:
        return dict(TASKS)
    if not isinstance(tables, Mapping):
        raise ConfigError(f"tasks {TASK_TABLES}")
    defined = {name: define_task(name, table) for name, table in tables.items()}
    seen: dict[str, str] = {}
    for name in defined:
        first = seen.setdefault(folded(name), name)
        if first != name:
            raise ConfigError(f"tasks {first!r} and {name!r} differ only in case or in _ for -, which run and file "
                              f"names do not tell apart: rename one of them")
    return {**TASKS, **defined}
