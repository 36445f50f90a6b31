"""The run directory, a stable contract: ``RunDir`` names its files, makes it, writes it while a
run goes, reads it back, and decides whether a run can be continued:

``runs/<name>/config.json``   the resolved configuration and library versions
``runs/<name>/metrics.csv``   one row per generation (``metrics_csv``)
``runs/<name>/species.csv``   NEAT only: generation, species_id, size (one row per species alive)
``runs/<name>/summary.json``  the paper's table values and the continual-learning metrics
``runs/<name>/recording.rrd`` the Rerun recording (``recording-resumed-<G>.rrd``: its continuations)
``runs/<name>/checkpoints/``  the last two checkpoints (see ``lifelong_evo.checkpoint``)
``runs/<name>/controllers/``  exported controllers (JSON: neat-python genomes or MLP parameters)
``runs/<name>/.lifelong-evo-run``  the marker written at creation: only a directory with it is
                              deleted by ``--overwrite``
``runs/<name>/.lock``         locked by the one process writing the run (``run_lock``)

``RunDir.setting_differences`` is the one rule by which a run is continued (``--resume``, a sweep's
trial) or another run takes over its first task (``--start-from``). Its neighbours each do one job
of the contract: ``run_names`` checks a run's name, ``run_lock`` keeps one writer per directory,
``provenance`` says what made the numbers, ``json_files`` reads and writes the JSON files,
``metrics_csv`` is metrics.csv's schema, writer and reader, ``run_files`` checks what is read,
and ``runs`` reads finished runs back for ``plot``, ``compare`` and ``sweep``.
"""
from __future__ import annotations

import os
import re
import shutil
import time
from dataclasses import fields, replace
from pathlib import Path
from typing import Any

from algorithms import REGISTRY

from . import checkpoint
from .config import DEFAULT_REGULARISER, RunConfig
from .errors import RunDirError
from .json_files import read_json, write_json
from .metrics_csv import METRICS_FILE, SPECIES_FILE
from .provenance import library_versions, package_version
from .run_files import as_json, check_config, check_controller, check_summary
from .run_lock import LOCK, RunDirInUseError, RunLock, held_by
from .run_names import check_out_folder, check_run_name
from .summary_json import SUMMARY_FILE

RESOLVED = (("env", "env_resolved"), ("algo_options", "algo_options_resolved"))
"""config.json's settings as given, each with its resolved form written beside it."""
RESOLVED_KEYS = ("env_resolved", "algo_options_resolved", "training_episodes", "task_definitions", "versions")
"""config.json's keys that are no RunConfig field."""


MARKER = ".lifelong-evo-run"
"""The file ``RunDir.create`` writes first into every run directory: ``--overwrite`` deletes only
a directory that holds it."""
SWEEP_FILE = "sweep.json"
"""The file a sweep writes first into its folder (``commands/sweep.py``): a folder with it is a
sweep's, whose run directories are its trials inside it, and never a run directory itself."""


class ResumeError(RunDirError):
    """A run directory that these settings cannot continue, or start from."""


def _reads(config: RunConfig, key: str) -> bool:
    """Whether a run of ``config`` reads its optimiser's option ``key`` as a value of its own: not
    one that chooses a regulariser (the stored ``regulariser`` says which), nor one only another
    regulariser reads (``_regulariser_option``), nor, at lambda 0, one that only weighs the penalty
    (``Optimizer.lambda_options``). Such an option changes no number of the run, and stating it is
    refused (``resolve_regulariser``)."""
    optimizer = REGISTRY[config.algo]
    return not _regulariser_option(config.algo, key, config.regulariser) and not (
        config.reg == 0 and key in optimizer.lambda_options)


def _regulariser_option(algo: str, key: str, regulariser: str | None = None, chosen_only: bool = False) -> bool:
    """Whether option ``key`` of ``algo`` chooses a regulariser (``Optimizer.regularisers``) or, unless
    ``chosen_only``, only some regularisers read it (``Optimizer.options_used_by``); with
    ``regulariser``: only those that ``regulariser`` does not read, so that a run stated with
    ``regulariser`` has it from there."""
    optimizer = REGISTRY.get(algo)
    if optimizer is None:  # an optimiser this process does not know: validating the run says so
        return False
    if key in optimizer.choosing_options():
        return True
    users = optimizer.options_used_by.get(key)
    return not chosen_only and users is not None and (regulariser is None or regulariser not in users)


def run_directory_around(path: Path) -> Path | None:
    """The run directory (it holds the ``MARKER``) that ``path`` lies inside, if any: a run's
    ``--overwrite`` deletes everything in it."""
    return next((folder for folder in Path(path).resolve().parents if (folder / MARKER).is_file()), None)


class RunDir:
    """The files of one run directory, and the rules for making, writing and reading them."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.config = self.path / "config.json"
        self.metrics = self.path / METRICS_FILE
        self.species = self.path / SPECIES_FILE
        self.summary = self.path / SUMMARY_FILE
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
        """The process that holds this run directory's lock (``run_lock.held_by``), or None."""
        return held_by(self.lock_file)

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
        (``first_task_differences``).

        ``stated``: settings as a command gives them (some of ``RunConfig``'s fields, their values
        typed or as text; ``env`` and ``algo_options`` key by key) or a whole configuration (every
        field: ``RunConfig.to_dict()``, a sweep's trial, the run that takes over a first task). The
        statement is laid over the stored settings, except a whole configuration's environment and
        options, which are whole too (a key it leaves out is at its default, not at the stored
        value), and validated (ConfigError for a bad value); then every setting but the output settings is
        compared, the environment and the optimiser's options resolved as config.json says the run
        resolved them, so a default stated in one and left out in the other is one setting. Where
        the optimiser differs, its options and regulariser are not compared: they are another
        optimiser's, which nobody stated, and ``--algo`` alone is the difference. Where a
        regulariser is stated, the stored options that chose the stored one, or that only it reads,
        are not laid under it, and a difference in them that nobody stated is the regulariser's."""
        return list(dict.fromkeys(text for _, text in self._differences(stated)))

    def _differences(self, stated: dict[str, Any]) -> list[tuple[str, str]]:
        """``setting_differences`` as ``(setting, text)``: the setting a field's name, or
        ``env.KEY``, ``algo_options.KEY`` or ``task.NAME``."""
        stored = self.read_config()
        written = read_json(self.config)
        algo = stated.get("algo", stored.algo)
        same_algo = algo == stored.algo
        whole = {field_.name for field_ in fields(RunConfig)} <= set(stated)
        # another optimiser's options mean nothing; a whole configuration states all of its own
        recorded = {} if whole else self._recorded_defaults(stored, written)
        keep_options = {**recorded.get("algo_options", {}), **stored.algo_options} if same_algo and not whole else {}
        regulariser = stated.get("regulariser", DEFAULT_REGULARISER)
        if same_algo and regulariser != DEFAULT_REGULARISER:  # the stated one's options, not the stored one's
            keep_options = {k: v for k, v in keep_options.items() if not _regulariser_option(algo, k, regulariser)}
        base = stored if same_algo else replace(stored, regulariser=DEFAULT_REGULARISER)  # nor its regulariser
        given = replace(base, **{k: v for k, v in stated.items() if k not in ("env", "algo_options")},
                        env={**({} if whole else {**recorded["env"], **stored.env}), **stated.get("env", {})},
                        algo_options={**keep_options, **stated.get("algo_options", {})}).validate(machine=False)
        differences = []
        theirs_defined = written.get("task_definitions")
        for name, value in RunConfig.outcome_settings(given.to_dict()).items():
            if name in ("algo_options", "regulariser") and not same_algo:
                continue
            if name == "tasks" and theirs_defined is not None:
                # compared below, task by task and field by field: a table the schedule never plays changes no number
                continue
            if name in ("env", "algo_options"):
                flag, mine = ("--env", given.env_config().to_dict()) if name == "env" else \
                    ("--option", given.algo_options_resolved())
                # a setting added since the run was written is at its default, which keeps the
                # numbers runs had before it existed
                theirs = {**(stored.env_config().to_dict() if name == "env" else stored.algo_options_resolved()),
                          **(written.get(f"{name}_resolved") or {})}
                mine, theirs = as_json(mine), as_json(theirs)
                # an option only another regulariser reads, which nobody stated, changes no number
                # (its default may have changed since the run was written)
                unread = set() if name == "env" or not same_algo else {
                    key for key in theirs if key not in stated.get("algo_options", {}) and key in
                    REGISTRY[algo].options_used_by and not _reads(given, key) and not _reads(stored, key)}
                differences += [(f"{name}.{key}", f"{flag} {key}={mine.get(key)!r} (stored: {theirs[key]!r})")
                                for key in sorted(theirs) if mine.get(key) != theirs[key] and key not in unread]
            elif as_json(value) != as_json(getattr(stored, name)):
                differences.append((name, f"--{name.replace('_', '-')} {value!r} (stored: {getattr(stored, name)!r})"))
        # an option that differs with the regulariser is told as the regulariser's difference: one that
        # chooses it (it cannot differ by itself), or one that only some regularisers read and nobody stated
        told = dict(differences).get("regulariser")
        if told is not None:
            differences = [(setting, told if setting.startswith("algo_options.") and _regulariser_option(
                algo, key := setting[len("algo_options."):], chosen_only=key in stated.get("algo_options", {}))
                else text) for setting, text in differences]
        # a task's definition can change without a setting changing (a built-in task of another
        # version); a run written before config.json recorded them ran the paper's tasks
        if theirs_defined is not None:
            mine = as_json(given.task_definitions())
            for name in sorted(set(mine) | set(theirs_defined)):
                if name not in theirs_defined or name not in mine:
                    where = "this schedule's, not the stored one's" if name in mine else \
                        "the stored schedule's, not this one's"
                    differences.append((f"task.{name}", f"task {name}: {where}"))
                    continue
                ours, kept = mine[name], theirs_defined[name]
                differences += [(f"task.{name}", f"task {name}: {key} {ours.get(key)!r} (stored: {kept.get(key)!r})")
                                for key in sorted(set(ours) | set(kept)) if ours.get(key) != kept.get(key)]
        return differences

    def first_task_differences(self, stated: dict[str, Any]) -> list[str]:
        """``setting_differences`` that would make a run of ``stated`` differ from this one before
        the first task's end: all but those that act only after it (``RunConfig.after_first_task``).
        None: the two share their first task (``--start-from``)."""
        after = self.read_config().after_first_task()
        return list(dict.fromkeys(text for setting, text in self._differences(stated) if setting not in after))

    def continuation(self, stated: dict[str, Any]) -> RunConfig:
        """The configuration to continue this run with: the one it was created with, and the
        settings ``stated`` gives that change no number of it (``RunConfig.free_settings``: the
        output settings, and under the portable arithmetic the speed settings but the device). Any
        other setting ``stated`` gives must be the stored one (``setting_differences``), else
        ResumeError naming each difference with both values."""
        differences = self.setting_differences(stated)
        if differences:
            raise ResumeError(f"{self.path} was run with other settings than these: {'; '.join(differences)}: "
                              "continue it with its stored settings (drop those flags or give the stored "
                              "values), or start a new run (another --name, or --overwrite to replace it)")
        stored = self.read_config()
        free = {name: stated[name] for name in RunConfig.free_settings(stored.to_dict()) if name in stated}
        return RunConfig.from_dict({**self.with_recorded_defaults(stored.to_dict()), **free}).validate(machine=False)

    def with_recorded_defaults(self, settings: dict[str, Any]) -> dict[str, Any]:
        """A configuration's settings (``RunConfig.to_dict()``: this run's, or a checkpoint's) with the
        options this run resolved to another value than today's default laid under its ``env`` and
        ``algo_options`` (``_recorded_defaults``): what the run computes with wherever it goes on."""
        recorded = self._recorded_defaults(self.read_config(), read_json(self.config))
        return {**settings, **{table: {**recorded.get(table, {}), **(settings.get(table) or {})}
                               for table in ("env", "algo_options") if recorded.get(table)}}

    @staticmethod
    def _recorded_defaults(stored: RunConfig, written: dict[str, Any]) -> dict[str, dict[str, Any]]:
        """By table (``env``, ``algo_options``): each option that config.json records the run
        resolved to another value than its given table resolves to today, the default having
        changed since the run was written, at its recorded value. A run goes on with these, not
        with today's defaults, so its numbers stay what it was made with; an option added since
        (one config.json does not record) is at its default, which keeps them too."""
        today = {"env": stored.env_config().to_dict()}
        if stored.algo in REGISTRY:  # an optimiser this process does not know has no defaults here
            today["algo_options"] = stored.algo_options_resolved()
        return {given: {key: value for key, value in (written.get(resolved) or {}).items()
                        if key in today[given] and key not in getattr(stored, given)
                        and as_json(value) != as_json(today[given][key])
                        and (given == "env" or _reads(stored, key))}
                for given, resolved in RESOLVED if given in today}

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
        elif Path(which).name == which and which not in (".", ".."):
            candidates = [folder / f"{which}.json", folder / f"{which}-top.json"]
        else:  # a name with a folder in it ('../config') would read outside controllers/
            candidates = []
        for candidate in candidates:
            if candidate.is_file():
                return candidate, which
        if not available:
            raise RunDirError(f"{self.path} has no stored controller yet (controllers/ is empty): "
                              "they are written at each task end")
        raise RunDirError(f"no controller {which!r} in {folder}: use final, task<N>, one of {', '.join(available)} "
                          "or the path of a controller .json")

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
        task (``--start-from``): they differ only in settings that act after it (``RunConfig.after_first_task``)."""
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
