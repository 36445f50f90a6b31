"""The run directory, a stable contract other tools read:

``runs/<name>/config.json``   the resolved configuration and library versions
``runs/<name>/metrics.csv``   one row per generation
``runs/<name>/species.csv``   NEAT only: generation, species_id, size (one row per species alive)
``runs/<name>/summary.json``  the paper's table values and the continual-learning metrics
``runs/<name>/recording.rrd`` the Rerun recording
``runs/<name>/checkpoints/``  the last two checkpoints (see ``lifelong_evo.checkpoint``)
``runs/<name>/controllers/``  exported controllers (JSON: neat-python genomes or MLP parameters)
"""
from __future__ import annotations

import csv
import io
import json
import math
import platform
import shutil
from importlib import metadata
from pathlib import Path
from typing import Any, Iterable

from .checkpoint import atomic_write_bytes
from .errors import UserError


class RunDirError(UserError):
    """A run directory, or one of its files, that is missing or not what the contract says."""


def library_versions() -> dict[str, str]:
    versions = {"python": platform.python_version()}
    for package in ("torch", "neat-python", "evotorch", "numpy", "gymnasium", "rerun-sdk", "lifelong-evo"):
        try:
            versions[package] = metadata.version(package)
        except metadata.PackageNotFoundError:
            versions[package] = "not installed"
    return versions


def write_json(path: Path, value: Any) -> None:
    atomic_write_bytes(path, (json.dumps(value, indent=2, default=_jsonable) + "\n").encode())


def _jsonable(value):
    if hasattr(value, "tolist"):
        return value.tolist()
    raise TypeError(f"{type(value).__name__} is not JSON serialisable")


def read_json(path: Path) -> Any:
    try:
        return json.loads(Path(path).read_text())
    except FileNotFoundError:
        raise RunDirError(f"{path} does not exist: is this a run directory?") from None
    except json.JSONDecodeError as error:
        raise RunDirError(f"{path} is not valid JSON ({error})") from None


class RunDir:
    """Paths of one run directory, and its creation rules."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.config = self.path / "config.json"
        self.metrics = self.path / "metrics.csv"
        self.species = self.path / "species.csv"
        self.summary = self.path / "summary.json"
        self.recording = self.path / "recording.rrd"
        self.checkpoints = self.path / "checkpoints"
        self.controllers = self.path / "controllers"

    def create(self, overwrite: bool) -> None:
        if self.path.exists() and not self.path.is_dir():
            raise RunDirError(f"run directory {self.path} is a file: choose another --name or --out")
        if self.path.exists() and any(self.path.iterdir()):
            if not overwrite:
                raise RunDirError(f"run directory {self.path} already exists: pass --resume to continue it, "
                                  "--overwrite to start it again, or --name for a new one")
            shutil.rmtree(self.path)
        try:
            self.checkpoints.mkdir(parents=True, exist_ok=True)
            self.controllers.mkdir(parents=True, exist_ok=True)
        except OSError as error:  # e.g. --out names a file, or a folder this user cannot write
            raise RunDirError(f"cannot make run directory {self.path}: {error.strerror}: "
                              "choose another --out or --name") from None

    def checkpoint_files(self) -> list[Path]:
        """The checkpoints, oldest first."""
        return sorted(self.checkpoints.glob("generation-*.pt"))

    def latest_checkpoint(self) -> Path | None:
        found = self.checkpoint_files()
        return found[-1] if found else None

    def checkpoint_path(self, generation: int) -> Path:
        return self.checkpoints / f"generation-{generation:06d}.pt"


def format_value(value) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return ""
    if isinstance(value, float):
        return repr(value)
    return str(value)


SPECIES_COLUMNS = ["generation", "species_id", "size"]


class MetricsWriter:
    """Appends CSV rows per generation, flushed at once; on resume it first cuts the file
    back to the rows of the generations the checkpoint covers (a kill may have left more)."""

    def __init__(self, path: Path, columns: list[str], keep_generations: int | None):
        self.path = path
        self.columns = columns
        kept: list[dict[str, str]] = []
        if keep_generations is not None and path.exists():
            kept = [row for row in read_metrics(path, required=("generation",))
                    if int(row["generation"]) < keep_generations]
        rows = [",".join(columns)] + [",".join(row.get(c, "") for c in columns) for row in kept]
        atomic_write_bytes(path, ("\n".join(rows) + "\n").encode())
        self.handle = open(path, "a", newline="")

    def write(self, row: dict[str, Any]) -> None:
        unknown = set(row) - set(self.columns)
        if unknown:
            raise KeyError(f"metrics row has columns not in the header: {sorted(unknown)}")
        self.handle.write(",".join(format_value(row.get(c)) for c in self.columns) + "\n")
        self.handle.flush()

    def close(self) -> None:
        self.handle.close()


FIXED_COLUMNS = ("task_index", "generation", "generation_in_task")
"""The integer columns every metrics.csv starts with, after ``task``."""
INTEGER_COLUMNS = {*FIXED_COLUMNS, "species", *SPECIES_COLUMNS}
"""Integer columns of metrics.csv and species.csv; ``task`` is text, every other column a number."""


def read_metrics(path: Path, required: tuple[str, ...] = ("task", *FIXED_COLUMNS)) -> list[dict[str, str]]:
    """Rows of a metrics.csv (or species.csv), checked against the contract: a header with the
    ``required`` columns, as many cells in each row, integers in the integer columns and numbers
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
                kind = "an integer" if column in INTEGER_COLUMNS else "a number"
                raise RunDirError(f"{path} line {number}, column {column}: {cell!r} is not {kind}")
        rows.append(row)
    return rows


def _is_metric(cell: str, integer: bool) -> bool:
    if integer:
        return cell.isascii() and cell.isdigit()
    try:
        float(cell or "nan")
    except ValueError:
        return False
    return True


def metric_columns(task_names: Iterable[str], has_species: bool, has_centre: bool,
                   diagnostics: Iterable[str] = ()) -> list[str]:
    """The metrics.csv header of a run: fixed by its schedule and algorithm (``diagnostics``:
    the optimiser's, see ``algorithms.base.Optimizer.diagnostics``)."""
    columns = ["task", *FIXED_COLUMNS]
    for prefix in ("", "reg_"):
        columns += [f"{prefix}best", f"{prefix}mean", f"{prefix}median", f"{prefix}std"]
    columns.append("top")
    if has_species:
        columns.append("species")
    if has_centre:
        columns.append("centre")
    columns += diagnostics
    for name in task_names:
        columns += [f"retention_pop_{name}", f"retention_top_{name}"]
        if has_centre:
            columns.append(f"retention_centre_{name}")
    return columns
