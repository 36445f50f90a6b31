"""Drift schedules: which task runs for how many generations, and on which tasks each generation's
training episodes are played.

A schedule item is a task (``red:200``) or a blend of two (``red>green:50``): over the blend's
generations the share of the second task's episodes grows linearly from 0 (its first generation)
to 1 (its last), so no generation announces a switch. A blend is a phase named after its second
task: the metrics end it, as any phase, at its last generation.

Which tasks a generation trains on (``training_episodes``): its phase's task (or the blend's
two), and with the baselines of docs/metrics.md (Baselines) also earlier tasks (rehearsal) or
every task of the schedule (joint); always ``--evals`` episodes per controller in all.

A schedule names tasks from a catalogue (``lifelong_evo.tasks.task_catalogue``): the built-in
ones and those the run defines; ``schedule_of`` reads a run directory's schedule with its own.

One schedule has one spelling (``canonical_schedule``), which a run's configuration stores and
compares: ``red:2, green:2``, ``red:02,green:+2`` and (at ``--generations 2``) ``red:2,green``
are all ``red:2,green:2``, and a list that is a named schedule at ``--generations`` is its name."""
from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from envs import TASKS, Task, colors_for_tasks

from .tasks import task_catalogue

NAMED_SCHEDULES = {
    "red-green-red": ("red", "green", "red"),
    "four-tasks": ("red", "green", "purple", "cyan"),
    "nest-relocation": ("red", "red-nest-bottom", "red"),
    "robot-failure": ("red", "red-two-failed", "red"),
}
"""The paper's schedules and two drifts of another kind (the nest moves; two robots fail); each
task runs for ``--generations`` generations."""
MAX_GENERATIONS = 1_000_000
"""The most generations a task may run (``--generations`` or a schedule's count): 5000 times the paper's."""


class ScheduleError(ValueError):
    pass


@dataclass(frozen=True)
class Phase:
    """One stretch of the schedule: a task and how long it lasts; for a blend, also the task it
    drifts from (``source``)."""

    task: Task
    generations: int
    source: Task | None = None

    @property
    def name(self) -> str:
        return self.task.name


def parse_schedule(spec: str, generations: int, tasks: Mapping[str, Task] | None = None) -> list[Phase]:
    """A named schedule (``NAMED_SCHEDULES``) or a list such as ``red:200,red>green:50,green:150``
    (an item without ``:N`` runs for ``generations``; ``a>b`` blends task a into task b), its
    tasks named in ``tasks`` (default: the built-in ones)."""
    tasks = TASKS if tasks is None else tasks
    if spec in NAMED_SCHEDULES:
        return [Phase(tasks[name], generations) for name in NAMED_SCHEDULES[spec]]
    phases = []
    for item in spec.split(","):
        names, _, count = item.strip().partition(":")
        source, blend, name = names.rpartition(">")
        for task in (name, source) if blend else (name,):
            if task not in tasks:
                raise ScheduleError(
                    f"unknown task {task!r} in schedule {spec!r}: use {', '.join(tasks)} or define it in a "
                    f"[tasks.{task or 'NAME'}] table (--tasks FILE; or a named schedule: {', '.join(NAMED_SCHEDULES)}; "
                    f"a>b:N blends task a into b)")
        if blend and source == name:
            raise ScheduleError(f"schedule item {item!r} blends {name} into itself: name two tasks, e.g. red>green:50")
        if count and not re.fullmatch(r"[+-]?[0-9]+", count.strip()):  # ASCII digits, as every integer option
            raise ScheduleError(f"bad generation count {count!r} in schedule item {item!r}: write it in the digits "
                                "0-9, e.g. red:200")
        n = int(count) if count else generations
        if not 1 <= n <= MAX_GENERATIONS:
            raise ScheduleError(f"every task of schedule {spec!r} needs from 1 to {MAX_GENERATIONS} generations")
        phases.append(Phase(tasks[name], n, tasks[source] if blend else None))
    return phases


def canonical_schedule(phases: list[Phase], generations: int) -> str:
    """The one spelling of a schedule's ``phases`` (``generations``: the count of an item that
    gives none): the named schedule they are, if any (config.json has always stored those by
    name), else every item with its count, ``red:200,red>green:50,green:150``."""
    spelt = [(phase.source.name if phase.source else None, phase.name, phase.generations) for phase in phases]
    for name, tasks in NAMED_SCHEDULES.items():
        if spelt == [(None, task, generations) for task in tasks]:
            return name
    return ",".join(f"{source + '>' if source else ''}{task}:{count}" for source, task, count in spelt)


def schedule_of(config: Mapping[str, Any]) -> list[Phase]:
    """The phases of a run's config.json (its ``schedule`` and ``generations``, its tasks named
    in its ``tasks`` tables beside the built-in ones)."""
    return parse_schedule(str(config.get("schedule")), int(config.get("generations", 0)),
                          task_catalogue(config.get("tasks") or {}))


def _rounded(x: float) -> int:
    """Half up (Python's ``round`` rounds half to even, which would make 0.25 x 10 and 0.35 x 10 differ oddly)."""
    return math.floor(x + 0.5)


def _split(count: int, tasks: list[Task]) -> list[tuple[Task, int]]:
    """``count`` episodes over ``tasks`` as evenly as may be, the earlier tasks taking the remainder."""
    return [(task, count // len(tasks) + (i < count % len(tasks))) for i, task in enumerate(tasks)]


def rehearsal_episodes(rehearsal: float, evals: int) -> int:
    """Of ``evals`` episodes, how many a ``rehearsal`` share plays on earlier tasks (at least one
    stays on the current task)."""
    return min(_rounded(rehearsal * evals), evals - 1)


def training_episodes(phases: list[Phase], index: int, in_task: int, evals: int, rehearsal: float = 0.0,
                      joint: bool = False) -> list[tuple[Task, int]]:
    """The tasks generation ``in_task`` of phase ``index`` trains on, with each one's episodes per
    controller (``evals`` in all; a task with none is left out): fitness is the mean over them.
    ``joint``: every task of the schedule, ``evals`` split evenly; otherwise the phase's task (a
    blend: its two tasks, by the blend's share at this generation), and with ``rehearsal`` that
    share of the episodes (rounded half up) split evenly over the earlier tasks of the schedule."""
    if joint:
        return _split(evals, distinct_tasks(phases))
    phase = phases[index]
    earlier = [task for task in distinct_tasks(phases[:index]) if task not in (phase.task, phase.source)]
    rehearsed = rehearsal_episodes(rehearsal, evals) if earlier else 0
    current = evals - rehearsed
    if phase.source is None:
        plan = [(phase.task, current)]
    else:
        share = in_task / (phase.generations - 1) if phase.generations > 1 else 1.0
        target = _rounded(current * share)
        plan = [(phase.source, current - target), (phase.task, target)]
    if rehearsed:
        plan += _split(rehearsed, earlier)
    return [(task, n) for task, n in plan if n > 0]


def distinct_tasks(phases: list[Phase]) -> list[Task]:
    """Each task of the schedule once (a blend's source before its task), in order of first appearance."""
    seen: dict[str, Task] = {}
    for phase in phases:
        for task in (phase.source, phase.task):
            if task is not None:
                seen.setdefault(task.name, task)
    return list(seen.values())


def arena_colors(phases: list[Phase]) -> tuple[int, ...]:
    """The arena's colour list: every colour up to the highest one the schedule uses."""
    return colors_for_tasks(distinct_tasks(phases))
