"""Reading runs back: what ``plot``, ``compare``, ``sweep`` and ``score`` see of run directories.

``find_run_dirs`` finds every run directory (config.json + summary.json) at or under some paths,
``load_run``/``load_runs`` read each as a ``Run`` (its files checked by ``run_files``), and
``group_runs`` gathers the repetitions of one configuration (``configuration_of``: the settings of
``RunConfig.configuration_settings``, as resolved; the regulariser's options dropped at lambda 0).
``describe_config`` labels a configuration by what sets it apart from the others. Nothing here
writes.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from algorithms import REGISTRY

from .config import RunConfig, default_regulariser
from .errors import RunDirError, UserError
from .json_files import read_json
from .metrics_csv import METRICS_FILE, SPECIES_COLUMNS, SPECIES_FILE, read_metrics
from .run_files import check_config, check_controller_files, check_metrics, check_species, check_summary
from .rundir import RESOLVED, RESOLVED_KEYS, RunDir
from .schedule import schedule_of
from .summary_json import SUMMARY_FILE, SummaryLayout


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
        return len(self.summary.get(SummaryLayout.PHASES, [])) == len(schedule)

    def metrics_rows(self) -> list[dict[str, str]]:
        """metrics.csv's rows (none where the run has no metrics.csv), checked by ``read_metrics``
        and against config.json's schedule and summary.json's ended phases (``run_files.check_metrics``)."""
        path = self.path / METRICS_FILE
        if not path.exists():
            return []
        return check_metrics(read_metrics(path), path, *self._logged_against())

    def _logged_against(self) -> tuple[RunConfig, int]:
        """What a log of the run is checked against: config.json's settings, and how many phases
        summary.json records as ended."""
        settings = check_config(self.config, self.path / "config.json", RESOLVED_KEYS)
        return settings, len(self.summary.get(SummaryLayout.PHASES, []))

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
        path = self.path / SPECIES_FILE
        if not path.exists():
            return None
        # checked as metrics.csv is: a broken line is an error naming it, a half-written last one dropped
        rows = check_species(read_metrics(path, required=SPECIES_COLUMNS), path, *self._logged_against())
        return [(int(row["generation"]), int(row["species_id"]), int(row["size"])) for row in rows]


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
        # no regulariser: the choice of one is no setting (at lambda 0 the functional one does not
        # even play, so its runs write what the default's do: loop._FunctionalReference)
        values.pop("regulariser")
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
    and environment setting by itself (``genetics=2.0``, ``env.see_other_agents=True``). The
    regulariser (``regulariser=wp``, in place of the options that choose it, such as
    ``importance``) wherever it is one (``reg > 0``) other than its family's default, so that
    NEAT's and sep-CMA-ES's ``functional`` rows both say so, and where another run of the same
    algorithm has another; a regulariser's option only against runs that have one (not those at
    ``reg == 0``), and only where the row's regulariser reads it (``Optimizer.options_used_by``: a
    ``functional`` row names no ``lambda_2``). A baseline setting (``RunConfig.BASELINE_SETTINGS``)
    only where it is on: fine-tuning is the plain label, a baseline ``rehearsal=0.3`` or
    ``joint=True``."""
    mine = configuration_of(config)
    theirs = [configuration_of(o) for o in others]
    same_algo = [t for t, o in zip(theirs, others) if o.get("algo") == config.get("algo")]
    algo = REGISTRY.get(str(config.get("algo")))
    regularizer_only = set(algo.regularizer_options) if algo is not None else set()
    # the options that choose a regulariser (an ES's importance): its label is regulariser=NAME
    choosing = algo.choosing_options() if algo is not None else frozenset()
    # and those only other regularisers read (all of them at lambda 0, where none plays)
    unread = {name for name, users in getattr(algo, "options_used_by", {}).items() if mine.get("regulariser") not in users}

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
                            if not (is_option and (name in choosing or name in unread))
                            and any(differs(t.get(key, {}), name, value[name], is_option) for t in compared)]
        elif key in RunConfig.BASELINE_SETTINGS and value == BASELINES_OFF[key]:
            continue
        elif (key == "regulariser" and value != default_regulariser(config.get("algo"))) or any(
                t.get(key) != value for t in compared if key in t or key != "regulariser"):  # runs with one
            differences.append(f"{key}={value}")
    return differences


def describe_config(config: dict[str, Any], others: list[dict[str, Any]] | None = None) -> str:
    """A short label: algorithm, lambda, schedule, and what else sets the configuration apart
    from ``others`` (``config_differences``)."""
    label = f"{config.get('algo')} reg={config.get('reg', 0):g} {config.get('schedule')}"
    return " ".join([label, *config_differences(config, others or [])])


def is_run_dir(path: Path) -> bool:
    return (path / "config.json").is_file() and (path / SUMMARY_FILE).is_file()


def find_run_dirs(paths) -> list[Path]:
    """Every run directory (config.json + summary.json) at or under ``paths``, sorted."""
    found: dict[Path, Path] = {}  # by the folder it is, however it was named
    for given in paths:
        path = Path(given)
        if not path.exists():
            raise RunDirError(f"{path} does not exist: give run directories or folders that hold them")
        runs = [path] if is_run_dir(path) else [c.parent for c in path.rglob("config.json") if is_run_dir(c.parent)]
        for run in runs:
            found.setdefault(run.resolve(), run)
    if not found:
        raise RunDirError(f"no run directory (config.json + summary.json) under {', '.join(map(str, paths))}: "
                          "run `python -m lifelong_evo run` first or check the path")
    return sorted(found.values())


def load_run(path: Path, with_metrics: bool = True) -> Run:
    """The run in ``path``, its files checked (``run_files``): config.json, summary.json against it,
    the controllers it names present and, ``with_metrics``, metrics.csv against both. ``Run.config``
    is config.json as written, its settings as their fields type them."""
    written = read_json(path / "config.json")
    settings = check_config(written, path / "config.json", RESOLVED_KEYS)
    config = {**written, **{key: getattr(settings, key) for key in written if key not in RESOLVED_KEYS}}
    summary = check_summary(read_json(path / SUMMARY_FILE), path / SUMMARY_FILE, settings)
    controllers = RunDir(path).controllers
    check_controller_files((file.stem for file in controllers.glob("*.json")), summary, controllers)
    run = Run(path=path, config=config, summary=summary)
    if with_metrics:
        run.metrics = run.metrics_rows()
    return run


def load_runs(paths, with_metrics: bool = True) -> list[Run]:
    """Every run at or under ``paths`` (``find_run_dirs``)."""
    return [load_run(path, with_metrics) for path in find_run_dirs(paths)]


def group_runs(runs: list[Run]) -> list[list[Run]]:
    """Runs grouped by configuration (in order of first appearance), each group sorted by seed.
    Two runs of one seed are two repetitions (under native arithmetic on two kinds of CPU, two
    trajectories), but UserError where they are one run twice (a copy, or the run again under
    other speed settings: the same figures), which would count it twice in every mean."""
    groups: dict[str, list[Run]] = {}
    for run in runs:
        group = groups.setdefault(run.key, [])
        twin = next((other for other in group if other.seed == run.seed and _figures(other) == _figures(run)), None)
        if twin is not None:
            raise UserError(f"{twin.path} and {run.path} are one run twice (one configuration, seed {run.seed}, the "
                            "same figures in summary.json), which would count twice in every mean: leave one out")
        group.append(run)
    return [sorted(group, key=lambda r: (str(r.seed), str(r.path))) for group in groups.values()]


def _figures(run: Run) -> dict[str, Any]:
    """What a run measured: summary.json without the wall time and the machines it ran on."""
    return {key: value for key, value in run.summary.items()
            if key not in (SummaryLayout.WALL_TIME, SummaryLayout.MACHINES)}
