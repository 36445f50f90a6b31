"""``python -m lifelong_evo score RUN_OR_FILE... [--episodes M]``: held-out scores for stored controllers.

For each run directory at or under the paths given, every exported controller in controllers/
(``task<i>-<task>-<kind>.json`` and ``initial-<kind>.json``) is played on the held-out episodes of
every task of the run's schedule (``lifelong_evo.held_out``), and summary.json's ``held_out`` block
is written anew (the rest of summary.json is kept as it is). The loop writes the same block at
every task end, so ``score`` brings a run made before held-out scoring existed up to the protocol,
and on a run that has it writes the same bytes (at the run's own ``--held-out-episodes``).
Scoring is deterministic: twice gives the same bytes.

A controller file (``.json``) given by itself is scored on the tasks of ``--schedule`` (built-in
ones, and those a ``--tasks`` file defines) in the arena that schedule and ``--env`` give (a file
in a run's controllers/ folder: that run's), and its scores are printed as JSON; nothing is written.

Every path is checked before anything is scored or written; a run directory is locked while its
summary is rewritten, so a running run is refused.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from algorithms import policy_from_export
from envs import ConfigError, numerics

from ..config import RunConfig, load_tasks, resolve
from ..errors import RunDirError, UserError
from ..held_out import score_controllers
from ..json_files import read_json
from ..metrics import held_out_summary, parse_controller_key
from ..options import parse_value, plain
from ..run_files import check_controller_files
from ..rundir import RunDir
from ..runs import find_run_dirs
from ..schedule import distinct_tasks
from ..summary_json import SummaryLayout
from .flags import parse_assignments

HELD_OUT_EPISODES = RunConfig.held_out_episodes
"""Held-out episodes per task for a controller file scored by itself: the run's default."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.description = plain(__doc__)
    parser.add_argument("paths", nargs="+", metavar="RUN_OR_FILE",
                        help="run directories, folders holding them, or controller .json files")
    parser.add_argument("--episodes", default=None, metavar="M",
                        help="held-out episodes per task (default: each run's --held-out-episodes; 100 for a file)")
    parser.add_argument("--schedule", default=None,
                        help="for a controller file outside a run: the tasks to score on (default: red-green-red)")
    parser.add_argument("--env", action="append", default=[], metavar="KEY=VALUE",
                        help="for a controller file outside a run: an environment option (repeatable)")
    parser.add_argument("--tasks", dest="tasks_file", default=None, metavar="FILE",
                        help="for a controller file outside a run: a TOML file of [tasks.NAME] tables whose names "
                             "--schedule can use (docs/usage.md, Tasks)")


def _episodes(text: str | None) -> int | None:
    if text is None:
        return None
    episodes = parse_value(int, text, "--episodes")
    if episodes < 1:
        raise ConfigError(f"--episodes must be >= 1, got {episodes}")
    return episodes


def _file_config(path: Path, args: argparse.Namespace) -> RunConfig:
    """The configuration a loose controller file is scored in: its run's, else the flags'."""
    run = RunDir(path.parent.parent)
    flags = args.schedule or args.env or args.tasks_file
    if path.parent.name == "controllers" and run.config.is_file() and not flags:
        return run.read_config()
    overrides: dict[str, Any] = {"env": parse_assignments(args.env, "--env")} if args.env else {}
    if args.schedule:
        overrides["schedule"] = args.schedule
    if args.tasks_file:
        overrides["tasks"] = load_tasks(args.tasks_file)
    return resolve("paper", None, overrides, machine=False)


def score_run(run_dir: RunDir, episodes: int | None = None) -> dict[str, Any]:
    """Score ``run_dir``'s exported controllers and rewrite summary.json's held-out block; returns it."""
    config = run_dir.read_config()
    numerics.use(config.numerics)  # the arithmetic the run computed its fitness in
    episodes = episodes or config.held_out_episodes
    controllers = {name: exported for name, exported in run_dir.read_controllers().items()
                   if parse_controller_key(name) is not None}
    if not controllers:
        raise RunDirError(f"{run_dir.path} has no exported controller to score (controllers/ holds none)")
    phases = config.phases()
    scores = score_controllers(controllers, config.env_config(), distinct_tasks(phases), episodes)
    block = held_out_summary([phase.name for phase in phases], scores, episodes, config.archive)
    summary = {key: value for key, value in (run_dir.checked_summary() or {}).items() if key != SummaryLayout.HELD_OUT}
    run_dir.write_summary({**summary, SummaryLayout.HELD_OUT: block})
    return block


def _check_controllers(controllers: dict[Path, Any]) -> None:
    """UserError naming the file of the first of ``controllers`` (by file) that is no exported controller."""
    for path, exported in controllers.items():
        try:
            policy_from_export(exported, "cpu")
        except Exception as error:  # noqa: BLE001 - whatever a damaged file breaks, it is refused by name
            raise UserError(f"{path} is not an exported controller ({type(error).__name__}: {error}): "
                            "give a file that a run wrote to its controllers/ folder") from None


def main(args: argparse.Namespace) -> int:
    episodes = _episodes(args.episodes)
    runs, files = [], []
    for given in map(Path, args.paths):
        if given.suffix == ".json" and given.is_file():
            files.append((given, read_json(given), _file_config(given, args)))
        else:
            runs += [RunDir(path) for path in find_run_dirs([given])]
    for run_dir in runs:  # every run readable before any is scored or rewritten
        summary = run_dir.checked_summary()  # its figures are kept beside the new block: one unreadable is refused
        controllers = run_dir.read_controllers()
        check_controller_files(controllers, summary or {}, run_dir.controllers)  # none of its scores dropped
        _check_controllers({run_dir.controllers / f"{name}.json": exported for name, exported in controllers.items()})
    for path, exported, config in files:
        _check_controllers({path: exported})
        try:
            numerics.use(config.numerics)
            scores = score_controllers({path.stem: exported}, config.env_config(), distinct_tasks(config.phases()),
                                       episodes or HELD_OUT_EPISODES)
        except RuntimeError as error:  # the network's inputs do not match the arena's observations
            raise UserError(f"{path} cannot play in this arena ({str(error).splitlines()[0]}): give the --schedule "
                            "and --env of the run that evolved it") from None
        print(json.dumps({"controller": str(path), "episodes": episodes or HELD_OUT_EPISODES,
                          "scores": scores[path.stem]}))
    for run_dir in runs:  # every run free before any is scored (the lock is taken again for the writing)
        run_dir.check_free(fix="then score it")
    for run_dir in runs:
        with run_dir.lock():
            block = score_run(run_dir, episodes)
        print(f"{run_dir.path}: {len(block['scores'])} controller(s) on {block['episodes']} held-out episodes per "
              f"task; held-out C_top per phase {', '.join(f'{v:.2f}' for v in block.get('current_top', []))}")
    return 0
