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


def summary_table(summary: dict[str, Any]) -> str:
    """The paper's table for one run: current performance per phase (the population's best and
    the top individual's: they differ when a regulariser ranks the population), then retention and
    forgetting of each earlier task at each later task end, then the transfer metrics."""
    keys = SummaryLayout
    lines = ["phase  task     C (current)   top individual"]
    tops = summary.get(keys.CURRENT_TOP) or [None] * len(summary[keys.CURRENT])
    for i, (name, c, top) in enumerate(zip(summary[keys.PHASES], summary[keys.CURRENT], tops)):
        lines.append(f"{i:>5}  {name:<7}  {_fmt(c):>11}   {_fmt(top):>14}")
    if summary[keys.FORGETTING]:
        lines.append("")
        lines.append("at end of  task     R_pop   F_pop   R_top   F_top")
        for row in summary[keys.FORGETTING]:
            lines.append(f"{row['at_end_of']:>9}  {row['task']:<7}  {_fmt(row['R_pop']):>6}  {_fmt(row['F_pop']):>6}  "
                         f"{_fmt(row['R_top']):>6}  {_fmt(row['F_top']):>6}")
    if keys.transfer("ACC", "pop") in summary:
        lines.append("")
        lines.append("         ACC     BWT     FWT")
        for level in ("pop", "top"):
            lines.append("  ".join([f"{level:<5}", *(f"{_fmt(summary[keys.transfer(m, level)]):>6}"
                                                     for m in keys.TRANSFER)]))
    lines.append(f"\nwall time: {duration(summary[keys.WALL_TIME])}")
    machines = summary.get(keys.MACHINES, [])
    for where in machines:
        since = "" if len(machines) == 1 else f" from generation {where['from_generation']}"
        gpu = f", {where['gpu']}" if where.get("gpu") else ""
        lines.append(f"machine{since}: {where['cpu']}, {where['vector_isa']}, {where['cpus']} CPUs{gpu}")
    return "\n".join(lines)
