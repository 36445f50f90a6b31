"""metrics.csv and species.csv: their schema, their writer and their reader. Every column name is
spelled here.

``MetricsLayout`` is metrics.csv's schema: its columns, fixed by the schedule's tasks and the
optimiser (species for NEAT, the centre for an ES, the optimiser's diagnostics), and how a
``metrics.GenerationRecord`` fills them. ``GenerationLog`` writes a run's rows as it goes (cut
back to a checkpoint on resume), ``read_metrics`` reads a file back checked against the contract.

Contract: floats are written exactly (``repr``), the files hold no timings, so the same seed and
settings give byte-identical files; a half-written last line (a killed run) is dropped on reading.
"""
from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable

from .checkpoint import atomic_write_bytes
from .errors import RunDirError
from .metrics import GenerationRecord, retention_column

METRICS_FILE = "metrics.csv"
"""A run directory's per-generation file."""
SPECIES_FILE = "species.csv"
"""A NEAT run directory's living species per generation."""
FIXED_COLUMNS = ("task_index", "generation", "generation_in_task")
"""The integer columns every metrics.csv starts with, after ``task``."""
STATISTICS = ("best", "mean", "median", "std")
"""The columns of the raw fitness (``metrics.FitnessStats``); ``reg_`` + each: of the selection fitness."""
RETENTION_LEVELS = ("pop", "top", "centre")
"""Whose retention a column holds (``metrics.Retention``); ``centre`` for an ES only."""
SPECIES_COLUMNS = ("generation", "species_id", "size")
INTEGER_COLUMNS = {*FIXED_COLUMNS, "species", *SPECIES_COLUMNS}
"""Integer columns of metrics.csv and species.csv; ``task`` is text, every other column a number."""


def retention_columns(columns: Iterable[str], level: str) -> dict[str, str]:
    """Task -> column, of the ``level`` retention columns among a metrics.csv header."""
    prefix = retention_column(level, "")
    return {column[len(prefix):]: column for column in columns if column.startswith(prefix)}


@dataclass(frozen=True)
class MetricsLayout:
    """The columns of a run's metrics.csv, fixed by its schedule and its optimiser, and how a
    ``metrics.GenerationRecord`` fills them."""

    tasks: tuple[str, ...]
    """Every task of the schedule, once, in order: each has its retention columns."""
    species: bool
    """NEAT: the species count (and species.csv)."""
    centre: bool
    """ES: the centre's fitness and retention."""
    diagnostics: tuple[str, ...] = ()
    """The optimiser's ``diagnostics``: a column each."""

    @property
    def levels(self) -> tuple[str, ...]:
        return RETENTION_LEVELS if self.centre else RETENTION_LEVELS[:2]

    @property
    def files(self) -> tuple[str, ...]:
        """The logs it writes: metrics.csv, and species.csv where it has species."""
        return (METRICS_FILE, SPECIES_FILE) if self.species else (METRICS_FILE,)

    @property
    def columns(self) -> list[str]:
        columns = ["task", *FIXED_COLUMNS, *STATISTICS, *(f"reg_{name}" for name in STATISTICS), "top"]
        if self.species:
            columns.append("species")
        if self.centre:
            columns.append("centre")
        columns += self.diagnostics
        for task in self.tasks:
            columns += [retention_column(level, task) for level in self.levels]
        return columns

    def row(self, record: GenerationRecord) -> dict[str, Any]:
        """``record`` as metrics.csv cells by column (a column left out is written empty)."""
        row = {"task": record.task, "task_index": record.task_index, "generation": record.generation,
               "generation_in_task": record.generation_in_task, "top": record.top}
        for prefix, stats in (("", record.fitness), ("reg_", record.regularised)):
            row.update({prefix + name: getattr(stats, name) for name in STATISTICS})
        if self.species and record.species_sizes is not None:
            row["species"] = len(record.species_sizes)
        if self.centre:
            row["centre"] = record.centre
        row.update({name: record.diagnostics[name] for name in self.diagnostics})
        for task, kept in record.retention.items():
            row.update({retention_column(level, task): getattr(kept, level) for level in self.levels})
        return row


def format_value(value) -> str:
    """A cell: floats exactly (``repr``), nothing for None or NaN."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return ""
    if isinstance(value, float):
        return repr(value)
    return str(value)


class CsvLog:
    """A CSV file appended to row by row, flushed at once; on resume it first cuts the file back
    to the rows of the generations the checkpoint covers (a kill may have left more)."""

    def __init__(self, path: Path, columns: Iterable[str], keep_generations: int | None):
        self.path = path
        self.columns = list(columns)
        kept: list[dict[str, str]] = []
        if keep_generations is not None and path.exists():
            kept = [row for row in read_metrics(path, required=("generation",))
                    if int(row["generation"]) < keep_generations]
        rows = [",".join(self.columns)] + [",".join(row.get(c, "") for c in self.columns) for row in kept]
        atomic_write_bytes(path, ("\n".join(rows) + "\n").encode())
        self.handle = open(path, "a", newline="")

    def write(self, row: dict[str, Any]) -> None:
        unknown = set(row) - set(self.columns)
        if unknown:
            raise KeyError(f"{self.path.name} row has columns not in the header: {sorted(unknown)}")
        self.handle.write(",".join(format_value(row.get(c)) for c in self.columns) + "\n")
        self.handle.flush()

    def close(self) -> None:
        self.handle.close()


class GenerationLog:
    """metrics.csv, and species.csv where the layout has species: a row (and the living species)
    per ``GenerationRecord``, in the run directory ``folder``. ``resumed_at``: the generations a
    resumed run keeps."""

    def __init__(self, folder: Path, layout: MetricsLayout, resumed_at: int | None):
        self.layout = layout
        self.metrics = CsvLog(folder / METRICS_FILE, layout.columns, resumed_at)
        self.species = CsvLog(folder / SPECIES_FILE, SPECIES_COLUMNS, resumed_at) if layout.species else None

    def write(self, record: GenerationRecord) -> None:
        self.metrics.write(self.layout.row(record))
        if self.species is not None:
            for species_id, size in sorted(record.species_sizes.items()):
                self.species.write({"generation": record.generation, "species_id": species_id, "size": size})

    def close(self) -> None:
        self.metrics.close()
        if self.species is not None:
            self.species.close()


def check_continuable(folder: Path, layout: MetricsLayout, generations: int, first_checkpoint: int) -> None:
    """RunDirError unless the logs of the run directory ``folder`` can be continued after
    ``generations`` generations, its newest checkpoint's (0: it has none), without losing a row:
    each log has this run's header and a row for every one of those generations, and a run with no
    checkpoint has no row past ``first_checkpoint``, the generation its first checkpoint follows
    (it had checkpoints and lost them; starting again would drop rows no checkpoint can rebuild
    until the run gets there again)."""
    logs = [(folder / METRICS_FILE, layout.columns)]
    if layout.species:
        logs.append((folder / SPECIES_FILE, list(SPECIES_COLUMNS)))
    again = f"delete checkpoints/ and {' and '.join(layout.files)} for --resume to start it again from generation 0"
    for path, columns in logs:
        if not path.is_file():
            if generations:
                raise RunDirError(f"{path} is missing, though the newest checkpoint continues the run after "
                                  f"{generations} generations: restore it from a copy of the run, or {again}")
            continue
        held = logged_generations(path)
        with open(path, newline="") as handle:
            header = next(csv.reader(handle), [])
        if header != columns:
            lacks, extra = [c for c in columns if c not in header], [c for c in header if c not in columns]
            said = "; ".join([*([f"it lacks {', '.join(lacks)}"] if lacks else []),
                              *([f"it has {', '.join(extra)}"] if extra else [])]) or "its columns are in another order"
            raise RunDirError(f"{path}'s header is not the one this run writes ({said}): restore it from a copy "
                              f"of the run, or {again}")
        missing = [g for g in range(generations) if g not in held]
        if missing:
            raise RunDirError(f"{path} has no rows for generation(s) {spans(missing)}, which the newest checkpoint "
                              f"(after {generations} generations) follows: restore it from a copy of the run, or "
                              f"{again}")
        if not generations and held and max(held) >= first_checkpoint:
            raise RunDirError(f"{folder} has no checkpoint, though its {path.name} holds rows up to generation "
                              f"{max(held)} and the run wrote one after generation {first_checkpoint - 1}: restore "
                              f"checkpoints/ from a copy of the run, or delete {' and '.join(layout.files)} for "
                              "--resume to start it again from generation 0")


def logged_generations(path: Path) -> set[int]:
    """The generations a metrics.csv or species.csv has rows for (none: no file), read checked."""
    return {int(row["generation"]) for row in read_metrics(path, required=("generation",))} if path.is_file() else set()


def spans(numbers: list[int]) -> str:
    """Sorted whole numbers as ranges: ``8-13, 20``."""
    spans: list[list[int]] = []
    for n in numbers:
        if spans and n == spans[-1][1] + 1:
            spans[-1][1] = n
        else:
            spans.append([n, n])
    return ", ".join(str(a) if a == b else f"{a}-{b}" for a, b in spans)


def read_metrics(path: Path, required: tuple[str, ...] = ("task", *FIXED_COLUMNS)) -> list[dict[str, str]]:
    """Rows of a metrics.csv (or species.csv), checked against the contract: a header with the
    ``required`` columns, as many cells in each row, integers in the integer columns and finite numbers
    or nothing in the others but ``task``; RunDirError naming the file, line and column otherwise.
    A half-written last line (a killed run) is dropped."""
    try:
        with open(path, newline="") as handle:
            text = handle.read()
    except UnicodeDecodeError:
        raise RunDirError(f"{path} is not a text file: is it a {path.name}?") from None
    complete = text[:text.rfind("\n") + 1]
    lines = list(csv.reader(io.StringIO(complete)))
    if not lines:
        return []
    header = lines[0]
    missing = [c for c in required if c not in header]
    if missing:
        raise RunDirError(f"{path} line 1 is not a {path.name} header: it lacks the column(s) {', '.join(missing)}")
    rows = []
    for number, cells in enumerate(lines[1:], start=2):
        if len(cells) != len(header):
            raise RunDirError(f"{path} line {number} has {len(cells)} cells for the header's {len(header)} columns")
        row = dict(zip(header, cells))
        for column, cell in row.items():
            if column != "task" and not _is_metric(cell, integer=column in INTEGER_COLUMNS):
                kind = "an integer" if column in INTEGER_COLUMNS else "a finite number"
                raise RunDirError(f"{path} line {number}, column {column}: {cell!r} is not {kind}")
        rows.append(row)
    return rows


def _is_metric(cell: str, integer: bool) -> bool:
    """An integer column's digits, or a finite number or nothing (``format_value`` writes no NaN
    and no run measures an infinity: ``nan``, ``inf`` are damage)."""
    if integer:
        return cell.isascii() and cell.isdigit()
    try:
        return not cell or math.isfinite(float(cell))
    except ValueError:
        return False
