"""``python -m lifelong_evo sweep``: a grid of lifelong runs (algorithms x lambda x seeds x ...) on Ray.

Any run option takes comma-separated values, and every option given more than one value is an
axis of the grid::

    python -m lifelong_evo sweep --algo neat,cmaes,openai-es --reg 0,5,11 --seed 13,17,24,31,42 --name my-sweep
    python -m lifelong_evo sweep --config examples/sweep.toml          # [grid] table of lists + fixed keys

``--schedule`` values are separated by ``;`` (a custom schedule has commas of its own; named
schedules may also be separated by commas). ``--env KEY=V1,V2`` and ``--option KEY=V1,V2`` make
axes too; write a list-valued option in brackets (``--option hidden=[16,16]``, an axis of lists:
``hidden=[16],[32,32]``).

Each trial is an ordinary run (``lifelong_evo.loop.run``) in ``<out>/<sweep>/<trial>/`` with the
run-directory contract, named from its axes (``neat-reg5-seed13``). The sweep directory also holds
``sweep.json`` (grid and trials), ``trials.csv`` (trial, status done/failed/pending, error, wall
time), ``comparison.md`` and ``.csv`` (``compare``'s tables of the sweep: each configuration with a
regulariser against lambda 0, plus the model-specific lambda rows)
and ``ray.log`` (Ray's messages).

``--only PATTERN`` runs only the trials whose names match one of the shell patterns (the part of a
grid meant for this machine) and leaves the others as they are. Running the same command again
skips finished trials and resumes unfinished ones from their checkpoints (``--overwrite``
restarts every trial picked; like run's, it deletes only a directory that lifelong-evo wrote). Each trial holds its run directory's lock while it runs (``run_lock.RunLock``):
a trial another process is running is refused before anything is written. A failed trial is
recorded and the others go on; Ctrl-C cancels the running trials (their checkpoints are kept)
and exits with 130, SIGTERM likewise with 143. Before anything is written, the trials that would
run at once here must fit in this machine's memory (``lifelong_evo.memory``; on a cluster each
trial checks its node; ``--no-memory-check`` lifts it).

The comparison adds the model-specific lambda ("m.s. reg", ``lifelong_evo.analysis.comparison``) where the
grid varies lambda: per configuration without lambda and seed, the lambda whose top individual is
best at the second task and keeps the first (``model_specific_lambda.md``/``.json``).

``--together`` runs every trial in this process instead, without Ray: each generation, the
trials' evaluations are played in one environment batch (``loop.run_together``), each trial with
its own optimiser, random streams, run directory and checkpoints and the numbers it gets alone.
One batch fills a GPU better than many small ones; its trials need ``--eval-threads 1``.

Ray: by default a local Ray with one CPU per core; each trial reserves ``--threads`` times ``--eval-threads``
CPUs (1 unless told otherwise) and ``--gpus-per-trial`` GPUs (runs then use ``--device cuda``). ``--address
HOST:PORT`` (or ``auto``) runs on an existing cluster (``ray start --head`` on one machine,
``ray start --address=HOST:6379`` on the others); the lifelong_evo, algorithms and envs packages
are shipped to the workers, the output folder must be on storage every node sees.

Everything that touches Ray (starting or joining it, token authentication, running the trials,
Ray's messages) is ``commands/ray_cluster.py``.

Output: one line per finished trial, and a status line every minute in between. What Ray would
print among them stays in files: its messages to the driver (task retries, a dying node's state
dump) in ``ray.log`` in the sweep directory, its process logs in its session folders
(``/tmp/ray/session_latest/logs`` on each node).
"""
from __future__ import annotations

import argparse
import csv
import fnmatch
import io
import json
import shutil
import sys
import time
from pathlib import Path
from typing import Any, Sequence

from envs import ConfigError

from .. import loop, memory
from ..analysis.comparison import write_comparison
from ..analysis.report import duration
from ..checkpoint import atomic_write_bytes
from ..config import RunConfig
from ..errors import RunDirError, UserError, interrupted_status, one_line
from ..json_files import read_json, write_json
from ..options import bounded, plain
from ..provenance import usable_cpus
from ..run_lock import RunDirInUseError
from ..run_names import check_out_folder
from ..rundir import SWEEP_FILE, RunDir, run_directory_around
from ..runs import find_run_dirs
from ..summary_json import SummaryLayout
from . import ray_cluster
from .flags import add_run_options, typed
from .grid import Grid, Trial, build_grid, default_sweep_name
from .rerun_recorder import RerunRecorder

STATUSES = ("done", "failed", "pending")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.description = plain(__doc__)
    add_run_options(parser, axes=True)
    parser.add_argument("--name", default=None,
                        help="sweep directory name under --out (default: the --config file's name, "
                             "else one derived from the grid)")
    parser.add_argument("--out", default="runs", help="parent folder of sweep directories (default: runs)")
    parser.add_argument("--workers", type=typed(bounded(int, {"min": 1, "max": 100_000})), default=None,
                        help="at most this many trials at once, from 1 to 100000 (default: as many as the CPUs allow)")
    parser.add_argument("--gpus-per-trial", type=typed(bounded(float, {"min": 0, "max": 1024})), default=0.0,
                        metavar="G", help="GPUs reserved per trial, e.g. 0.5 (runs use --device cuda; default 0)")
    parser.add_argument("--address", default=None, metavar="HOST:PORT",
                        help="run on an existing Ray cluster (or 'auto'); default: a local Ray for the sweep")
    parser.add_argument("--retries", type=typed(bounded(int, {"min": 0, "max": 100})), default=1,
                        help="re-run a trial whose worker died this many times (0 to 100), from its checkpoint "
                             "(default 1)")
    parser.add_argument("--together", action="store_true",
                        help="run the trials in this process, without Ray, their evaluations in one environment "
                             "batch per generation (for one GPU; needs --eval-threads 1)")
    parser.add_argument("--overwrite", action="store_true",
                        help="restart every trial, finished or not (only directories lifelong-evo wrote)")
    parser.add_argument("--share-first-task", action="store_true",
                        help="a new trial that differs from another run only in --reg starts from that run's first "
                             "task once it has ended (run --start-from: the same numbers, a third of the paper's "
                             "schedule saved); the other runs: this sweep's trials (lambda 0 first) and --first-task-from")
    parser.add_argument("--first-task-from", action="append", default=[], metavar="DIR",
                        help="with --share-first-task: also take first tasks from the runs under this folder (repeatable)")
    parser.add_argument("--only", action="append", default=[], metavar="PATTERN[,PATTERN...]",
                        help="run only the trials whose names match one of these shell patterns, e.g. "
                             "'neat-*-seed17' (repeatable); the others are left as they are, and --overwrite "
                             "restarts only these")
    parser.add_argument("--dry-run", action="store_true", help="list the trials and their state, run nothing")


# ------------------------------------------------------------------------------------------- trials

def trial_run(config_values: dict[str, Any], path: str, overwrite: bool,
              start_from: RunDir | None = None) -> loop.Lifelong:
    """One trial's loop, as ``python -m lifelong_evo run`` would start it (resuming when ``path``
    holds a run; a new one from ``start_from``'s first task where given)."""
    run_dir = RunDir(path)
    resume = not overwrite and run_dir.config.exists()
    # a resumed trial continues with the settings it was created with, as run --resume does
    config = run_dir.continuation(config_values) if resume else RunConfig.from_dict(config_values)
    recorder = RerunRecorder.for_run(run_dir, config, resume=resume) if config.record else None
    return loop.lifelong(config, run_dir, resume=resume, overwrite=overwrite, recorder=recorder, progress="off",
                         start_from=None if resume else start_from)


FileIdentity = tuple[int, int]
"""A file's inode and modification time (ns): ``checkpoint.save`` replaces a file by a new one
(a rename), so a rewritten first-task-end.pt has another identity than the one it replaced."""


def file_identity(path: Path) -> FileIdentity | None:
    """``path``'s ``FileIdentity``, or None where there is no such file."""
    try:
        found = path.stat()
    except OSError:
        return None
    return found.st_ino, found.st_mtime_ns


def first_task_source(config: RunConfig, candidates: Sequence[str],
                      outdated: dict[str, FileIdentity] | None = None) -> RunDir | None:
    """The first of the run directories ``candidates`` whose first task a run of ``config`` may
    take over (``run --start-from``): it has reached that task's end and differs only in settings
    that act after it (``RunDir.first_task_differences``).
    Looked up when the trial starts, so a source that ended its first task meanwhile counts.
    ``outdated``: candidates that this sweep's ``--overwrite`` restarts, with the identity their
    first-task-end.pt had before the sweep: such a candidate counts only once its own trial has
    written that file again (before, its trial may delete it while it is read, and it is what
    the overwrite replaces)."""
    outdated = outdated or {}
    for candidate in map(RunDir, candidates):
        identity = file_identity(candidate.first_task_end)
        if identity is not None and identity != outdated.get(str(candidate.path)):
            try:
                if not candidate.first_task_differences(config.to_dict()):
                    return candidate
            except (RunDirError, ConfigError):  # not (yet) a run directory with a readable config.json
                continue
    return None


def first_task_order(trials: list[Trial]) -> list[Trial]:
    """``trials`` with the ones that share a first task together (``RunConfig.first_task_settings``),
    fine-tuning (lambda 0 and none of the baselines among ``RunConfig.AFTER_FIRST_TASK_SETTINGS``:
    the regulariser is no baseline) first, in order of first appearance: each other trial then runs
    right after the run it starts from."""
    groups: dict[str, list[Trial]] = {}
    for trial in trials:
        settings = RunConfig.first_task_settings(trial.config.to_dict())
        groups.setdefault(json.dumps(settings, sort_keys=True), []).append(trial)
    on = [name for name in RunConfig.AFTER_FIRST_TASK_SETTINGS if name != "regulariser"]
    return [trial for group in groups.values() for trial in sorted(
        group, key=lambda t: any(getattr(t.config, name) for name in on))]


def run_trial(config_values: dict[str, Any], path: str, overwrite: bool, memory_check: bool = True,
              first_task_sources: Sequence[str] = (),
              outdated_sources: dict[str, FileIdentity] | None = None) -> dict[str, Any]:
    """One trial alone; never raises: an error comes back as ``{"status": "failed", "error": one line}``.
    ``memory_check``: first check that the trial fits in the memory of the node it runs on;
    ``first_task_sources``: run directories a new trial may take its first task from
    (``first_task_source``, with ``outdated_sources``); the result names the one it took, if any."""
    started = time.monotonic()
    try:
        if memory_check:
            memory.check([RunConfig.from_dict(config_values)], what=f"trial {Path(path).name}")
        run_dir = RunDir(path)
        new = overwrite or not run_dir.config.exists()
        # never itself, by any path (--first-task-from may reach it through a link): it deletes what it would read
        others = [s for s in first_task_sources if not RunDir(s).is_same_directory(run_dir)]
        source = first_task_source(RunConfig.from_dict(config_values), others, outdated_sources) if new else None
        summary = loop.run_alone(trial_run(config_values, path, overwrite, source))
        # the summary's, which a trial resumed after taking over its first task still names
        return {"status": "done", "error": "", "wall_time_s": summary[SummaryLayout.WALL_TIME],
                "first_task_from": summary.get(SummaryLayout.FIRST_TASK_FROM, "")}
    except Exception as error:  # noqa: BLE001 - the driver records it and goes on
        return {"status": "failed", "error": one_line(error), "wall_time_s": time.monotonic() - started}


def picked_trials(grid: Grid, patterns: Sequence[str]) -> set[str]:
    """The names of the trials ``--only`` picks: every trial without patterns, else those whose
    names match one of the comma-separated shell patterns (``fnmatch``, case-sensitive). A pattern
    that matches no trial is refused: misspelt, it would quietly run nothing it was meant to."""
    names = [trial.name for trial in grid.trials]
    if not patterns:
        return set(names)
    picked: set[str] = set()
    for pattern in (piece.strip() for item in patterns for piece in item.split(",")):
        if not pattern:
            raise UserError("--only has an empty pattern: give trial names or shell patterns such as "
                            "neat-*-seed17, separated by commas")
        matched = [name for name in names if fnmatch.fnmatchcase(name, pattern)]
        if not matched:
            raise UserError(f"--only {pattern!r} matches none of the grid's {len(names)} trials: "
                            "the same command with --dry-run and without --only lists them")
        picked.update(matched)
    return picked


def is_complete(summary: dict[str, Any] | None, config: RunConfig) -> bool:
    """Whether ``summary.json`` covers every phase of the schedule (the run has finished)."""
    return (bool(summary) and len(summary.get(SummaryLayout.CURRENT, [])) == len(config.phases())
            and SummaryLayout.transfer("ACC", "pop") in summary)


def trial_state(path: Path, config: RunConfig) -> tuple[str, str]:
    """``("done", "")``, ``("resume", "")``, ``("new", "")`` or ``("failed", why)`` for a trial directory."""
    run_dir = RunDir(path)
    if not run_dir.config.exists():
        return "new", ""
    try:
        differences = run_dir.setting_differences(config.to_dict())
    except (RunDirError, ConfigError) as error:
        return "failed", str(error)
    if differences:  # the sweep's grid changed, or a default since the trial was made
        return "failed", (f"{path} was made with other settings than the sweep gives this trial: "
                          f"{'; '.join(differences)}: give the stored values in the sweep's settings, or run the "
                          "trial again with --overwrite (and --only naming it)")
    return ("done", "") if is_complete(run_dir.read_summary(), config) else ("resume", "")


def write_trials_csv(sweep_dir: Path, grid: Grid) -> None:
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(["trial", "status", "error", "wall_time_s", "first_task_from", *grid.columns])
    for t in grid.trials:
        wall = "" if t.wall_time_s is None else f"{t.wall_time_s:.1f}"
        writer.writerow([t.name, t.status, t.error, wall, t.first_task_from,
                         *(t.values.get(k, "") for k in grid.columns)])
    atomic_write_bytes(sweep_dir / "trials.csv", buffer.getvalue().encode())


def write_sweep_json(sweep_dir: Path, grid: Grid, ray_settings: dict[str, Any]) -> None:
    write_json(sweep_dir / SWEEP_FILE, {
        "name": grid.name, "preset": grid.preset, "grid": grid.axes, "fixed": grid.fixed,
        "by_algo": {algo: {"grid": a, "fixed": f} for algo, (a, f) in grid.by_algo.items()}, "ray": ray_settings,
        "trials": [{"trial": t.name, "path": t.name, "values": t.values, "config": t.config.to_dict()}
                   for t in grid.trials]})


SWEEP_FILES = (SWEEP_FILE, "trials.csv", "ray.log", "comparison*", "model_specific_lambda*")
"""What a sweep writes into its folder besides its trials' run directories."""


def check_sweep_folder(sweep_dir: Path) -> None:
    """RunDirError where ``sweep_dir`` is a run directory or lies inside one (the run's
    ``--overwrite`` would delete the sweep), or is not a sweep's folder (no sweep.json a sweep
    wrote) yet holds files a sweep would replace: nothing of a folder of someone else's is
    overwritten."""
    if RunDir(sweep_dir).holds_a_run():
        raise RunDirError(f"{sweep_dir} is a run directory, not a sweep's folder: the sweep's files and trials "
                          "would go into the run, and its --overwrite would delete them: choose another --name or "
                          "--out")
    outer = run_directory_around(sweep_dir)
    if outer is not None:
        raise RunDirError(f"--out {sweep_dir.parent} is inside run directory {outer}, whose --overwrite would "
                          "delete the sweep too: choose another --out")
    sweep_file = sweep_dir / SWEEP_FILE
    try:
        if {"name", "grid", "trials"} <= set(read_json(sweep_file)):
            return
    except RunDirError:  # missing, or not JSON at all
        if sweep_file.is_file():
            raise RunDirError(f"{sweep_file} is damaged (not UTF-8 JSON), so this folder cannot be told to be a "
                              "sweep's: restore the file from a copy of the sweep's folder, or choose another --name "
                              "or --out") from None
    except TypeError:  # JSON of another shape
        pass
    try:
        clashing = sorted({p.name for pattern in SWEEP_FILES for p in sweep_dir.glob(pattern)})
    except OSError:  # not a folder that can be read: the sweep's own checks say so
        return
    if clashing:
        raise RunDirError(f"{sweep_dir} is not a sweep's folder (it has no sweep.json a sweep wrote) but holds "
                          f"{', '.join(clashing)}, which a sweep writes: choose another --name or --out")


# ---------------------------------------------------------------------------------------- comparison

def aggregate(sweep_dir: Path, grid: Grid) -> str:
    """``compare``'s tables over the finished trials, the m.s. reg rows included, written into the
    sweep directory (``compare.write_comparison``); returns the markdown."""
    done = [t for t in grid.trials if t.status == "done"]
    if not done:
        return "no finished trial: nothing to compare"
    return write_comparison([sweep_dir / t.name for t in done], sweep_dir)


# --------------------------------------------------------------------------------------------- driver

def _cpus(config: RunConfig) -> int:
    """CPUs a trial keeps busy: its evaluation threads, each with its torch threads."""
    return config.threads * config.eval_threads


STATUS_EVERY_S = 60.0
"""A status line at least this often while trials run."""


def _print(text: str) -> None:
    print(text, flush=True)


def main(args: argparse.Namespace) -> int:
    grid = build_grid(args)
    grid.name = default_sweep_name(grid) if grid.name is None else grid.name
    sweep_dir = (check_out_folder(args.out) / grid.name).resolve()
    check_sweep_folder(sweep_dir)
    picked = picked_trials(grid, args.only)
    to_run, resuming = _plan(grid, sweep_dir, picked, args.overwrite)
    _print_plan(grid, sweep_dir, to_run, picked, resuming)
    if args.together:
        _check_together(args, to_run)
    to_run, sources, outdated = _first_task_sources(args, grid, to_run, sweep_dir)
    if args.dry_run:
        for trial in to_run:
            _print(f"would run {trial.name}")
        return 0
    for trial in to_run:  # each trial takes its run directory's lock; one still held is in use by another sweep
        holder = RunDir(sweep_dir / trial.name).in_use_by()
        if holder is not None:
            raise RunDirInUseError(sweep_dir / trial.name, holder)
    if args.memory_check:
        _check_memory(args, to_run)
    if to_run and not args.together:
        ray_cluster.check_token_file()
    # a cluster that cannot be joined is one error line before anything is written
    address = ray_cluster.check_cluster(args.address) if args.address and to_run else None
    _write_sweep_folder(sweep_dir, grid, {"address": args.address or "local", "workers": args.workers,
                                          "gpus_per_trial": args.gpus_per_trial, "retries": args.retries})
    interruption = None
    try:
        if to_run and args.together:
            _run_together(grid, to_run, sweep_dir, args.overwrite)
        elif to_run:
            _run_trials(args, grid, to_run, sweep_dir, address, sources, outdated)
    except KeyboardInterrupt as stop:  # Ctrl-C or SIGTERM: running trials were cancelled; their checkpoints stay
        interruption = stop
    write_trials_csv(sweep_dir, grid)
    if interruption is not None:
        print(f"\ninterrupted: finished trials and checkpoints are kept in {sweep_dir}; "
              "run the same command again to continue", file=sys.stderr)
        return interrupted_status(interruption)
    return _report(sweep_dir, grid)


def _plan(grid: Grid, sweep_dir: Path, picked: set[str], overwrite: bool) -> tuple[list[Trial], set[str]]:
    """The trials to run (those picked that are neither done nor failed; with ``overwrite`` every
    one picked) and the names of those among them that resume; the others' states recorded on the
    trials. With ``overwrite``, RunDirError before anything is written where a trial's directory
    is one that ``--overwrite`` may not delete (as ``run``'s, only one lifelong-evo wrote)."""
    to_run: list[Trial] = []
    resuming: set[str] = set()
    for trial in grid.trials:
        restart = overwrite and trial.name in picked
        state, why = ("new", "") if restart else trial_state(sweep_dir / trial.name, trial.config)
        if state == "done":
            summary = RunDir(sweep_dir / trial.name).read_summary()
            trial.status, trial.wall_time_s = "done", summary[SummaryLayout.WALL_TIME]
            trial.first_task_from = summary.get(SummaryLayout.FIRST_TASK_FROM, "")
        elif state == "failed":
            trial.status, trial.error = "failed", why
        elif trial.name in picked:
            to_run.append(trial)
            if state == "resume":
                resuming.add(trial.name)
    if overwrite:
        for trial in to_run:
            RunDir(sweep_dir / trial.name).check_create(overwrite=True)
    return to_run, resuming


def _print_plan(grid: Grid, sweep_dir: Path, to_run: list[Trial], picked: set[str], resuming: set[str]) -> None:
    """The sweep's axes and what becomes of each trial: skipped, failed, resumed or left out."""
    axes = ", ".join([*(f"{k} ({len(v)})" for k, v in grid.axes.items()),
                      *(f"{algo}: {k} ({len(v)})" for algo, (a, _) in grid.by_algo.items() for k, v in a.items())]) \
        or "no axes"
    _print(f"sweep {grid.name}: {len(grid.trials)} trial(s) over {axes}, preset {grid.preset}; "
           f"{len(to_run)} to run -> {sweep_dir}")
    for trial in grid.trials:
        if trial.status == "done":
            _print(f"skipped {trial.name} (done)")
        elif trial.status == "failed":
            _print(f"failed  {trial.name}: {trial.error}")
        elif trial.name in resuming:
            _print(f"resume  {trial.name} (from its last checkpoint)")
        elif trial.name not in picked:
            _print(f"left    {trial.name} (not picked by --only)")


def _first_task_sources(args: argparse.Namespace, grid: Grid, to_run: list[Trial], sweep_dir: Path
                        ) -> tuple[list[Trial], list[str], dict[str, FileIdentity]]:
    """With ``--share-first-task``: the trials to run in first-task order, the runs a trial may take
    its first task from (the sweep's trials, and the runs under ``--first-task-from``), and, with
    ``--overwrite``, the sources whose first task is about to be replaced (no source then);
    without it, ``to_run`` as it is and none. UserError for what cannot be shared."""
    if args.first_task_from and not args.share_first_task:
        raise UserError("--first-task-from names runs to share first tasks with: add --share-first-task")
    if not args.share_first_task:
        return to_run, [], {}
    if args.together:
        raise UserError("--share-first-task starts a trial from a run that has ended its first task, but "
                        "--together plays every trial at once: drop one of them")
    to_run = first_task_order(to_run)
    sources = [str(sweep_dir / t.name) for t in first_task_order(grid.trials)]
    for folder in args.first_task_from:
        sources += [str(path.resolve()) for path in find_run_dirs([folder])]
    outdated: dict[str, FileIdentity] = {}
    if args.overwrite:  # a restarted trial's first task, as it was before this sweep, is no source
        restarted = {str(sweep_dir / t.name) for t in to_run}
        outdated = {source: identity for source in sources if source in restarted
                    and (identity := file_identity(RunDir(source).first_task_end)) is not None}
    return to_run, sources, outdated


def _write_sweep_folder(sweep_dir: Path, grid: Grid, ray_settings: dict[str, Any]) -> None:
    """The sweep's folder with sweep.json and trials.csv; UserError where it cannot be written (a
    folder made just now is removed again: nothing of it is left half-made)."""
    new_folder = not sweep_dir.exists()
    try:
        sweep_dir.mkdir(parents=True, exist_ok=True)
        write_sweep_json(sweep_dir, grid, ray_settings)
        write_trials_csv(sweep_dir, grid)
    except OSError as error:  # a read-only --out, or one on a file system that refuses the names
        if new_folder:
            shutil.rmtree(sweep_dir, ignore_errors=True)
        raise UserError(f"cannot write the sweep's folder {sweep_dir}: {error.strerror or error}: choose another "
                        "--out") from None


def _report(sweep_dir: Path, grid: Grid) -> int:
    """The comparison of the finished trials (``aggregate``) printed with the counts; the exit
    status: 1 where a trial failed."""
    table = aggregate(sweep_dir, grid)
    counts = {s: sum(t.status == s for t in grid.trials) for s in STATUSES}
    _print("")
    _print(table)
    _print(f"\n{counts['done']} done, {counts['failed']} failed; results in {sweep_dir} (trials.csv, sweep.json"
           + (", comparison.md/.csv)" if counts["done"] else ")"))
    return 1 if counts["failed"] else 0


def _check_memory(args: argparse.Namespace, to_run: list[Trial]) -> None:
    """Refuse, before anything is written, trials that cannot fit in this machine's memory as they
    would run here: all of them in this process (``--together``), else as many at once as the
    CPUs and ``--workers`` allow, the largest first. On a cluster (``--address``) each trial
    checks the node it lands on (``run_trial``)."""
    if not to_run or args.address:
        return
    if args.together:
        memory.check([t.config for t in to_run], together=True, what=f"--together with {len(to_run)} trial(s)")
        return
    cores = usable_cpus()
    at_once = min(len(to_run), args.workers or len(to_run), max(1, cores // min(_cpus(t.config) for t in to_run)))
    largest = sorted(to_run, key=lambda t: memory.estimate(t.config).host(), reverse=True)[:at_once]
    memory.check([t.config for t in largest], what=f"the sweep, with {at_once} trial(s) at once,")


def _check_together(args: argparse.Namespace, to_run: list[Trial]) -> None:
    """Refuse, before anything is written, what ``--together`` cannot do as asked."""
    if args.address or args.gpus_per_trial or args.workers:
        raise UserError("--together runs every trial in this process, without Ray: drop --address, "
                        "--gpus-per-trial and --workers")
    for trial in to_run:  # a trial to resume has its stored settings (trial_state), eval_threads included
        if trial.config.eval_threads != 1:
            # one batch is one thread: another count would change the rounding of the trial's numbers
            raise UserError(f"--together plays each generation in one batch, but trial {trial.name} has "
                            f"--eval-threads {trial.config.eval_threads}: pass --eval-threads 1")


def _run_together(grid: Grid, to_run: list[Trial], sweep_dir: Path, overwrite: bool) -> None:
    """Run ``to_run`` in this process, in step (``loop.run_together``), recording each as it ends."""
    started = time.monotonic()
    finished = len(grid.trials) - len(to_run)

    def record(trial: Trial, result: dict[str, Any] | Exception) -> None:
        nonlocal finished
        if isinstance(result, Exception):
            trial.status, trial.error = "failed", one_line(result)
            trial.wall_time_s = time.monotonic() - started
        else:
            trial.status, trial.error, trial.wall_time_s = "done", "", result["wall_time_s"]
        finished += 1
        line = f"[{finished}/{len(grid.trials)}] {trial.status:<6} {trial.name} ({duration(trial.wall_time_s)})"
        _print(line + (f": {trial.error}" if trial.error else ""))
        write_trials_csv(sweep_dir, grid)

    runs, trials = [], []
    for trial in to_run:
        try:
            runs.append(trial_run(trial.config.to_dict(), str(sweep_dir / trial.name), overwrite))
            trials.append(trial)
        except Exception as error:  # noqa: BLE001 - recorded; the others go on
            record(trial, error)
    last_line = time.monotonic()

    def status(going: int) -> None:
        nonlocal last_line
        if going and time.monotonic() - last_line >= STATUS_EVERY_S:
            _print(f"[{finished}/{len(grid.trials)}] {going} running together; "
                   f"{duration(time.monotonic() - started)} so far")
            last_line = time.monotonic()

    _print(f"running {len(runs)} trial(s) together in this process")
    for index, result in loop.run_together(runs, after_generation=status):
        record(trials[index], result)
        last_line = time.monotonic()


def _run_trials(args: argparse.Namespace, grid: Grid, to_run: list[Trial], sweep_dir: Path,
                address: str | None, first_task_sources: list[str],
                outdated_sources: dict[str, FileIdentity]) -> None:
    """Run ``to_run`` on Ray (``ray_cluster.run_jobs``), in that order, recording each result as it
    comes; on Ctrl-C or SIGTERM the running trials are cancelled and KeyboardInterrupt raised."""
    finished = len(grid.trials) - len(to_run)
    started = time.monotonic()

    def record(index: int, result: dict[str, Any] | None, error: str) -> None:
        nonlocal finished
        trial = to_run[index]
        result = result or {"status": "failed", "error": error, "wall_time_s": None}
        trial.status, trial.error = result["status"], result["error"]
        trial.wall_time_s = result["wall_time_s"]
        trial.first_task_from = result.get("first_task_from", "")
        finished += 1
        wall = "" if trial.wall_time_s is None else f" ({duration(trial.wall_time_s)})"
        if trial.first_task_from:
            wall += f" (first task from {Path(trial.first_task_from).name})"
        line = f"[{finished}/{len(grid.trials)}] {trial.status:<6} {trial.name}{wall}"
        _print(line + (f": {trial.error}" if trial.error else ""))
        write_trials_csv(sweep_dir, grid)

    def waiting(in_flight: int, queued: int) -> None:
        _print(f"[{finished}/{len(grid.trials)}] {in_flight} running or waiting for CPUs, {queued} not submitted "
               f"yet; {duration(time.monotonic() - started)} so far")

    jobs = [ray_cluster.Job(trial.name, _cpus(trial.config),
                            (trial.config.to_dict(), str(sweep_dir / trial.name), args.overwrite, args.memory_check,
                             first_task_sources, outdated_sources)) for trial in to_run]
    ray_cluster.run_jobs(jobs, run_trial, address=address, given_address=args.address, workers=args.workers,
                         gpus_per_job=args.gpus_per_trial, retries=args.retries, log=sweep_dir / ray_cluster.RAY_LOG,
                         on_result=record, on_wait=waiting, wait_every_s=STATUS_EVERY_S)
