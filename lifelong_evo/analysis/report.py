"""Plain-text tables of a run's summary."""
from __future__ import annotations

from typing import Any

from ..summary_json import SummaryLayout


def _fmt(value) -> str:
    return "-" if value is None else f"{value:.2f}"


def duration(seconds: float) -> str:
    """A wall time to read at a glance: seconds under a minute, minutes under an hour, else hours."""
    if seconds < 60:
        return f"{seconds:.1f} s"
    if seconds < 3600:
        return f"{seconds / 60:.1f} min"
    return f"{seconds / 3600:.1f} h"


def aligned(header: list[str], rows: list[list[str]], left: tuple[int, ...] = ()) -> list[str]:
    """``header`` and ``rows`` as lines of columns as wide as their widest cell (a long task name
    widens its column), two spaces apart: the columns ``left`` names (text) aligned left, the
    others (numbers) right."""
    widths = [max(len(cell) for cell in column) for column in zip(header, *rows)]
    return ["  ".join(cell.ljust(width) if i in left else cell.rjust(width)
                      for i, (cell, width) in enumerate(zip(line, widths))).rstrip() for line in [header, *rows]]


def summary_table(summary: dict[str, Any]) -> str:
    """The paper's table for one run: current performance per phase (the population's best and
    the top individual's: they differ when a regulariser ranks the population), then retention and
    forgetting of each earlier task at each later task end, then the transfer metrics."""
    keys = SummaryLayout
    tops = summary.get(keys.CURRENT_TOP) or [None] * len(summary[keys.CURRENT])
    phases = enumerate(zip(summary[keys.PHASES], summary[keys.CURRENT], tops))
    lines = aligned(["phase", "task", "C (current)", "top individual"],
                    [[str(i), name, _fmt(c), _fmt(top)] for i, (name, c, top) in phases], left=(1,))
    if summary[keys.FORGETTING]:
        lines.append("")
        figures = ("R_pop", "F_pop", "R_top", "F_top")
        lines += aligned(["at end of", "task", *figures],
                         [[str(row["at_end_of"]), row["task"], *(_fmt(row[m]) for m in figures)]
                          for row in summary[keys.FORGETTING]], left=(1,))
    if keys.transfer("ACC", "pop") in summary:
        lines.append("")
        lines += aligned(["", *keys.TRANSFER],
                         [[level, *(_fmt(summary[keys.transfer(m, level)]) for m in keys.TRANSFER)]
                          for level in ("pop", "top")], left=(0,))
    lines.append(f"\nwall time: {duration(summary[keys.WALL_TIME])}")
    machines = summary.get(keys.MACHINES, [])
    for where in machines:
        since = "" if len(machines) == 1 else f" from generation {where['from_generation']}"
        gpu = f", {where['gpu']}" if where.get("gpu") else ""
        lines.append(f"machine{since}: {where['cpu']}, {where['vector_isa']}, {where['cpus']} CPUs{gpu}")
    return "\n".join(lines)
