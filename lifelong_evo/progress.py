"""A one-line progress display on a terminal; silent otherwise."""
from __future__ import annotations

import sys
import time


def _clock(seconds: float) -> str:
    seconds = int(seconds)
    return f"{seconds // 3600}:{seconds // 60 % 60:02d}:{seconds % 60:02d}"


class Progress:
    def __init__(self, total_generations: int, done_generations: int = 0, stream=None, enabled: bool | None = None):
        self.stream = stream or sys.stderr
        self.enabled = self.stream.isatty() if enabled is None else enabled
        self.total = total_generations
        self.start_done = done_generations
        self.start = time.monotonic()

    def update(self, generation: int, task: str, task_number: int, n_tasks: int, best: float,
               retention: dict[str, float]) -> None:
        if not self.enabled:
            return
        done = generation + 1
        elapsed = time.monotonic() - self.start
        rate = (done - self.start_done) / elapsed if elapsed > 0 else 0.0
        eta = (self.total - done) / rate if rate > 0 else 0.0
        kept = "  ".join(f"ret {name} {value:.1f}" for name, value in retention.items())
        line = (f"task {task_number}/{n_tasks} {task:<6} gen {done}/{self.total}  best {best:6.2f}  {kept}  "
                f"elapsed {_clock(elapsed)}  ETA {_clock(eta)}")
        self.stream.write("\r" + line[:160].ljust(100))
        self.stream.flush()

    def close(self) -> None:
        if self.enabled:
            self.stream.write("\n")
            self.stream.flush()
