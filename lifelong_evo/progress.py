"""Progress of a lifelong run on stderr, in one of three modes (``--progress``):

``bar``    a tqdm bar, redrawn in place: the default on a terminal.
``lines``  one plain line after the first generation, at every task end and at least every
           ``interval_s`` (30 s) in between: the default where stderr is not a terminal (nohup,
           SLURM, a log file), so that a long run shows it is alive without flooding the log.
``off``    nothing.

Every display names the task, the generation, the best fitness of the generation, the latest
retention scores of earlier tasks, elapsed time and the time left.
"""
from __future__ import annotations

import sys
import time

from tqdm import tqdm

MODES = ("bar", "lines", "off")


def choose_mode(mode: str | None, stream) -> str:
    """``mode`` itself, or for None the default for ``stream``: a bar on a terminal, else lines."""
    if mode is None:
        return "bar" if stream.isatty() else "lines"
    if mode not in MODES:
        raise ValueError(f"progress mode must be one of {', '.join(MODES)}, got {mode!r}")
    return mode


class Progress:
    def __init__(self, total_generations: int, done_generations: int = 0, mode: str | None = None, stream=None,
                 interval_s: float = 30.0):
        self.stream = stream or sys.stderr
        self.mode = choose_mode(mode, self.stream)
        self.total = total_generations
        self.initial = done_generations
        self.interval_s = interval_s
        self.start = time.monotonic()
        self.last_line = self.start
        self.task_number: int | None = None
        self.retention: dict[str, float] = {}
        self.bar = None
        if self.mode == "bar":
            self.bar = tqdm(total=total_generations, initial=done_generations, file=self.stream, unit="gen",
                            dynamic_ncols=True, leave=True)

    def update(self, generation: int, task: str, task_number: int, n_tasks: int, best: float,
               retention: dict[str, float], task_end: bool = False) -> None:
        if self.mode == "off":
            return
        done = generation + 1
        if task_number != self.task_number:  # retention is of the tasks before this one: start afresh
            self.task_number = task_number
            self.retention = {}
        self.retention.update(retention)  # measured every few generations: show the latest
        description = f"task {task_number}/{n_tasks} {task}"
        stats = "  ".join([f"best {best:.2f}", *(f"ret {name} {value:.2f}" for name, value in self.retention.items())])
        if self.bar is not None:
            self.bar.set_description_str(description, refresh=False)
            self.bar.set_postfix_str(stats, refresh=False)
            self.bar.update(done - self.bar.n)
            return
        now = time.monotonic()
        if done == self.initial + 1 or task_end or now - self.last_line >= self.interval_s:
            meter = tqdm.format_meter(done, self.total, now - self.start, unit="gen", initial=self.initial,
                                      bar_format="gen {n_fmt}/{total_fmt}  {percentage:3.0f}%  "
                                                 "[{elapsed}<{remaining}, {rate_fmt}]")
            self.stream.write(f"{description:<16} {meter}  {stats}\n")
            self.stream.flush()
            self.last_line = now

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
