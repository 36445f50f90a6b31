"""``python -m lifelong_evo replay RUN [--task red] [--episodes 5] [--controller final] [--seed S]``

Plays a stored controller of a run (``RUN/controllers/``: ``final`` = final-top.json, ``task0`` =
the top individual at the end of phase 0, ``task0-red-top``, or a path to a controller .json) on
fresh episodes of a task (default: the run's last task; any built-in task or one the run defines)
in the run's arena, prints each episode's
reward and the mean, and records the episodes to ``RUN/replay-<task>.rrd`` (``replay-<controller>-
<task>.rrd`` for another controller than ``final``; ``--no-record``: none). Episode i uses the
environment seed S + i (default S = 1000000, away from the seeds of the run's own recordings).
"""
from __future__ import annotations

import argparse
from pathlib import Path

from algorithms import policy_from_export
from envs import numerics

from ..config import check_device
from ..episodes import play_episodes
from ..errors import UserError
from ..options import bounded
from ..rundir import RunDir
from ..tasks import task_catalogue
from .flags import typed
from .rerun_recorder import APPLICATION_ID, RerunRecorder, make_blueprint

DEFAULT_SEED = 1_000_000


def replay(run: str | Path, task_name: str | None = None, episodes: int = 5, controller: str = "final",
           seed: int = DEFAULT_SEED, record: bool = True, device: str = "cpu", quiet: bool = False):
    """Play and (optionally) record; returns (episodes, recording path or None)."""
    run_dir = RunDir(run)
    if not run_dir.path.is_dir():
        raise UserError(f"{run_dir.path} does not exist: give a run directory (runs/<name>)")
    if episodes < 1:
        raise UserError(f"--episodes must be >= 1, got {episodes}")
    check_device(device)
    config = run_dir.read_config()
    numerics.use(config.numerics)  # the arithmetic the run computed its fitness in
    phases = config.phases()
    task_name = task_name or phases[-1].name
    tasks = task_catalogue(config.tasks)
    if task_name not in tasks:
        raise UserError(f"unknown task {task_name!r}: choose one of {', '.join(tasks)}")
    task = tasks[task_name]
    env_config = config.env_config()
    env_config.check_task(task)  # ConfigError (one line) if the run's arena lacks its colours
    path, label = run_dir.find_controller(controller)
    exported = run_dir.read_controller(path)  # one that plays in this arena, or a line naming what is wrong
    try:
        policy = policy_from_export(exported, device)
    except (ValueError, KeyError) as error:
        raise UserError(f"{path} is not a usable controller ({error}): pick another with --controller") from None
    seeds = [seed + i for i in range(episodes)]
    played = play_episodes(policy, env_config, task, seeds, device)
    recording = None
    if record:
        recording = _record(run_dir, config, label, task_name, played, seeds, path)
    if not quiet:
        for i, (s, episode) in enumerate(zip(seeds, played)):
            print(f"episode {i} (seed {s}): reward {episode.total_reward:g} in {len(episode.rewards)} steps")
        mean = sum(e.total_reward for e in played) / len(played)
        print(f"mean reward of {path.name} on {task_name} over {len(played)} episodes: {mean:g}")
        if recording is not None:
            print(f"recorded: {recording}  (python -m lifelong_evo view {recording})")
    return played, recording


def _record(run_dir, config, label: str, task_name: str, played, seeds, controller_path: Path) -> Path:
    path = run_dir.replay_recording(label, task_name)
    name = path.stem
    entities = [(f"replay/{label}/on_{task_name}/episode{i}", f"{label} on {task_name}, seed {s}")
                for i, s in enumerate(seeds)]
    recorder = RerunRecorder(path, recording_id=f"{APPLICATION_ID}/{run_dir.path.resolve().name}/{name}",
                             recording_name=f"{run_dir.path.name} {name}", arena_size=config.env_config().size,
                             blueprint=make_blueprint(entities, curves=False), mode="file")
    try:
        for (entity, _), s, episode in zip(entities, seeds, played):
            recorder.log_episode_at(entity, episode)
            recorder.text(0, f"{controller_path.name} on {task_name}, seed {s}: reward {episode.total_reward:g} "
                                f"({entity})", timeline="step")
    finally:
        recorder.close()
    return path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", metavar="RUN", help="run directory")
    parser.add_argument("--task", default=None, help="task to play, a built-in one or one the run defines "
                                                     "(default: the run's last task)")
    parser.add_argument("--episodes", type=typed(bounded(int, {"min": 1, "max": 10_000})), default=5,
                        help="episodes to play, from 1 to 10000 (default: 5)")
    parser.add_argument("--controller", default="final",
                        help="final (default), task<N> (top at the end of phase N), a file stem in "
                             "RUN/controllers/, or a controller .json path")
    # episode i uses seed + i: below 2**63, where the held-out episodes' seeds begin
    parser.add_argument("--seed", type=typed(bounded(int, {"min": 0, "max": 2**62})), default=DEFAULT_SEED,
                        help=f"environment seed of the first episode, from 0 to 2**62 (default: {DEFAULT_SEED})")
    parser.add_argument("--device", default="cpu", help="torch device (default: cpu)")
    parser.add_argument("--no-record", dest="record", action="store_false", help="do not write an .rrd")


def main(args: argparse.Namespace) -> int:
    replay(args.run, args.task, args.episodes, args.controller, args.seed, args.record, args.device)
    return 0

