"""Drift schedules: which task runs for how many generations."""
from __future__ import annotations

from dataclasses import dataclass

from envs import TASKS, Task, colors_for_tasks

NAMED_SCHEDULES = {
    "red-green-red": ("red", "green", "red"),
    "four-tasks": ("red", "green", "purple", "cyan"),
}
"""The paper's schedules; each task runs for ``--generations`` generations."""
MAX_GENERATIONS = 1_000_000
"""The most generations a task may run (``--generations`` or a schedule's count): 5000 times the paper's."""


class ScheduleError(ValueError):
    pass


@dataclass(frozen=True)
class Phase:
    """One stretch of the schedule: a task and how long it lasts."""

    task: Task
    generations: int

    @property
    def name(self) -> str:
        return self.task.name


def parse_schedule(spec: str, generations: int) -> list[Phase]:
    """``red-green-red``, ``four-tasks``, or a list such as ``red:200,green:100,red:50``
    (a task without ``:N`` runs for ``generations``)."""
    if spec in NAMED_SCHEDULES:
        items = [(name, generations) for name in NAMED_SCHEDULES[spec]]
    else:
        items = []
        for item in spec.split(","):
            name, _, count = item.strip().partition(":")
            if name not in TASKS:
                raise ScheduleError(
                    f"unknown task {name!r} in schedule {spec!r}: use {', '.join(TASKS)} "
                    f"(or a named schedule: {', '.join(NAMED_SCHEDULES)})")
            try:
                n = int(count) if count else generations
            except ValueError:
                raise ScheduleError(f"bad generation count {count!r} in schedule item {item!r}: write e.g. red:200") from None
            items.append((name, n))
    if any(not 1 <= n <= MAX_GENERATIONS for _, n in items):
        raise ScheduleError(f"every task of schedule {spec!r} needs from 1 to {MAX_GENERATIONS} generations")
    return [Phase(TASKS[name], n) for name, n in items]


def distinct_tasks(phases: list[Phase]) -> list[Task]:
    """Each task of the schedule once, in order of first appearance."""
    seen: dict[str, Task] = {}
    for phase in phases:
        seen.setdefault(phase.name, phase.task)
    return list(seen.values())


def arena_colors(phases: list[Phase]) -> tuple[int, ...]:
    """The arena's colour list: every colour up to the highest one the schedule uses."""
    return colors_for_tasks([p.task for p in phases])
