"""The run directory, a stable contract, and the only module that reads or writes one:

``runs/<name>/config.json``   the resolved configuration and library versions
``runs/<name>/metrics.csv``   one row per generation
``runs/<name>/species.csv``   NEAT only: generation, species_id, size (one row per species alive)
``runs/<name>/summary.json``  the paper's table values and the continual-learning metrics
``runs/<name>/recording.rrd`` the Rerun recording (``recording-resumed-<G>.rrd``: its continuations)
``runs/<name>/checkpoints/``  the last two checkpoints (see ``lifelong_evo.checkpoint``)
``runs/<name>/controllers/``  exported controllers (JSON: neat-python genomes or MLP parameters)
``runs/<name>/.lifelong-evo-run``  the marker written at creation: only a directory with it is
                              deleted by ``--overwrite``
``runs/<name>/.lock``         locked by the one process writing the run (``RunLock``)

A run name is one folder name (``check_run_name``), so a run directory is always directly inside
``--out``. ``RunDir`` names these files and writes them while a run goes; ``MetricsLayout`` spells every
metrics.csv column and flattens a ``metrics.GenerationRecord`` into a row; ``Run`` (``load_runs``,
``group_runs``) is what ``plot``, ``compare`` and ``sweep`` read back. Which runs are repetitions
of one configuration is ``RunConfig.configuration_settings``.
"""
from __future__ import annotations

import csv
import fcntl
import io
import json
import math
import os
import platform
import re
import shutil
import socket
import subprocess
import time
from dataclasses import dataclass, field, replace
from importlib import metadata
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from algorithms import REGISTRY

from . import checkpoint
from .checkpoint import atomic_write_bytes
from .config import DEFAULT_REGULARISER, RunConfig
from .errors import RunDirError
from .metrics import GenerationRecord, retention_column
from .options import flag
from .run_files import check_config, check_controller, check_metrics, check_summary
from .schedule import schedule_of

RESOLVED = (("env", "env_resolved"), ("algo_options", "algo_options_resolved"))
"""config.json's settings as given, each with its resolved form written beside it."""
RESOLVED_KEYS = ("env_resolved", "algo_options_resolved", "training_episodes", "task_definitions", "versions")
"""config.json's keys that are no RunConfig field."""


MARKER = ".lifelong-evo-run"
"""The file ``RunDir.create`` writes first into every run directory: ``--overwrite`` deletes only
a directory that holds it."""
LOCK = ".lock"
"""The file in every run directory that the process writing the run holds locked (``RunLock``)."""
SWEEP_FILE = "sweep.json"
"""The file a sweep writes first into its folder (``commands/sweep.py``): a folder with it is a
sweep's, whose run directories are its trials inside it, and never a run directory itself."""


class ResumeError(RunDirError):
    """A run directory that these settings cannot continue, or start from."""


def _as_stored(value: Any) -> Any:
    """``value`` as config.json holds it (tuples are lists; 11 and 11.0 compare equal)."""
    return json.loads(json.dumps(value))


class RunDirInUseError(RunDirError):
    """A run directory whose lock another process holds."""

    def __init__(self, path: Path, holder: str, fix: str = "or choose another --name"):
        super().__init__(f"run directory {path} is in use by {holder}: wait for it to end (or stop it), {fix}")


NAME_MAX = 255
"""The longest folder name, in bytes, that Linux's and macOS's file systems take."""


def _name_bytes(name: str) -> int:
    """The length of folder name ``name`` as the file system counts it (``NAME_MAX``)."""
    return len(os.fsencode(name))


def check_run_name(name: Any, what: str = "--name",
                   fix: str = "give a folder name, and --out for the folder it goes in") -> str:
    """``name`` if it is one folder name (not empty, ``.`` or ``..``, without ``/``, ``\\`` or NUL,
    at most ``NAME_MAX`` bytes), so that the run directory it names lies directly inside
    ``--out``; RunDirError otherwise."""
    if not isinstance(name, str) or name in ("", ".", "..") or any(c in name for c in "/\\\0"):
        raise RunDirError(f"{what} {name!r} is not one folder name (a run name is not empty, '.' or '..' "
                          f"and has no / or \\ in it): {fix}")
    if _name_bytes(name) > NAME_MAX:
        raise RunDirError(f"{what} {name[:40]!r}... is {_name_bytes(name)} bytes long, longer than a folder "
                          f"name may be ({NAME_MAX} bytes): give a shorter one")
    return name


def check_out_folder(out: str | Path) -> Path:
    """``--out`` as a path, if each folder name in it is one a file system takes (at most
    ``NAME_MAX`` bytes) and the nearest part of it that exists is a folder; RunDirError otherwise."""
    path = Path(out)
    too_long = [part for part in path.parts if _name_bytes(part) > NAME_MAX]
    if too_long:
        raise RunDirError(f"--out {str(out)[:40]!r}... has a folder name of {_name_bytes(too_long[0])} bytes, "
                          f"longer than a folder name may be ({NAME_MAX} bytes): choose another --out")
    existing = next((p for p in (path, *path.parents) if p.exists()), None)
    if existing is not None and not existing.is_dir():
        raise RunDirError(f"--out {str(out)!r} cannot be a folder: {existing} is a file: choose another --out")
    return path


def package_version(package: str) -> str:
    """An installed distribution's version, or ``not installed``."""
    try:
        return metadata.version(package)
    except metadata.PackageNotFoundError:
        return "not installed"


def library_versions() -> dict[str, str]:
    versions = {"python": platform.python_version()}
    for package in ("torch", "neat-python", "evotorch", "numpy", "gymnasium", "rerun-sdk", "lifelong-evo"):
        versions[package] = package_version(package)
    versions["lifelong-evo-commit"] = source_commit()
    return versions


CODE_FOLDERS = ("lifelong_evo", "algorithms", "envs")
"""The toolkit's packages, whose source a run's commit names."""


def source_commit(package: Path = Path(__file__).resolve().parent) -> str:
    """The git commit of the code this process imports: ``HEAD`` of the checkout that tracks
    ``package``, with `` + local changes`` when a tracked file of the toolkit's packages differs from
    it; ``unknown`` for an installed copy (git does not track it: a version number is all there is),
    or without git. Two runs of one version number can differ in code between commits; this tells."""
    def git(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run(["git", "-C", str(package), *args], capture_output=True, text=True, timeout=30)
    try:
        tracked = git("ls-files", "--error-unmatch", "__init__.py")
        head = git("rev-parse", "HEAD")
        if tracked.returncode or head.returncode:
            return "unknown"
        # ":/" names a path from the checkout's top, wherever ``package`` lies in it
        changed = git("diff", "--quiet", "HEAD", "--", *(f":/{folder}" for folder in CODE_FOLDERS))
    except (OSError, subprocess.TimeoutExpired):
        return "unknown"
    return head.stdout.strip() + (" + local changes" if changed.returncode else "")


def usable_cpus() -> int:
    """The CPUs this process may run on (its affinity where the system has one, else all)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def machine(device: str) -> dict[str, Any]:
    """The machine a process runs on, as far as it can change a run's numbers or its speed: the
    CPU's name (with its family and model where Linux gives them: a VM often names only the
    vendor's line), the widest vector instructions torch's kernels use on it (AVX2, AVX512, ...:
    torch's and the compiled code's rounding follows them), the CPUs this process may use, and
    the GPU when ``device`` is one."""
    import torch  # here, not above: reading and checking run directories needs no torch

    cpu = platform.processor() or platform.machine()
    try:
        lines = Path("/proc/cpuinfo").read_text().splitlines()[:30]
        fields = {key.strip(): value.strip() for key, value in (line.split(":", 1) for line in lines if ":" in line)}
        if "model name" in fields:
            cpu = f"{fields['model name']} (family {fields.get('cpu family', '?')}, model {fields.get('model', '?')})"
    except OSError:  # not Linux
        pass
    described: dict[str, Any] = {"cpu": cpu, "vector_isa": torch.backends.cpu.get_cpu_capability(),
                                 "cpus": usable_cpus()}
    if device.startswith("cuda"):
        described["gpu"] = torch.cuda.get_device_name(torch.device(device))
    return described


def write_json(path: Path, value: Any) -> None:
    atomic_write_bytes(path, (json.dumps(value, indent=2, default=_jsonable) + "\n").encode())


def _jsonable(value):
    if hasattr(value, "tolist"):
        return value.tolist()
    raise TypeError(f"{type(value).__name__} is not JSON serialisable")


def read_json(path: Path) -> Any:
    try:
        return json.loads(Path(path).read_text())
    except (FileNotFoundError, NotADirectoryError):
        raise RunDirError(f"{path} does not exist: is this a run directory?") from None
    except (OSError, UnicodeDecodeError) as error:
        raise RunDirError(f"cannot read {path}: {getattr(error, 'strerror', None) or error}") from None
    except json.JSONDecodeError as error:
        raise RunDirError(f"{path} is not valid JSON ({error})") from None


class RunLock:
    """The lock of one run directory (its ``LOCK`` file, ``fcntl.flock``), taken at once or refused
    with RunDirInUseError naming the process that holds it; then the file holds this process's
    PID and host. The kernel releases it when the process ends, however it ends (SIGKILL too),
    so a lock left behind never blocks a resume. Release it with ``release`` or a ``with`` block."""

    def __init__(self, path: Path):
        self.path = path
        self._fd: int | None = None
        lock_file = path / LOCK
        try:
            self._fd = os.open(lock_file, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as error:
            raise RunDirError(f"cannot lock run directory {path}: {error.strerror} ({lock_file}): "
                              "choose another --out or --name") from None
        try:
            fcntl.flock(self._fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as error:
            os.close(self._fd)
            self._fd = None
            if isinstance(error, BlockingIOError):
                raise RunDirInUseError(path, lock_holder(lock_file)) from None
            raise RunDirError(f"cannot lock run directory {path}: {error.strerror}: "
                              "put --out on a file system that supports locks") from None
        os.ftruncate(self._fd, 0)
        os.write(self._fd, json.dumps({"pid": os.getpid(), "host": socket.gethostname()}).encode())

    def release(self) -> None:
        """Let go of the lock (again: nothing); the file is emptied first, as nobody holds it then."""
        if self._fd is not None:
            os.ftruncate(self._fd, 0)
            os.close(self._fd)  # closing releases the flock
            self._fd = None

    def __del__(self) -> None:
        # a run that fails between taking its lock and the loop's ``finally`` lets go of it with this object
        self.release()

    def __enter__(self) -> RunLock:
        return self

    def __exit__(self, *exc) -> None:
        self.release()


def lock_holder(lock_file: Path) -> str:
    """The process a run directory's lock file names: ``process 1234 on host node1``."""
    try:
        holder = json.loads(lock_file.read_text())
        return f"process {int(holder['pid'])} on host {holder['host']}"
    except (OSError, ValueError, TypeError, KeyError):  # taken a moment ago: its PID is not written yet
        return "another process"


def run_directory_around(path: Path) -> Path | None:
    """The run directory (it holds the ``MARKER``) that ``path`` lies inside, if any: a run's
    ``--overwrite`` deletes everything in it."""
    return next((folder for folder in Path(path).resolve().parents if (folder / MARKER).is_file()), None)


class RunDir:
    """The files of one run directory, and the rules for making, writing and reading them."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.config = self.path / "config.json"
        self.metrics = self.path / "metrics.csv"
        self.species = self.path / "species.csv"
        self.summary = self.path / "summary.json"
        self.recording = self.path / "recording.rrd"
        self.checkpoints = self.path / "checkpoints"
        self.controllers = self.path / "controllers"
        self.marker = self.path / MARKER
        self.lock_file = self.path / LOCK

    @classmethod
    def inside(cls, out: str | Path, name: Any, what: str = "--name", **fix) -> RunDir:
        """The run directory ``name`` directly inside ``out``; RunDirError unless ``name`` is one
        folder name (``check_run_name``)."""
        return cls(check_out_folder(out) / check_run_name(name, what, **fix))

    def is_same_directory(self, other: RunDir) -> bool:
        """Whether ``other`` names this directory, by whatever path: relative or absolute, with a
        trailing slash or ``..``, through a symbolic link (the file system decides where both exist)."""
        try:
            return os.path.samefile(self.path, other.path)
        except OSError:  # one of them does not exist (yet): where they would be
            return self.path.resolve() == other.path.resolve()

    def lock(self) -> RunLock:
        """This existing run directory's lock, taken (RunDirInUseError where another process holds
        it): one writer per run directory. ``create`` takes it for a new run."""
        return RunLock(self.path)

    def in_use_by(self) -> str | None:
        """The process that holds this run directory's lock (``lock_holder``), or None."""
        try:
            fd = os.open(self.lock_file, os.O_RDONLY)
        except OSError:  # no lock file: nobody has locked it
            return None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            return lock_holder(self.lock_file)
        finally:
            os.close(fd)
        return None

    def holds_a_run(self) -> bool:
        """Whether this folder is a run directory: it holds the ``MARKER``, or config.json (a run
        directory written before the marker existed)."""
        return self.marker.is_file() or self.config.is_file()

    def check_create(self, overwrite: bool) -> None:
        """What ``create`` refuses, checked without writing anything: a directory another process
        holds locked (RunDirInUseError), a file where the directory goes, a sweep's folder, a place
        inside another run directory (whose ``--overwrite`` would delete this one), and an existing
        directory that holds anything (its lock file aside), unless ``overwrite`` and it is a run
        directory lifelong-evo wrote (it holds the ``MARKER``)."""
        self.check_free()
        self.check_not_a_sweep()
        outer = run_directory_around(self.path)
        if outer is not None:
            raise RunDirError(f"--out {self.path.parent} is inside run directory {outer}, whose --overwrite would "
                              "delete this run too: choose another --out")
        self._check_contents(overwrite)

    def check_not_a_sweep(self) -> None:
        """RunDirError where this path is a sweep's folder (it holds ``SWEEP_FILE``), not a run directory."""
        if (self.path / SWEEP_FILE).is_file() and not self.holds_a_run():
            raise RunDirError(f"{self.path} is a sweep's folder (it holds {SWEEP_FILE}), not a run directory: its "
                              "trials are the run directories inside it; choose another --name or --out")

    def check_free(self, **fix) -> None:
        """RunDirInUseError (with ``fix``, if given, as its advice) where another process holds this
        run directory's lock."""
        holder = self.in_use_by()
        if holder is not None:
            raise RunDirInUseError(self.path, holder, **fix)

    def _check_contents(self, overwrite: bool) -> None:
        try:
            if self.path.exists() and not self.path.is_dir():
                raise RunDirError(f"run directory {self.path} is a file: choose another --name or --out")
            if not self.path.exists() or not any(p.name != LOCK for p in self.path.iterdir()):
                return
        except OSError as error:  # a name too long, a folder that cannot be read
            raise RunDirError(f"cannot read run directory {self.path}: {error.strerror}: "
                              "choose another --out or --name") from None
        if not overwrite:
            raise RunDirError(f"run directory {self.path} already exists: pass --resume to continue it, "
                              "--overwrite to start it again, or --name for a new one")
        if self.path.is_symlink():
            raise RunDirError(f"{self.path} is a symbolic link: --overwrite deletes only a run directory inside "
                              "--out; delete it yourself or choose another --name")
        if not self.marker.is_file():
            if self.config.is_file():
                raise RunDirError(f"{self.path} was written before lifelong-evo marked its run directories (no "
                                  f"{MARKER}), so --overwrite does not delete it: delete it yourself or choose "
                                  "another --name")
            raise RunDirError(f"{self.path} was not written by lifelong-evo (no {MARKER} marker): delete it "
                              "yourself or choose another --name")

    def create(self, overwrite: bool) -> RunLock:
        """Make the run directory, or with ``overwrite`` empty one that lifelong-evo wrote, and
        return its lock, held: refused (``check_create``, RunDirInUseError) before anything is
        written. With ``overwrite`` the lock is taken on the existing directory before anything in
        it is deleted, so a run still writing there is never touched."""
        self.check_create(overwrite)
        try:
            self.path.mkdir(parents=True, exist_ok=True)
        except OSError as error:  # e.g. --out names a file, or a folder this user cannot write
            raise RunDirError(f"cannot make run directory {self.path}: {error.strerror}: "
                              "choose another --out or --name") from None
        lock = self.lock()
        try:
            self._check_contents(overwrite)  # again, locked: another process may have written it meanwhile
            for entry in self.path.iterdir():
                if entry.name == LOCK:  # kept: there is no moment without the lock
                    continue
                if entry.is_dir() and not entry.is_symlink():
                    shutil.rmtree(entry)
                else:
                    entry.unlink()
            write_json(self.marker, {"written_by": "lifelong-evo", "version": package_version("lifelong-evo"),
                                     "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())})
            self.checkpoints.mkdir()
            self.controllers.mkdir()
        except OSError as error:
            lock.release()
            raise RunDirError(f"cannot make run directory {self.path}: {error.strerror} ({error.filename}): "
                              "choose another --out or --name") from None
        except BaseException:
            lock.release()
            raise
        return lock

    # -- config.json, summary.json, controllers/ --------------------------------------------------

    def write_config(self, config: RunConfig) -> None:
        """config.json: every RunConfig field, the resolved environment and algorithm options
        (defaults included), each phase's training episodes per task, every task's full
        definition and the library versions."""
        write_json(self.config, {**config.to_dict(), "env_resolved": config.env_config().to_dict(),
                                 "algo_options_resolved": config.algo_options_resolved(),
                                 "training_episodes": config.training_plan(),
                                 "task_definitions": config.task_definitions(), "versions": library_versions()})

    def read_config(self) -> RunConfig:
        """The configuration the run was created with, checked (``run_files.check_config``)."""
        return check_config(read_json(self.config), self.config, RESOLVED_KEYS)

    def setting_differences(self, stated: dict[str, Any]) -> list[str]:
        """Each setting that would change this run's numbers in which ``stated`` differs from the
        settings the run was created with, as ``--flag value (stored: value)``: the one rule by which
        a run is continued (``continuation``) or another run takes over its first task
        (``loop.lifelong``'s ``start_from``).

        ``stated``: settings as a command gives them (some of ``RunConfig``'s fields, their values
        typed or as text; ``env`` and ``algo_options`` key by key) or a whole configuration
        (``RunConfig.to_dict()``, a sweep's trial). The statement is laid over the stored settings
        and validated (ConfigError for a bad value); then every setting but the output settings is
        compared, the environment and the optimiser's options resolved as config.json says the run
        resolved them, so a default stated in one and left out in the other is one setting. Where
        the optimiser differs, its options and regulariser are not compared: they are another
        optimiser's, which nobody stated, and ``--algo`` alone is the difference."""
        stored = self.read_config()
        written = read_json(self.config)
        algo = stated.get("algo", stored.algo)
        same_algo = algo == stored.algo
        keep_options = stored.algo_options if same_algo else {}  # another optimiser's options mean nothing
        base = stored if same_algo else replace(stored, regulariser=DEFAULT_REGULARISER)  # nor its regulariser
        given = replace(base, **{k: v for k, v in stated.items() if k not in ("env", "algo_options")},
                        env={**stored.env, **stated.get("env", {})},
                        algo_options={**keep_options, **stated.get("algo_options", {})}).validate(machine=False)
        differences = []
        for name, value in RunConfig.outcome_settings(given.to_dict()).items():
            if name in ("algo_options", "regulariser") and not same_algo:
                continue
            if name in ("env", "algo_options"):
                flag, mine = ("--env", given.env_config().to_dict()) if name == "env" else \
                    ("--option", given.algo_options_resolved())
                theirs = written.get(f"{name}_resolved") or (stored.env_config().to_dict() if name == "env"
                                                             else {**stored.algo_options_resolved()})
                mine, theirs = _as_stored(mine), _as_stored(theirs)
                differences += [f"{flag} {key}={mine.get(key)!r} (stored: {theirs[key]!r})" if key in theirs
                                else f"{flag} {key}={mine.get(key)!r} (stored: not set)"
                                for key in sorted(set(mine) | set(theirs)) if mine.get(key) != theirs.get(key)]
            elif _as_stored(value) != _as_stored(getattr(stored, name)):
                differences.append(f"--{name.replace('_', '-')} {value!r} (stored: {getattr(stored, name)!r})")
        # a task's definition can change without a setting changing (a built-in task of another
        # version); a run written before config.json recorded them ran the paper's tasks
        theirs = written.get("task_definitions")
        if theirs is not None:
            mine = _as_stored(given.task_definitions())
            differences += [f"task {name}: {mine.get(name)!r} (stored: {theirs.get(name)!r})"
                            for name in sorted(set(mine) | set(theirs)) if mine.get(name) != theirs.get(name)]
        return differences

    def first_task_differences(self, stated: dict[str, Any]) -> list[str]:
        """``setting_differences`` that would make a run of ``stated`` differ from this one before
        the first task's end: all but ``RunConfig.AFTER_FIRST_TASK_SETTINGS``. None: the two share
        their first task (``--start-from``)."""
        after = tuple(f"{flag(name)} " for name in RunConfig.AFTER_FIRST_TASK_SETTINGS)
        return [difference for difference in self.setting_differences(stated) if not difference.startswith(after)]

    def continuation(self, stated: dict[str, Any]) -> RunConfig:
        """The configuration to continue this run with: the one it was created with, and the output
        settings ``stated`` gives (``RunConfig.OUTPUT_SETTINGS``: they change no number). Any other
        setting ``stated`` gives must be the stored one (``setting_differences``), else ResumeError
        naming each difference with both values."""
        differences = self.setting_differences(stated)
        if differences:
            raise ResumeError(f"{self.path} was run with other settings than these: {'; '.join(differences)}: "
                              "continue it with its stored settings (drop those flags or give the stored "
                              "values), or start a new run (another --name, or --overwrite to replace it)")
        outputs = {name: stated[name] for name in RunConfig.OUTPUT_SETTINGS if name in stated}
        return replace(self.read_config(), **outputs).validate(machine=False)

    def write_summary(self, summary: dict[str, Any]) -> None:
        write_json(self.summary, summary)

    def read_summary(self) -> dict[str, Any] | None:
        """summary.json, or None where there is none or it cannot be read (a run killed early)."""
        try:
            return read_json(self.summary) if self.summary.exists() else None
        except RunDirError:
            return None

    def checked_summary(self) -> dict[str, Any] | None:
        """summary.json checked against config.json (``run_files.check_summary``), or None where
        there is none yet; RunDirError where it cannot be read or breaks the contract."""
        if not self.summary.exists():
            return None
        return check_summary(read_json(self.summary), self.summary, self.read_config())

    def write_controller(self, name: str, exported: dict[str, Any]) -> None:
        """controllers/<name>.json (names: ``metrics.controller_key``, and ``final-top``)."""
        write_json(self.controllers / f"{name}.json", exported)

    def read_controllers(self) -> dict[str, dict[str, Any]]:
        """Every controller in controllers/ by name (file stem), sorted by name, each checked to
        play in the run's arena (``run_files.check_controller``)."""
        files = sorted(self.controllers.glob("*.json"))
        config = self.read_config() if files else None
        return {path.stem: check_controller(read_json(path), path, config) for path in files}

    def read_controller(self, path: Path) -> dict[str, Any]:
        """The controller in ``path`` (``find_controller``'s), checked to play in the run's arena."""
        return check_controller(read_json(path), path, self.read_config())

    def find_controller(self, which: str) -> tuple[Path, str]:
        """(controller file, label) for ``which``: ``final``, ``task<N>`` (the top individual at
        the end of phase N), a file stem in controllers/, or a path to a controller .json."""
        folder = self.controllers
        given = Path(which)
        if given.suffix == ".json" and given.is_file():
            return given, re.sub(r"[^A-Za-z0-9-]+", "-", given.stem)
        available = sorted(p.stem for p in folder.glob("*.json")) if folder.is_dir() else []
        if which == "final":
            candidates = [folder / "final-top.json"]
        elif re.fullmatch(r"task\d+", which):
            candidates = sorted(folder.glob(f"{which}-*-top.json"))
        else:
            candidates = [folder / f"{which}.json", folder / f"{which}-top.json"]
        for candidate in candidates:
            if candidate.is_file():
                return candidate, which
        if not available:
            raise RunDirError(f"{self.path} has no stored controller yet (controllers/ is empty): "
                              "they are written at each task end")
        raise RunDirError(f"no controller {which!r} in {folder}: use final, task<N> or one of {', '.join(available)}")

    # -- checkpoints/ -----------------------------------------------------------------------------

    def checkpoint_files(self) -> list[Path]:
        """The checkpoints, oldest first."""
        return sorted(self.checkpoints.glob("generation-*.pt"))

    def latest_checkpoint(self) -> Path | None:
        found = self.checkpoint_files()
        return found[-1] if found else None

    @property
    def first_task_end(self) -> Path:
        """A copy of the checkpoint at the first task's end, kept for runs that share the first
        task (``--start-from``): they differ only in ``RunConfig.AFTER_FIRST_TASK_SETTINGS``."""
        return self.checkpoints / "first-task-end.pt"

    def save_first_task_end(self, payload: dict[str, Any]) -> None:
        checkpoint.save(self.first_task_end, payload)

    def checkpoint_path(self, generation: int) -> Path:
        return self.checkpoints / f"generation-{generation:06d}.pt"

    def save_checkpoint(self, generation: int, payload: dict[str, Any]) -> None:
        """The checkpoint after ``generation`` generations; only the last two are kept."""
        checkpoint.save(self.checkpoint_path(generation), payload)
        for old in self.checkpoint_files()[:-2]:
            old.unlink()

    # -- recordings ---------------------------------------------------------------------------------

    def recording_path(self, resume: bool) -> Path:
        """Where a run's recording goes: recording.rrd, or for a resumed run (Rerun cannot append
        to an .rrd file) ``recording-resumed-<G>.rrd``, G the generation of the checkpoint it
        continues from."""
        latest = self.latest_checkpoint() if resume else None
        if latest is None:
            return self.recording
        generation = int(re.sub(r"\D", "", latest.stem) or 0)
        return self.path / f"recording-resumed-{generation:06d}.rrd"

    def recording_files(self, replays: bool = False) -> list[Path]:
        """recording.rrd and its continuations, in order (and the replays' recordings)."""
        files = ([self.recording] if self.recording.is_file() else []) \
            + sorted(self.path.glob("recording-resumed-*.rrd"))
        return files + (sorted(self.path.glob("replay-*.rrd")) if replays else [])

    def replay_recording(self, controller: str, task: str) -> Path:
        """``replay-<task>.rrd`` for the final controller, else ``replay-<controller>-<task>.rrd``."""
        return self.path / (f"replay-{task}.rrd" if controller == "final" else f"replay-{controller}-{task}.rrd")


# ---------------------------------------------------------------------------------------------
# metrics.csv and species.csv: every column name is spelled here


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
    per ``GenerationRecord``. ``resumed_at``: the generations a resumed run keeps."""

    def __init__(self, run_dir: RunDir, layout: MetricsLayout, resumed_at: int | None):
        self.layout = layout
        self.metrics = CsvLog(run_dir.metrics, layout.columns, resumed_at)
        self.species = CsvLog(run_dir.species, SPECIES_COLUMNS, resumed_at) if layout.species else None

    def write(self, record: GenerationRecord) -> None:
        self.metrics.write(self.layout.row(record))
        if self.species is not None:
            for species_id, size in sorted(record.species_sizes.items()):
                self.species.write({"generation": record.generation, "species_id": species_id, "size": size})

    def close(self) -> None:
        self.metrics.close()
        if self.species is not None:
            self.species.close()


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


# ---------------------------------------------------------------------------------------------
# Reading runs back: what plot, compare and sweep see


@dataclass
class Run:
    """One run directory as the figures and the comparison read it."""

    path: Path
    config: dict[str, Any]
    """config.json as written (RunConfig's fields, ``env_resolved``, ``algo_options_resolved``,
    ``versions``)."""
    summary: dict[str, Any]
    metrics: list[dict[str, str]] = field(default_factory=list)
    """metrics.csv's rows, checked by ``read_metrics`` and against the schedule (``metrics_rows``)."""

    @property
    def seed(self):
        return self.config.get("seed")

    @property
    def key(self) -> str:
        return config_key(self.config)

    @property
    def finished(self) -> bool:
        """Every task of the schedule has ended (summary.json names them all)."""
        schedule = schedule_of(self.config)
        return len(self.summary.get("phases", [])) == len(schedule)

    def metrics_rows(self) -> list[dict[str, str]]:
        """metrics.csv's rows (none where the run has no metrics.csv), checked by ``read_metrics``
        and against config.json's schedule (``run_files.check_metrics``)."""
        path = self.path / "metrics.csv"
        if not path.exists():
            return []
        settings = check_config(self.config, self.path / "config.json", RESOLVED_KEYS)
        return check_metrics(read_metrics(path), path, settings)

    def column(self, name: str) -> np.ndarray:
        """A metrics.csv column as floats over generations (NaN where empty or absent)."""
        return np.array([_float(row.get(name, "")) for row in self.metrics], dtype=float)

    @property
    def generations(self) -> np.ndarray:
        return np.array([int(row["generation"]) for row in self.metrics], dtype=int)

    @property
    def tasks(self) -> list[str]:
        """The tasks of the metrics rows, one per generation."""
        return [row["task"] for row in self.metrics]

    def species_rows(self) -> list[tuple[int, int, int]] | None:
        """species.csv as (generation, species_id, size); None where the run has none."""
        path = self.path / "species.csv"
        if not path.exists():
            return None
        # checked as metrics.csv is: a broken line is an error naming it, a half-written last one dropped
        return [(int(row["generation"]), int(row["species_id"]), int(row["size"]))
                for row in read_metrics(path, required=SPECIES_COLUMNS)]


def _float(text: str) -> float:
    return float(text) if text else float("nan")  # read_metrics let only numbers and blanks through


def configuration_of(config: dict[str, Any]) -> dict[str, Any]:
    """The settings of a config.json that make runs different configurations
    (``RunConfig.configuration_settings``; the library versions and the training plan are no setting). Where config.json
    holds the resolved environment and algorithm options, they stand for the ones given, so a
    default stated and a default left out are one configuration. (A run written before
    ``algo_options_resolved`` existed keeps its options as given: the defaults it ran with may
    not be today's, as NEAT's ``genetics`` shows.) Without a regulariser (``reg == 0``) the
    options that shape only the regulariser (``Optimizer.regularizer_options``) are no setting:
    such runs evolve the same controllers whatever those options say."""
    # a setting that config.json lacks (written before the setting existed) ran at its default
    # the training plan follows from the settings beside it, which compare already
    values = {**RunConfig().to_dict(), **RunConfig.WRITTEN_BEFORE,
              **{k: v for k, v in config.items() if k not in ("versions", "training_episodes", "task_definitions")}}
    values["regulariser"] = RunConfig.regulariser_of(values)
    for given, resolved in RESOLVED:
        if resolved in values:
            values.pop(given, None)
    algo = REGISTRY.get(str(values.get("algo")))
    if not values.get("reg"):
        values.pop("regulariser")  # no regulariser: the choice of one is no setting
    if algo is not None and not values.get("reg"):
        for key in ("algo_options", "algo_options_resolved"):
            if isinstance(values.get(key), dict):
                values[key] = {k: v for k, v in values[key].items() if k not in algo.regularizer_options}
    return RunConfig.configuration_settings(values)


def config_key(config: dict[str, Any]) -> str:
    """A canonical string of a config.json's configuration: equal for repetitions of one."""
    return json.dumps(configuration_of(config), sort_keys=True)


BASELINES_OFF = {key: getattr(RunConfig(), key) for key in RunConfig.BASELINE_SETTINGS}
"""Each baseline setting's value when it is off (its default), as config.json writes it."""


def config_differences(config: dict[str, Any], others: list[dict[str, Any]]) -> list[str]:
    """What sets ``config`` apart from ``others`` beyond algorithm, lambda and schedule, as
    ``KEY=VALUE`` items: an algorithm option only among runs of the same algorithm, each option
    and environment setting by itself (``genetics=2.0``, ``env.see_other_agents=True``). A
    regulariser's option only against runs that have one (not those at ``reg == 0``), the
    regulariser itself (``regulariser=wp``) likewise and among runs of the same algorithm, in place
    of the options that choose it (``importance``), a baseline
    setting (``RunConfig.BASELINE_SETTINGS``) only where it is on: fine-tuning is the plain label,
    a baseline ``rehearsal=0.3`` or ``joint=True``."""
    mine = configuration_of(config)
    theirs = [configuration_of(o) for o in others]
    same_algo = [t for t, o in zip(theirs, others) if o.get("algo") == config.get("algo")]
    algo = REGISTRY.get(str(config.get("algo")))
    regularizer_only = set(algo.regularizer_options) if algo is not None else set()
    # the options that choose a regulariser (an ES's importance): its label is regulariser=NAME
    choosing = {key for options in getattr(algo, "regularisers", {}).values() for key in options}

    def differs(settings: dict[str, Any], name: str, value: Any, is_option: bool) -> bool:
        if is_option and name in regularizer_only and name not in settings:
            return False
        return settings.get(name) != value

    differences = []
    for key in sorted(k for k in mine if k not in ("algo", "reg", "schedule")):
        value = mine[key]
        is_option = key in ("algo_options", "algo_options_resolved")
        compared = same_algo if is_option or key == "regulariser" else theirs  # as an option: one algorithm's
        if isinstance(value, dict):
            prefix = "env." if key in ("env", "env_resolved") else ""
            differences += [f"{prefix}{name}={value[name]}" for name in sorted(value)
                            if not (is_option and name in choosing)
                            and any(differs(t.get(key, {}), name, value[name], is_option) for t in compared)]
        elif key in RunConfig.BASELINE_SETTINGS and value == BASELINES_OFF[key]:
            continue
        elif any(t.get(key) != value for t in compared if key in t or key != "regulariser"):  # runs with one
            differences.append(f"{key}={value}")
    return differences


def describe_config(config: dict[str, Any], others: list[dict[str, Any]] | None = None) -> str:
    """A short label: algorithm, lambda, schedule, and what else sets the configuration apart
    from ``others`` (``config_differences``)."""
    label = f"{config.get('algo')} reg={config.get('reg', 0):g} {config.get('schedule')}"
    return " ".join([label, *config_differences(config, others or [])])


def is_run_dir(path: Path) -> bool:
    return (path / "config.json").is_file() and (path / "summary.json").is_file()


def find_run_dirs(paths) -> list[Path]:
    """Every run directory (config.json + summary.json) at or under ``paths``, sorted."""
    found: set[Path] = set()
    for given in paths:
        path = Path(given)
        if not path.exists():
            raise RunDirError(f"{path} does not exist: give run directories or folders that hold them")
        if is_run_dir(path):
            found.add(path)
            continue
        for config in path.rglob("config.json"):
            if is_run_dir(config.parent):
                found.add(config.parent)
    if not found:
        raise RunDirError(f"no run directory (config.json + summary.json) under {', '.join(map(str, paths))}: "
                          "run `python -m lifelong_evo run` first or check the path")
    return sorted(found)


def load_run(path: Path, with_metrics: bool = True) -> Run:
    """The run in ``path``, its files checked (``run_files``): config.json, summary.json against it
    and, ``with_metrics``, metrics.csv against it. ``Run.config`` is config.json as written, its
    settings as their fields type them."""
    written = read_json(path / "config.json")
    settings = check_config(written, path / "config.json", RESOLVED_KEYS)
    config = {**written, **{key: getattr(settings, key) for key in written if key not in RESOLVED_KEYS}}
    summary = check_summary(read_json(path / "summary.json"), path / "summary.json", settings)
    run = Run(path=path, config=config, summary=summary)
    if with_metrics:
        run.metrics = run.metrics_rows()
    return run


def load_runs(paths, with_metrics: bool = True) -> list[Run]:
    """Every run at or under ``paths`` (``find_run_dirs``)."""
    return [load_run(path, with_metrics) for path in find_run_dirs(paths)]


def group_runs(runs: list[Run]) -> list[list[Run]]:
    """Runs grouped by configuration (in order of first appearance), each group sorted by seed."""
    groups: dict[str, list[Run]] = {}
    for run in runs:
        groups.setdefault(run.key, []).append(run)
    return [sorted(group, key=lambda r: (str(r.seed), str(r.path))) for group in groups.values()]
