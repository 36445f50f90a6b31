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

Running the same command again skips finished trials and resumes unfinished ones from their
checkpoints (``--overwrite`` restarts every trial; like run's, it deletes only a directory that
lifelong-evo wrote). Each trial holds its run directory's lock while it runs (``rundir.RunLock``):
a trial another process is running is refused before anything is written. A failed trial is
recorded and the others go on; Ctrl-C cancels the running trials (their checkpoints are kept)
and exits with 130, SIGTERM likewise with 143. Before anything is written, the trials that would
run at once here must fit in this machine's memory (``lifelong_evo.memory``; on a cluster each
trial checks its node; ``--no-memory-check`` lifts it).

The comparison adds the model-specific lambda ("m.s. reg", ``lifelong_evo.compare``) where the
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

Token authentication (Ray >= 2.52; ``ray start`` turns it on where a token exists): where
RAY_AUTH_MODE is not set and this machine has a token (RAY_AUTH_TOKEN, RAY_AUTH_TOKEN_PATH or
~/.ray/auth_token), the sweep connects with it, as Ray itself does for ``--address auto``. A cluster
that cannot be reached or refuses the token is a one-line error naming the fix, within seconds.

Output: one line per finished trial, and a status line every minute in between. What Ray would
print among them stays in files: its messages to the driver (task retries, a dying node's state
dump) in ``ray.log`` in the sweep directory, its process logs in its session folders
(``/tmp/ray/session_latest/logs`` on each node).
"""
from __future__ import annotations

import argparse
import contextlib
import csv
import io
import json
import logging
import os
import socket
import sys
import time
from pathlib import Path
from typing import Any, Sequence

from . import loop, memory
from .checkpoint import atomic_write_bytes
from .compare import write_comparison
from .config import RunConfig
from .errors import UserError, interrupted_status, terminating_as_interrupt
from .flags import add_run_options, typed
from .grid import Grid, Trial, build_grid, default_sweep_name
from .options import bounded, plain
from .report import duration
from .rerun_recorder import RerunRecorder
from .rundir import RunDir, RunDirError, RunDirInUseError, find_run_dirs, write_json

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
    parser.add_argument("--dry-run", action="store_true", help="list the trials and their state, run nothing")


# ------------------------------------------------------------------------------------------- trials

def _one_line(error: BaseException) -> str:
    lines = [line.strip() for line in str(error).splitlines() if line.strip()]
    return f"{type(error).__name__}: {lines[0] if lines else ''}".rstrip(": ")


def trial_run(config_values: dict[str, Any], path: str, overwrite: bool,
              start_from: RunDir | None = None) -> loop.Lifelong:
    """One trial's loop, as ``python -m lifelong_evo run`` would start it (resuming when ``path``
    holds a run; a new one from ``start_from``'s first task where given)."""
    run_dir = RunDir(path)
    resume = not overwrite and run_dir.config.exists()
    # a resumed trial continues with the settings it was created with, as run --resume does
    # (trial_state found them equal, perhaps with a default stated in one and left out in the other)
    config = run_dir.read_config() if resume else RunConfig.from_dict(config_values)
    recorder = RerunRecorder.for_run(run_dir, config, resume=resume) if config.record else None
    return loop.lifelong(config, run_dir, resume=resume, overwrite=overwrite, recorder=recorder, progress="off",
                         start_from=None if resume else start_from)


def first_task_source(config: RunConfig, candidates: Sequence[str]) -> RunDir | None:
    """The first of the run directories ``candidates`` whose first task a run of ``config`` may
    take over (``run --start-from``): it has reached that task's end and differs only in lambda.
    Looked up when the trial starts, so a source that ended its first task meanwhile counts."""
    for candidate in map(RunDir, candidates):
        if candidate.first_task_end.is_file():
            try:
                if set(candidate.differing_settings(config)) <= {"reg"}:
                    return candidate
            except RunDirError:  # not (yet) a run directory with a readable config.json
                continue
    return None


def first_task_order(trials: list[Trial]) -> list[Trial]:
    """``trials`` with the ones that share a first task together, lambda 0 first, in order of
    first appearance: each regularised trial then runs right after the run it starts from."""
    groups: dict[str, list[Trial]] = {}
    for trial in trials:
        settings = RunConfig.outcome_settings(trial.config.to_dict())
        settings.pop("reg")
        groups.setdefault(json.dumps(settings, sort_keys=True), []).append(trial)
    return [trial for group in groups.values() for trial in sorted(group, key=lambda t: t.config.reg != 0)]


def run_trial(config_values: dict[str, Any], path: str, overwrite: bool, memory_check: bool = True,
              first_task_sources: Sequence[str] = ()) -> dict[str, Any]:
    """One trial alone; never raises: an error comes back as ``{"status": "failed", "error": one line}``.
    ``memory_check``: first check that the trial fits in the memory of the node it runs on;
    ``first_task_sources``: run directories a new trial may take its first task from
    (``first_task_source``); the result names the one it took, if any."""
    started = time.monotonic()
    try:
        if memory_check:
            memory.check([RunConfig.from_dict(config_values)], what=f"trial {Path(path).name}")
        new = overwrite or not RunDir(path).config.exists()
        source = first_task_source(RunConfig.from_dict(config_values),
                                   [s for s in first_task_sources if s != path]) if new else None
        summary = loop.run_alone(trial_run(config_values, path, overwrite, source))
        return {"status": "done", "error": "", "wall_time_s": summary["wall_time_s"],
                "first_task_from": "" if source is None else str(source.path)}
    except Exception as error:  # noqa: BLE001 - the driver records it and goes on
        return {"status": "failed", "error": _one_line(error), "wall_time_s": time.monotonic() - started}


def is_complete(summary: dict[str, Any] | None, config: RunConfig) -> bool:
    """Whether ``summary.json`` covers every phase of the schedule (the run has finished)."""
    return bool(summary) and len(summary.get("current", [])) == len(config.phases()) and "ACC_pop" in summary


def trial_state(path: Path, config: RunConfig) -> tuple[str, str]:
    """``("done", "")``, ``("resume", "")``, ``("new", "")`` or ``("failed", why)`` for a trial directory."""
    run_dir = RunDir(path)
    if not run_dir.config.exists():
        return "new", ""
    try:
        different = run_dir.differing_settings(config)
    except RunDirError as error:
        return "failed", str(error)
    if different:
        return "failed", (f"{path} was run with other settings ({', '.join(different)} differ): "
                          "pass --overwrite to restart it, or use another --name")
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
    write_json(sweep_dir / "sweep.json", {
        "name": grid.name, "preset": grid.preset, "grid": grid.axes, "fixed": grid.fixed,
        "by_algo": {algo: {"grid": a, "fixed": f} for algo, (a, f) in grid.by_algo.items()}, "ray": ray_settings,
        "trials": [{"trial": t.name, "path": t.name, "values": t.values, "config": t.config.to_dict()}
                   for t in grid.trials]})


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


CONNECT_TIMEOUT_S = 5.0
"""How long the sweep waits for a cluster's address to answer before giving up."""
STATUS_EVERY_S = 60.0
"""A status line at least this often while trials run."""


def _start_ray(args: argparse.Namespace, address: str | None):
    """Ray for the trials: the cluster at ``address`` (checked by ``_check_cluster``), else a local one."""
    import ray

    if ray.is_initialized():
        return ray, False
    _quiet_token_notice()
    quiet = {"log_to_driver": False, "logging_level": logging.WARNING}
    if address:
        import algorithms
        import envs

        import lifelong_evo

        modules = [str(Path(m.__file__).parent) for m in (lifelong_evo, algorithms, envs)]
        try:
            ray.init(address=address, runtime_env={"py_modules": modules, "excludes": ["__pycache__"]}, **quiet)
        except (ConnectionError, RuntimeError, ray.exceptions.RayError) as error:
            raise UserError(f"could not join the Ray cluster at {args.address}: {_one_line(error)}") from None
    else:
        cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
        # "local": always a new instance, never a cluster that `ray start` left running on this machine
        ray.init(address="local", num_cpus=cores, include_dashboard=False, **quiet)
    return ray, True


RAY_LOG = "ray.log"
"""In the sweep directory: the messages Ray's driver would print (task retries, dead nodes' state dumps)."""


@contextlib.contextmanager
def _ray_messages_to(path: Path):
    """Ray's driver prints the cluster's error messages to stdout from a thread of its own, a whole
    state dump of every node that dies among them, whatever ``log_to_driver`` says; the sweep
    appends them to ``path`` instead and reports each trial's outcome itself."""
    from ray._private import worker

    original = worker.print_to_stdstream

    def to_file(data: dict[str, Any], ignore_prefix: bool) -> None:
        stamp = time.strftime("%Y-%m-%d %H:%M:%S")
        with open(path, "a") as log:  # opened per message: they are rare, and come from Ray's thread
            log.writelines(f"{stamp} ({data.get('pid', 'ray')}) {line}\n" for line in data.get("lines", []))

    worker.print_to_stdstream = to_file  # looked up by name on every message
    try:
        yield
    finally:
        worker.print_to_stdstream = original


@contextlib.contextmanager
def _native_stderr_silenced():
    """Ray's C++ client logs its retries to file descriptor 2; the sweep reports the outcome itself."""
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(os.devnull, "wb") as sink:
            os.dup2(sink.fileno(), 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def _quiet_token_notice() -> None:
    # Ray's INFO lines and the token notice are for Ray's users; the sweep says what it connected to
    logging.getLogger("ray._private.authentication.authentication_token_setup").setLevel(logging.ERROR)


def _check_cluster(given: str) -> str:
    """The HOST:PORT of the cluster ``--address`` names, once it answers and accepts this
    machine's token; otherwise UserError with the fix, within seconds (Ray itself would retry
    for 20 s and end in a traceback). Turns token authentication on where a token is found."""
    from ray._private.authentication.authentication_token_setup import maybe_enable_token_auth_if_token_available
    from ray._private.services import canonicalize_bootstrap_address
    from ray._raylet import AuthenticationMode, AuthenticationTokenLoader, GcsClient, get_authentication_mode
    from ray.exceptions import AuthenticationError, RpcError

    _quiet_token_notice()
    start_hint = "start it with `ray start --head --port=6379` (docs/usage.md, On a cluster), or fix --address"
    try:
        address = canonicalize_bootstrap_address(given)
    except (ConnectionError, ValueError) as error:
        raise UserError(f"--address {given}: {_one_line(error)}: {start_hint}") from None
    host, _, port = address.rpartition(":")
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=CONNECT_TIMEOUT_S).close()
    except (OSError, ValueError) as error:
        reason = getattr(error, "strerror", None) or str(error) or type(error).__name__
        raise UserError(f"no Ray cluster answers at {given} ({reason}): {start_hint}") from None
    # an explicit address never turns token authentication on in Ray, while `ray start` does
    maybe_enable_token_auth_if_token_available(warn_if_disabled=False)
    copy = ("copy the head node's ~/.ray/auth_token to ~/.ray/auth_token on this machine (or set RAY_AUTH_TOKEN "
            "to its contents)")
    has_token = AuthenticationTokenLoader.instance().has_token(ignore_auth_mode=True)
    token_mode = get_authentication_mode() == AuthenticationMode.TOKEN
    if token_mode and not has_token:  # Ray's client would exit the process on its first request
        raise UserError(f"RAY_AUTH_MODE is token and this machine has no Ray token: {copy}")
    try:
        with _native_stderr_silenced():
            GcsClient(address=address)
    except AuthenticationError:
        if not has_token:
            raise UserError(f"the Ray cluster at {given} requires its token and this machine has none: {copy}") from None
        if not token_mode:
            raise UserError(f"the Ray cluster at {given} requires its token and RAY_AUTH_MODE is "
                           f"{os.environ.get('RAY_AUTH_MODE')!r} here: unset RAY_AUTH_MODE or set it to token") from None
        raise UserError(f"the Ray cluster at {given} rejected this machine's token: {copy}") from None
    except RpcError as error:
        raise UserError(f"{given} does not answer as a Ray cluster ({_one_line(error)}): {start_hint}") from None
    return address


def _print(text: str) -> None:
    print(text, flush=True)


def main(args: argparse.Namespace) -> int:
    grid = build_grid(args)
    grid.name = default_sweep_name(grid) if grid.name is None else grid.name
    sweep_dir = (Path(args.out) / grid.name).resolve()
    to_run: list[Trial] = []
    resuming: set[str] = set()
    for trial in grid.trials:
        state, why = ("new", "") if args.overwrite else trial_state(sweep_dir / trial.name, trial.config)
        if state == "done":
            summary = RunDir(sweep_dir / trial.name).read_summary()
            trial.status, trial.wall_time_s = "done", summary["wall_time_s"]
            trial.first_task_from = summary.get("first_task_from", "")
        elif state == "failed":
            trial.status, trial.error = "failed", why
        else:
            to_run.append(trial)
            if state == "resume":
                resuming.add(trial.name)
    if args.overwrite:  # as run's, it deletes only run directories lifelong-evo wrote: each checked up front
        for trial in to_run:
            RunDir(sweep_dir / trial.name).check_create(overwrite=True)
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
    if args.together:
        _check_together(args, to_run, sweep_dir)
    if args.first_task_from and not args.share_first_task:
        raise UserError("--first-task-from names runs to share first tasks with: add --share-first-task")
    sources: list[str] = []
    if args.share_first_task:
        if args.together:
            raise UserError("--share-first-task starts a trial from a run that has ended its first task, but "
                            "--together plays every trial at once: drop one of them")
        to_run = first_task_order(to_run)
        sources = [str(sweep_dir / t.name) for t in first_task_order(grid.trials)]
        for folder in args.first_task_from:
            sources += [str(path.resolve()) for path in find_run_dirs([folder])]
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
        _check_token_file()
    # a cluster that cannot be joined is one error line before anything is written
    address = _check_cluster(args.address) if args.address and to_run else None
    sweep_dir.mkdir(parents=True, exist_ok=True)
    ray_settings = {"address": args.address or "local", "workers": args.workers,
                    "gpus_per_trial": args.gpus_per_trial, "retries": args.retries}
    write_sweep_json(sweep_dir, grid, ray_settings)
    write_trials_csv(sweep_dir, grid)
    interruption = None
    try:
        if to_run and args.together:
            _run_together(grid, to_run, sweep_dir, args.overwrite)
        elif to_run:
            _run_trials(args, grid, to_run, sweep_dir, address, sources)
    except KeyboardInterrupt as stop:  # Ctrl-C or SIGTERM: running trials were cancelled; their checkpoints stay
        interruption = stop
    write_trials_csv(sweep_dir, grid)
    if interruption is not None:
        print(f"\ninterrupted: finished trials and checkpoints are kept in {sweep_dir}; "
              "run the same command again to continue", file=sys.stderr)
        return interrupted_status(interruption)
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
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    at_once = min(len(to_run), args.workers or len(to_run), max(1, cores // min(_cpus(t.config) for t in to_run)))
    largest = sorted(to_run, key=lambda t: memory.estimate(t.config).host(), reverse=True)[:at_once]
    memory.check([t.config for t in largest], what=f"the sweep, with {at_once} trial(s) at once,")


def _check_token_file() -> None:
    """RAY_AUTH_TOKEN_PATH names the file Ray reads its token from, whenever Ray starts or joins a
    cluster: one that is missing or empty is one line here, not Ray's traceback."""
    path = os.environ.get("RAY_AUTH_TOKEN_PATH")
    if not path:
        return
    fix = "copy the cluster's token there (docs/usage.md, On a cluster), or unset RAY_AUTH_TOKEN_PATH"
    try:
        token = Path(path).read_text().strip()
    except (OSError, UnicodeDecodeError) as error:
        raise UserError(f"RAY_AUTH_TOKEN_PATH is {path}, which cannot be read "
                        f"({getattr(error, 'strerror', None) or error}): {fix}") from None
    if not token:
        raise UserError(f"RAY_AUTH_TOKEN_PATH is {path}, which is empty: {fix}")


def _check_together(args: argparse.Namespace, to_run: list[Trial], sweep_dir: Path) -> None:
    """Refuse, before anything is written, what ``--together`` cannot do as asked."""
    if args.address or args.gpus_per_trial or args.workers:
        raise UserError("--together runs every trial in this process, without Ray: drop --address, "
                        "--gpus-per-trial and --workers")
    for trial in to_run:
        run_dir = RunDir(sweep_dir / trial.name)
        config = run_dir.read_config() if not args.overwrite and run_dir.config.exists() else trial.config
        if config.eval_threads != 1:
            # one batch is one thread: another count would change the rounding of the trial's numbers
            raise UserError(f"--together plays each generation in one batch, but trial {trial.name} has "
                            f"--eval-threads {config.eval_threads}: pass --eval-threads 1")


def _run_together(grid: Grid, to_run: list[Trial], sweep_dir: Path, overwrite: bool) -> None:
    """Run ``to_run`` in this process, in step (``loop.run_together``), recording each as it ends."""
    started = time.monotonic()
    finished = len(grid.trials) - len(to_run)

    def record(trial: Trial, result: dict[str, Any] | Exception) -> None:
        nonlocal finished
        if isinstance(result, Exception):
            trial.status, trial.error = "failed", _one_line(result)
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
                address: str | None, first_task_sources: list[str]) -> None:
    """Run ``to_run`` on Ray, in that order, recording each result as it comes; on Ctrl-C, cancel
    the running trials (killing their workers) and raise KeyboardInterrupt."""
    ray, started = _start_ray(args, address)
    in_flight: dict[Any, Trial] = {}
    messages = contextlib.ExitStack()
    try:
        messages.enter_context(_ray_messages_to(sweep_dir / RAY_LOG))
        # ray.init installs a handler of its own that dies on SIGTERM: SIGTERM must take Ctrl-C's way
        messages.enter_context(terminating_as_interrupt())
        resources = ray.cluster_resources()
        if args.gpus_per_trial > resources.get("GPU", 0):
            raise UserError(f"the Ray cluster has {resources.get('GPU', 0):g} GPU(s), a trial asks for "
                           f"{args.gpus_per_trial:g}: drop --gpus-per-trial or add GPU nodes")
        widest = max(_cpus(t.config) for t in to_run)
        if widest > resources.get("CPU", 0):
            raise UserError(f"the Ray cluster has {resources.get('CPU', 0):g} CPUs, a trial asks for {widest} "
                           "(--threads times --eval-threads): lower them")
        where = f"the Ray cluster at {args.address}" if args.address else "a local Ray"
        logs = "/tmp/ray/session_latest/logs" + (" on each node" if args.address else "")
        _print(f"running on {where}: {resources.get('CPU', 0):g} CPUs, {resources.get('GPU', 0):g} GPUs; "
               f"Ray's messages go to {sweep_dir / RAY_LOG}, its logs to {logs}")
        remote = ray.remote(run_trial)
        limit = args.workers or len(to_run)
        queue = list(to_run)
        finished = len(grid.trials) - len(to_run)
        started_at = last_line = time.monotonic()
        try:
            while queue or in_flight:
                while queue and len(in_flight) < limit:
                    trial = queue.pop(0)
                    ref = remote.options(num_cpus=_cpus(trial.config), num_gpus=args.gpus_per_trial,
                                         max_retries=args.retries, name=f"trial:{trial.name}").remote(
                        trial.config.to_dict(), str(sweep_dir / trial.name), args.overwrite, args.memory_check,
                        first_task_sources)
                    in_flight[ref] = trial
                ready, _ = ray.wait(list(in_flight), num_returns=1, timeout=1.0)
                for ref in ready:
                    trial = in_flight.pop(ref)
                    try:
                        result = ray.get(ref)
                    except ray.exceptions.RayError as error:  # worker killed, out of memory, cancelled
                        result = {"status": "failed", "error": _one_line(error), "wall_time_s": None}
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
                    last_line = time.monotonic()
                if in_flight and time.monotonic() - last_line >= STATUS_EVERY_S:
                    _print(f"[{finished}/{len(grid.trials)}] {len(in_flight)} running or waiting for CPUs, "
                           f"{len(queue)} not submitted yet; {duration(time.monotonic() - started_at)} so far")
                    last_line = time.monotonic()
        except KeyboardInterrupt:
            for ref in in_flight:
                ray.cancel(ref, force=True)
            raise
    finally:
        messages.close()
        if started:
            ray.shutdown()
