"""``python -m lifelong_evo compare RUN_OR_DIR... [--out DIR] [--baseline KEY=VALUE,...] [--episodes ...]``:
configurations side by side, and each against its baseline.

Finds every run directory (config.json + summary.json) at or under the given paths (so a sweep
folder works), groups the runs by configuration (``rundir.group_runs``: runs that differ only in
the seed, the speed settings and the output settings of ``RunConfig``, or at lambda 0 in the
regulariser's options, are one) and writes, to ``--out`` (default: the one folder given, else
``comparison/``):

``comparison.md``    an overview (one line per configuration: ACC/BWT/FWT); per schedule of at
                     least two tasks the paper's tables, one line per configuration: one table per
                     deployed controller (the top individual; for an ES also the centre and the
                     best sample: the first task's C, the second's, the first task's retention R
                     and forgetting F at the second's end, the third task's C, ACC/BWT/FWT) and one
                     for the population (its best: C, R_pop, F_pop, ACC_pop/BWT_pop/FWT_pop, the
                     wall time per run); then each configuration against its baseline (paired
                     by seed within an algorithm, or Welch across algorithms and where they
                     share fewer than two seeds: difference, 95%
                     interval, p, effect size, seeds for 80% power, per outcome of the paper's
                     tables); then per configuration its tables in full: C per phase, R and F at
                     each later task end, ACC/BWT/FWT. Values are means over seeds with their
                     95% t-interval (one seed: the value alone); ``lifelong_evo.statistics`` has
                     the formulas.
``comparison.csv``   every figure the tables show and more: per configuration, metric and kind of
                     episodes its mean, interval and the value of each seed (with the seeds); per
                     configuration with a baseline, outcome and kind the difference with its
                     interval, p, effect size, seeds for 80% power, n and the per-seed differences
``comparison-current[-<schedule>].png``  each configuration's current-performance curve (mean
                     over seeds, min-max band) on a shared drift schedule
``comparison-retention[-<schedule>].png``  the same for the retention of every task while another
                     is current (red through green, green through red's return), the population's
                     and the top individual's, one line style per task
``comparison-diagnostics[-<schedule>].png``  the same for each diagnostic the optimisers log
                     (``Optimizer.diagnostics``: the distance to the regulariser's reference and
                     its spread; NEAT's fraction of disabled connections), one panel each
``model_specific_lambda.md`` / ``.json``  where a configuration ran several lambdas (below)

Episodes. Every figure names the episodes it was scored on: ``held-out`` (summary.json's
``held_out`` block: the exported controllers re-scored on the fixed held-out episodes, the same
for every run), ``selection-time`` (the top individual's score on the training episodes it was
selected on) or ``training`` (the population's best, and an ES centre's, on the training
episodes; no held-out counterpart). ``--episodes held-out`` (the default) shows the controllers'
held-out figures where the runs have the block and their selection-time ones elsewhere;
``training`` shows the selection-time ones; ``both`` shows both. The population's figures are
always training ones. comparison.csv holds every kind whatever ``--episodes`` says.

Baselines. Without ``--baseline`` each configuration with a regulariser is compared with lambda 0
of the same algorithm and otherwise the same settings, where such runs exist.
``--baseline KEY=VALUE,...`` names one configuration per schedule by its settings
(``baseline_settings``: ``algo``, ``reg``, ``schedule``, the other settings of ``RunConfig``, the
algorithm's options by name, the environment's as ``env.NAME``) and compares every other
configuration of that schedule with it; naming none, or several of one schedule, is a UserError.

The markdown is printed too. ``compare_table(paths)`` returns ``(rows, markdown)`` for reuse;
``write_comparison`` writes the tables (``sweep`` uses it for its own directory).

Model-specific lambda ("m.s. reg"): for each configuration without lambda and each seed, the
lambda maximising ``C_top(phase 1) + R_top(task of phase 0 at the end of phase 1)`` (the top
individual's current performance plus its retention of the first task at the end of the second
task: the controller one would deploy, good at both; ties go to the smaller lambda), chosen on the
selection-time figures (the training episodes) and reported as a configuration of its own with the
chosen lambda per seed, its tables held-out where the chosen runs have the block; beside it the
one lambda for all seeds, the highest mean of the same criterion over the seeds
(``select_model_specific``, ``model_specific_report``).
"""
from __future__ import annotations

import argparse
import csv
import itertools
import json
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from algorithms import REGISTRY

from .plots import CONFIG_COLORS, band, draw_drifts, retention_by_task, save, shade_phases, stack
from .checkpoint import atomic_write_bytes
from .errors import UserError
from .metrics import HELD_OUT_LEVELS
from .rundir import Run, config_key, configuration_of, describe_config, group_runs, is_run_dir, load_runs, write_json
from .schedule import parse_schedule
from .statistics import Difference, difference, seed_order, t_interval

HELD_OUT, SELECTION_TIME, TRAINING = "held-out", "selection-time", "training"
"""The kinds of episodes a figure was scored on (the module docstring says which is which)."""
EPISODES_CHOICES = ("held-out", "training", "both")
"""``--episodes``: which figures of the deployed controllers the tables show."""
CONTROLLERS = ("top", *(level for level in HELD_OUT_LEVELS.values() if level != "top"))
"""The deployed controllers in table order: the top individual, an ES centre and best sample."""
CONTROLLER_NAMES = {"top": "top individual", "centre": "centre (ES)", "best_sample": "best sample (ES)"}
TRAINING_KIND = {"top": SELECTION_TIME, "centre": TRAINING}
"""The kind of a controller's training-episode figures (none for the best sample: only held-out)."""
CSV_COLUMNS = ["configuration", "algo", "reg", "schedule", "statistic", "episodes", "metric", "baseline", "n",
               "n_baseline", "mean", "ci_low", "ci_high", "p", "p_method", "effect_size", "seeds_for_80_power",
               "seeds", "values"]


def _nan(value) -> bool:
    return isinstance(value, float) and math.isnan(value)


@dataclass(frozen=True)
class Estimate:
    """One metric over seeds: the seeds and values present (ascending by seed), their mean and
    its 95% t-interval (``statistics.t_interval``; NaN ends for one seed)."""

    seeds: list[Any]
    values: list[float]
    mean: float
    low: float
    high: float

    @classmethod
    def of(cls, values, seeds=None) -> Estimate:
        """The estimate of ``values`` (None and NaN left out), seed by seed (``seeds``: one per
        value; default: none named)."""
        pairs = [(s, float(v)) for s, v in zip(seeds if seeds is not None else itertools.repeat(None), values)
                 if v is not None and not _nan(v)]
        pairs.sort(key=lambda pair: (seed_order(pair[0]), pair[1]))
        interval = t_interval(v for _, v in pairs)
        return cls([s for s, _ in pairs], [v for _, v in pairs], interval.mean, interval.low, interval.high)

    def by_seed(self) -> dict[Any, float]:
        """Seed -> value (the mean of a seed run twice), for pairing with another configuration."""
        found: dict[Any, list[float]] = {}
        for seed, value in zip(self.seeds, self.values):
            found.setdefault(seed, []).append(value)
        return {seed: sum(v) / len(v) for seed, v in found.items()}

    def __str__(self) -> str:
        """A table cell: ``-`` for none, the value for one seed, else ``mean [low, high]``."""
        if not self.values:
            return "-"
        if len(self.values) == 1:
            return f"{self.mean:.2f}"
        return f"{self.mean:.2f} [{self.low:.2f}, {self.high:.2f}]"


Key = tuple[str, str]
"""A figure: (kind of episodes, metric name), e.g. ``("held-out", "R_top red at end of phase 1")``."""


def run_metrics(summary: dict[str, Any]) -> list[tuple[str, Key, float | None]]:
    """(section, (kind, metric name), value) of one run's summary.json, in table order: the
    training-episode figures (the population's: training; the top individual's: selection-time;
    an ES centre's: training), then those of the ``held_out`` block (held-out), then the wall time
    (kind ``""``)."""
    out: list[tuple[str, Key, float | None]] = []

    def add(kind: str, part: dict[str, Any], current: dict[str, str], forgetting: dict[str, str],
            transfer: list[str]) -> None:
        phases = part.get("phases", [])
        for name, key in current.items():
            for i, (task, value) in enumerate(zip(phases, part.get(key) or [])):
                out.append(("current", (kind[name], f"{name} phase {i} ({task})"), value))
        for row in part.get("forgetting", []):
            where = f"{row['task']} at end of phase {row['at_end_of']}"
            for key, kind_of in forgetting.items():
                if key in row:
                    out.append(("forgetting", (kind_of, f"{key} {where}"), row[key]))
        for name in transfer:
            if name in part:
                out.append(("transfer", (kind[name], name), part[name]))

    train = {"C": TRAINING, "C_top": SELECTION_TIME, "C_centre": TRAINING,
             **{f"{m}_{level}": kind for m in ("ACC", "BWT", "FWT") for level, kind in
                (("pop", TRAINING), ("top", SELECTION_TIME))}}
    add(train, summary, {"C": "current", "C_top": "current_top", "C_centre": "centre_current"},
        {"R_pop": TRAINING, "F_pop": TRAINING, "R_top": SELECTION_TIME, "F_top": SELECTION_TIME,
         "R_centre": TRAINING, "F_centre": TRAINING},
        [f"{m}_{level}" for level in ("pop", "top") for m in ("ACC", "BWT", "FWT")])
    held = summary.get("held_out")
    if held:
        levels = [level for level in CONTROLLERS if f"current_{level}" in held]
        transfer = [f"{m}_{level}" for level in levels for m in ("ACC", "BWT", "FWT")]
        add({name: HELD_OUT for name in [f"C_{level}" for level in levels] + transfer}, held,
            {f"C_{level}": f"current_{level}" for level in levels},
            {f"{m}_{level}": HELD_OUT for level in levels for m in ("R", "F")}, transfer)
    if summary.get("wall_time_s") is not None:
        out.append(("cost", ("", "wall time (min)"), summary["wall_time_s"] / 60))
    return out


Estimates = dict[Key, tuple[str, Estimate]]
"""(kind, metric name) -> (its section in ``run_metrics``, its estimate over seeds)."""


def estimates(runs: list[tuple[Any, dict[str, Any]]]) -> Estimates:
    """Every figure of ``run_metrics`` over ``runs``, (seed, summary.json dict) pairs."""
    per_metric: dict[Key, tuple[str, list, list]] = {}
    for seed, summary in runs:
        for section_name, key, value in run_metrics(summary):
            _, seeds, values = per_metric.setdefault(key, (section_name, [], []))
            seeds.append(seed)
            values.append(value)
    return {key: (section_name, Estimate.of(values, seeds)) for key, (section_name, seeds, values) in per_metric.items()}


def group_estimates(group: list[Run]) -> Estimates:
    return estimates([(run.seed, run.summary) for run in group])


def _has(found: Estimates, level: str, kind: str) -> bool:
    prefix = f"C_{level} phase "
    return any(k == kind and name.startswith(prefix) and est.values for (k, name), (_, est) in found.items())


def shown_controllers(founds: list[Estimates], episodes: str) -> list[tuple[str, str]]:
    """(controller, kind) whose figures the tables show for configurations whose estimates are
    ``founds`` (all of them must have the figures), in order: with ``episodes`` ``held-out``
    the held-out ones where present, else the training ones; ``training``: the training ones;
    ``both``: both."""
    held = [(level, HELD_OUT) for level in CONTROLLERS if all(_has(f, level, HELD_OUT) for f in founds)]
    trained = [(level, kind) for level, kind in TRAINING_KIND.items() if all(_has(f, level, kind) for f in founds)]
    if episodes == "training":
        return trained
    if episodes == "both":
        return held + trained
    return held or trained


def table(header: list[str], rows: list[list[Any]]) -> list[str]:
    """A markdown table's lines."""
    return ["| " + " | ".join(header) + " |", "|" + "---|" * len(header),
            *("| " + " | ".join(map(str, row)) + " |" for row in rows)]


def _cell(found: Estimates, key: Key) -> str:
    return str(found[key][1]) if key in found else "-"


def _present(found: Estimates, keys: list[Key]) -> bool:
    return any(key in found and found[key][1].values for key in keys)


def section(heading: str, intro: str, found: Estimates, episodes: str) -> str:
    """One configuration's tables: C per phase, R and F at each later task end, ACC/BWT/FWT, the
    population's (training) and each shown controller's (``shown_controllers``), every column
    named with its kind of episodes."""
    lines = [heading, "", intro, ""]
    shown = shown_controllers([found], episodes)
    phases = [name[len("C "):] for (kind, name), (sec, _) in found.items() if sec == "current" and name.startswith("C phase ")]
    if phases:
        columns = [("C (training)", (TRAINING, "C"))] + [(f"C_{level} ({kind})", (kind, f"C_{level}")) for level, kind in shown]
        lines += table(["phase", *(heading for heading, _ in columns)],
                       [[where, *(_cell(found, (kind, f"{m} {where}")) for _, (kind, m) in columns)] for where in phases])
        lines.append("")
    wheres = [name[len("R_pop "):] for (kind, name), (sec, _) in found.items()
              if sec == "forgetting" and name.startswith("R_pop ")]
    if wheres:
        columns = [(f"{m} (training)", (TRAINING, m)) for m in ("R_pop", "F_pop")]
        columns += [(f"{m}_{level} ({kind})", (kind, f"{m}_{level}")) for level, kind in shown for m in ("R", "F")]
        columns = [(heading, (kind, m)) for heading, (kind, m) in columns
                   if _present(found, [(kind, f"{m} {where}") for where in wheres])]
        lines += table(["task at end of phase", *(heading for heading, _ in columns)],
                       [[where, *(_cell(found, (kind, f"{m} {where}")) for _, (kind, m) in columns)] for where in wheres])
        lines.append("")
    levels = [("pop", TRAINING), *shown]
    rows = [[f"{level} ({kind})", *(_cell(found, (kind, f"{m}_{level}")) for m in ("ACC", "BWT", "FWT"))]
            for level, kind in levels if _present(found, [(kind, f"{m}_{level}") for m in ("ACC", "BWT", "FWT")])]
    if rows:
        lines += table(["controller (episodes)", "ACC", "BWT", "FWT"], rows)
        lines.append("")
    return "\n".join(lines)


def outcomes(phases: list[str], level: str) -> list[tuple[str, str]]:
    """(heading, metric name) of the paper's figures of one controller (``level``: ``pop`` for
    the population's best, ``top``, ``centre``, ``best_sample``) on a schedule of ``phases``
    (task names): the first task's C, the second's, the first task's retention R and forgetting
    F at the end of the second, the third task's C (in the paper's red -> green -> red, red when
    it returns), ACC, BWT, FWT; as many of them as the phases allow."""
    c = "C" if level == "pop" else f"C_{level}"
    first = phases[0]
    columns = [(f"{first} {c}", f"{c} phase 0 ({first})")]
    if len(phases) > 1:
        where = f"{first} at end of phase 1"
        columns += [(f"{phases[1]} {c}", f"{c} phase 1 ({phases[1]})"),
                    (f"{first} R_{level}", f"R_{level} {where}"), (f"{first} F_{level}", f"F_{level} {where}")]
    if len(phases) > 2:
        returns = " (returns)" if phases[2] == first else ""
        columns.append((f"{phases[2]} {c}{returns}", f"{c} phase 2 ({phases[2]})"))
    return columns + [(f"{m}_{level}", f"{m}_{level}") for m in ("ACC", "BWT", "FWT")]


@dataclass
class Configuration:
    """One configuration as the tables see it."""

    label: str
    config: dict[str, Any]
    runs: list[Run]
    phases: list[str]
    found: Estimates
    n: str
    """Its seed count for the tables (``seed_count``)."""


def paper_tables(configurations: list[Configuration], episodes: str) -> list[str]:
    """The paper's tables for each schedule with at least two tasks, configurations in the given
    order: one per deployed controller that some configuration shows (``shown_controllers``), a
    line per configuration and kind of episodes, and the population's (training episodes)."""
    lines: list[str] = []
    schedules = list(dict.fromkeys(tuple(c.phases) for c in configurations if len(c.phases) >= 2))
    for phases in schedules:
        mine = [c for c in configurations if tuple(c.phases) == phases]
        drift = " -> ".join(phases)
        for level in CONTROLLERS:
            rows = [[c.label, c.n, kind, *(_cell(c.found, (kind, name)) for _, name in outcomes(list(phases), level))]
                    for c in mine for shown, kind in shown_controllers([c.found], episodes) if shown == level]
            if rows:
                lines += [f"The paper's table ({drift}), the {CONTROLLER_NAMES[level]}: C on its own task at the "
                          f"task's end, the first task's retention R and forgetting F at the end of the second; "
                          "mean over seeds [95% t-interval]; episodes: held-out or selection-time (the training "
                          "episodes it was selected on).", "",
                          *table(["configuration", "n seeds", "episodes",
                                  *(heading for heading, _ in outcomes(list(phases), level))], rows), ""]
        columns = outcomes(list(phases), "pop")
        rows = [[c.label, c.n, *(_cell(c.found, (TRAINING, name)) for _, name in columns),
                 _cell(c.found, ("", "wall time (min)"))] for c in mine]
        lines += [f"The paper's table ({drift}), the population (its best, on the training episodes: no "
                  "held-out counterpart) and the wall time per run; mean over seeds [95% t-interval].", "",
                  *table(["configuration", "n seeds", *(heading for heading, _ in columns),
                          "wall time per run (min)"], rows), ""]
    return lines


# ------------------------------------------------------------------------------------- baselines

def baseline_settings(config: dict[str, Any]) -> dict[str, Any]:
    """The settings ``--baseline`` matches, by name: RunConfig's configuration settings (``algo``,
    ``reg``, ``schedule``, ``generations``, ...), the algorithm's options by their own names
    (``genetics``, ``sigma``, ``importance``) and the environment's as ``env.NAME``
    (``rundir.configuration_of``: as resolved, regulariser options dropped at lambda 0)."""
    settings: dict[str, Any] = {}
    for key, value in configuration_of(config).items():
        if key in ("env", "env_resolved"):
            settings.update({f"env.{name}": v for name, v in value.items()})
        elif key in ("algo_options", "algo_options_resolved"):
            settings.update(value)
        else:
            settings[key] = value
    return settings


def parse_baseline(given: list[str] | None) -> dict[str, str] | None:
    """``--baseline`` (each given once or more, items comma-separated) as KEY -> VALUE text."""
    if not given:
        return None
    items: dict[str, str] = {}
    for item in (part.strip() for text in given for part in text.split(",")):
        key, equals, value = item.partition("=")
        if not equals or not key.strip() or not value.strip():
            raise UserError(f"--baseline {item!r} is not KEY=VALUE: name the baseline configuration by its settings, "
                            "e.g. --baseline reg=0 or --baseline algo=neat,reg=0")
        items[key.strip()] = value.strip()
    return items


def _parse_like(text: str, example: Any, key: str) -> Any:
    """``text`` as the type of ``example`` (the value some configuration has for ``key``)."""
    if isinstance(example, bool):
        if text.lower() not in ("true", "false"):
            raise UserError(f"--baseline {key}={text}: {key} is true or false")
        return text.lower() == "true"
    if isinstance(example, (int, float)):
        try:
            return float(text)
        except ValueError:
            raise UserError(f"--baseline {key}={text}: {key} is a number, e.g. {key}={example:g}") from None
    if isinstance(example, str):
        return text
    try:
        return json.loads(text)
    except ValueError:
        raise UserError(f"--baseline {key}={text}: {key} is given as JSON, e.g. {key}={json.dumps(example)}") from None


def _equal(value: Any, wanted: Any) -> bool:
    if isinstance(wanted, float) and isinstance(value, (int, float)) and not isinstance(value, bool):
        return float(value) == wanted
    return json.dumps(value) == json.dumps(wanted)


def choose_baselines(configurations: list[Configuration], items: dict[str, str] | None) -> list[int | None]:
    """The index of each configuration's baseline in ``configurations`` (None: none, or itself).
    Without ``items``: lambda 0 of the same algorithm and otherwise the same settings, for a
    configuration with a regulariser. With ``items`` (``--baseline``): in each schedule, the one
    configuration whose ``baseline_settings`` has every item; UserError where no configuration
    matches, or several of one schedule do."""
    if items is None:
        def at_lambda_0(config: dict[str, Any]) -> str:
            return config_key({**config, "reg": 0.0})  # 0.0: as config.json writes lambda 0

        unregularised = {at_lambda_0(c.config): i for i, c in enumerate(configurations) if not float(c.config.get("reg") or 0)}
        return [unregularised.get(at_lambda_0(c.config)) if float(c.config.get("reg") or 0) else None
                for c in configurations]
    settings = [baseline_settings(c.config) for c in configurations]
    wanted = {}
    for key, text in items.items():
        examples = [s[key] for s in settings if key in s]
        if not examples:
            known = sorted({k for s in settings for k in s if not k.startswith("env.")})
            raise UserError(f"--baseline {key}={text}: no configuration compared has a setting {key}; the settings "
                            f"are {', '.join(known)} and env.NAME for an environment setting")
        wanted[key] = _parse_like(text, examples[0], key)
    matching = [i for i, s in enumerate(settings) if all(k in s and _equal(s[k], v) for k, v in wanted.items())]
    named = ",".join(f"{k}={v}" for k, v in items.items())
    if not matching:
        raise UserError(f"--baseline {named} matches none of the {len(configurations)} configurations compared "
                        f"({'; '.join(c.label for c in configurations)}): name one of them by its settings")
    chosen: dict[tuple[str, ...], int] = {}
    for i in matching:
        phases = tuple(configurations[i].phases)
        if phases in chosen:
            both = [configurations[j].label for j in matching if tuple(configurations[j].phases) == phases]
            raise UserError(f"--baseline {named} matches {len(both)} configurations of schedule "
                            f"{' -> '.join(phases)} ({'; '.join(both)}): add an item that tells them apart, "
                            "e.g. algo=... or an option")
        chosen[phases] = i
    return [None if chosen.get(tuple(c.phases)) in (None, i) else chosen[tuple(c.phases)]
            for i, c in enumerate(configurations)]


def pairable(config: Configuration, baseline: Configuration) -> bool:
    """Whether runs of the two configurations are paired by seed: runs of one algorithm with the
    same seed draw the same episodes and start from the same population, so they share their
    sample path up to where their settings part (lambda: up to the first drift); runs of two
    algorithms share at most the episodes, not the population that meets them, and are compared
    unpaired (Welch)."""
    return config.config.get("algo") == baseline.config.get("algo")


def differences(config: Configuration, baseline: Configuration) -> list[tuple[str, str, Key, Difference]]:
    """(controller, heading, (kind, metric name), configuration minus baseline) for each outcome both have,
    of every kind: the paper's figures (``outcomes``) of each controller, then of the population.
    Paired by seed where the runs are ``pairable`` and share at least two seeds, else Welch
    (``statistics.difference``)."""
    same_algo = pairable(config, baseline)
    found: list[tuple[str, str, Key, Difference]] = []
    kinds = [*((level, HELD_OUT) for level in CONTROLLERS), *TRAINING_KIND.items(), ("pop", TRAINING)]
    for level, kind in kinds:
        for heading, name in outcomes(config.phases, level):
            mine, theirs = config.found.get((kind, name)), baseline.found.get((kind, name))
            if mine and theirs and mine[1].values and theirs[1].values:
                found.append((level, heading, (kind, name),
                              difference(mine[1].by_seed(), theirs[1].by_seed(), same_algo)))
    return found


def format_difference(d: Difference) -> list[str]:
    """The cells of a differences-table row: difference [interval], p, effect size, n, seeds for 80% power."""
    interval = "" if _nan(d.low) else f" [{d.low:+.2f}, {d.high:+.2f}]"
    p = "-" if d.p is None else f"{d.p:.3g}" + ("" if d.p_exact or d.test == "Welch" else " (random flips)")
    effect = "-" if d.effect is None else f"{d.effect:+.2f}"
    n = str(d.n) if d.test == "paired" else f"{d.n} + {d.n_baseline} (Welch)"
    power = "-" if d.seeds_for_power is None else ("inf" if math.isinf(d.seeds_for_power) else str(d.seeds_for_power))
    return [f"{d.mean:+.2f}{interval}", p, effect, n, power]


def differences_section(config: Configuration, baseline: Configuration, episodes: str) -> str:
    """The markdown of ``config`` against ``baseline``: a row per outcome shown (the population's,
    training; the controllers' kinds per ``shown_controllers`` of both), and the seeds left out."""
    shown = {("pop", TRAINING), *shown_controllers([config.found, baseline.found], episodes)}
    rows = [[heading, kind, *format_difference(d)] for level, heading, (kind, _), d in differences(config, baseline)
            if (level, kind) in shown]
    seeds = {run.seed for run in config.runs}
    theirs = {run.seed for run in baseline.runs}
    paired = pairable(config, baseline) and len(seeds & theirs) >= 2
    lines = [f"### {config.label} against {baseline.label}", ""]
    if paired:
        lines.append("Paired by seed: per outcome the mean of the per-seed differences (this configuration minus "
                     "the baseline) with its 95% t-interval, the exact two-sided sign-flip permutation p-value (never "
                     "below 2/2^n with n pairs: 0.0625 with 5), "
                     "the effect size d_z (mean difference / SD of the differences), n: the seeds both ran that "
                     "have the figure, and the seeds a two-sided paired t-test (alpha 0.05) needs to detect d_z "
                     "with 80% power.")
        alone = sorted(seeds ^ theirs, key=seed_order)
        if alone:
            lines.append("Left out of the pairs (run by one of the two only): seed(s) "
                         + ", ".join(f"{s} ({config.label if s in seeds else baseline.label})" for s in alone) + ".")
    else:
        why = ("two algorithms: a seed's runs share no sample path" if not pairable(config, baseline)
               else "fewer than two seeds in common")
        lines.append(f"Welch ({why}, so unpaired): per outcome the difference of the means "
                     "(this configuration minus the baseline) with Welch's 95% interval and p-value, the effect size "
                     "d = difference / sqrt((SD_a^2 + SD_b^2) / 2), n: the seeds of each, and the seeds per "
                     "configuration a two-sided two-sample t-test (alpha 0.05) needs to detect d with 80% power.")
    effect = "d_z" if paired else "d"
    lines += ["", *table(["outcome", "episodes", "difference [95% interval]", "p", effect, "n seeds",
                          "seeds for 80% power"], rows), ""]
    return "\n".join(lines)


# ------------------------------------------------------------------------------------------ tables

def csv_rows(label: str, config: dict[str, Any], found: Estimates, reg: Any = None) -> list[dict[str, Any]]:
    """comparison.csv's mean rows of one configuration (``reg``: what its reg column says, default its lambda)."""
    return [{**_csv_head(label, config, reg), "statistic": "mean", "episodes": kind, "metric": name,
             "n": len(estimate.values), "mean": estimate.mean, "ci_low": estimate.low, "ci_high": estimate.high,
             "seeds": estimate.seeds, "values": estimate.values}
            for (kind, name), (_, estimate) in found.items()]


def _csv_head(label: str, config: dict[str, Any], reg: Any = None) -> dict[str, Any]:
    return {"configuration": label, "algo": config.get("algo"), "reg": config.get("reg") if reg is None else reg,
            "schedule": config.get("schedule")}


def difference_rows(config: Configuration, baseline: Configuration) -> list[dict[str, Any]]:
    """comparison.csv's rows of ``config`` against ``baseline``: every outcome of every kind."""
    rows = []
    for _, _, (kind, name), d in differences(config, baseline):
        rows.append({**_csv_head(config.label, config.config), "statistic": f"{d.test} difference", "episodes": kind,
                     "metric": name, "baseline": baseline.label, "n": d.n, "n_baseline": d.n_baseline,
                     "mean": d.mean, "ci_low": d.low, "ci_high": d.high, "p": d.p,
                     "p_method": ("Welch t-test" if d.test == "Welch" else
                                  "exact sign-flip" if d.p_exact else "random sign-flip"),
                     "effect_size": d.effect, "seeds_for_80_power": d.seeds_for_power,
                     "seeds": d.seeds, "values": d.differences})
    return rows


def compare_table(paths, episodes: str = "held-out", baseline: dict[str, str] | None = None
                  ) -> tuple[list[dict[str, Any]], str]:
    """Rows (comparison.csv's: see CSV_COLUMNS; ``seeds`` and ``values`` are sequences) and the
    markdown report, for every run at or under ``paths``; ``episodes`` and ``baseline`` as
    ``--episodes`` and ``--baseline`` (``parse_baseline``) take them."""
    return _table(load_runs(paths, with_metrics=False), episodes, baseline)


def configurations(runs: list[Run]) -> list[Configuration]:
    """The runs' configurations, in table order, with their estimates."""
    # each group by seed (numerically), so nothing below depends on the order the runs came in
    groups = [sorted(g, key=lambda r: (seed_order(r.seed), str(r.path))) for g in _sorted_groups(group_runs(runs))]
    configs = [g[0].config for g in groups]
    return [Configuration(describe_config(config, configs), config, group,
                          [p.name for p in parse_schedule(str(config.get("schedule")), int(config.get("generations", 0)))],
                          group_estimates(group), seed_count(group))
            for group, config in zip(groups, configs)]


def _table(runs: list[Run], episodes: str = "held-out", baseline: dict[str, str] | None = None
           ) -> tuple[list[dict[str, Any]], str]:
    found = configurations(runs)
    baselines = choose_baselines(found, baseline)
    rows: list[dict[str, Any]] = []
    overview, sections, compared = [], [], []
    for c, b in zip(found, baselines):
        rows += csv_rows(c.label, c.config, c.found)
        if b is not None:
            rows += difference_rows(c, found[b])
            compared.append(differences_section(c, found[b], episodes))
        overview.append(overview_row(c.label, c.n, c.found, episodes))
        seeds = ", ".join(f"{r.seed}{'' if r.finished else ' (unfinished)'}" for r in c.runs)
        sections.append(section(f"## {c.label}", f"{len(c.runs)} seed(s): {seeds}", c.found, episodes))
    against = (["## Differences from the baseline", "",
                "Each configuration against its baseline (" + ("named by --baseline" if baseline else
                "lambda 0 of the same algorithm and otherwise the same settings") + "), per outcome of the paper's "
                "tables.", "", *compared] if compared else [])
    header = [f"# Comparison of {len(runs)} run(s) in {len(found)} configuration(s)", "",
              "Mean over seeds [95% t-interval]; a single seed shows its value. C: current performance at the end "
              "of a phase (the population's: its best; C_top: that of the top individual, the best by selection "
              "fitness; for an ES C_centre and C_best_sample: the search distribution's centre and the best "
              "sample); R/F: retention/forgetting of an earlier task; ACC/BWT/FWT: average final performance, "
              "backward and forward transfer. Episodes: held-out (the exported controllers re-scored on the "
              "fixed held-out episodes), selection-time (the top individual on the training episodes it was "
              "selected on) or training (the population's best; an ES centre).", "",
              *table(["configuration", "n seeds", *OVERVIEW], overview), "", *paper_tables(found, episodes), *against]
    return rows, "\n".join(header + sections)


OVERVIEW = ("ACC_pop", "BWT_pop", "FWT_pop", "ACC_top", "BWT_top", "FWT_top", "episodes (top)")


def overview_row(label: str, n: str, found: Estimates, episodes: str) -> list[str]:
    """A configuration's overview line: the population's ACC/BWT/FWT (training) and the top
    individual's, of the first kind ``shown_controllers`` shows."""
    kinds = [kind for level, kind in shown_controllers([found], episodes) if level == "top"]
    kind = kinds[0] if kinds else SELECTION_TIME
    return [label, n, *(_cell(found, (TRAINING, f"{m}_pop")) for m in ("ACC", "BWT", "FWT")),
            *(_cell(found, (kind, f"{m}_top")) for m in ("ACC", "BWT", "FWT")), kind]


def seed_count(group: list[Run]) -> str:
    """A configuration's seeds for the tables: ``5``, or ``5 (2 unfinished)`` while some of its
    runs have not ended every task (their later metrics are missing, so a row's cells can rest
    on fewer seeds than its count)."""
    unfinished = sum(not run.finished for run in group)
    return f"{len(group)} ({unfinished} unfinished)" if unfinished else str(len(group))


def _sorted_groups(groups: list[list[Run]]) -> list[list[Run]]:
    return sorted(groups, key=lambda g: (str(g[0].config.get("schedule")), str(g[0].config.get("algo")),
                                         float(g[0].config.get("reg") or 0), g[0].key))


# ------------------------------------------------------------------------------- model-specific lambda

CRITERION = "C_top(phase 1) + R_top(task of phase 0 at end of phase 1)"


def selection_score(summary: dict[str, Any]) -> float | None:
    """``C_top(phase 1) + R_top(task of phase 0 at the end of phase 1)``; None before phase 1 ended."""
    current = summary.get("current_top") or []
    phases = summary.get("phases") or []
    if len(current) < 2 or len(phases) < 2:
        return None
    rows = [r for r in summary.get("forgetting", []) if r["at_end_of"] == 1 and r["task"] == phases[0]]
    if not rows or current[1] is None or rows[0]["R_top"] is None:
        return None
    return float(current[1]) + float(rows[0]["R_top"])


def select_model_specific(runs: list[tuple[dict[str, Any], dict[str, Any], Any]]) -> list[dict[str, Any]]:
    """The model-specific lambda: ``runs`` are (config.json dict, summary.json dict, tag) triples;
    for each configuration without lambda that was run with several lambdas, and each of its seeds,
    the run whose lambda maximises ``selection_score`` (ties: the smaller lambda). A run without
    regulariser (lambda 0) is a candidate of every such configuration it differs from only in the
    regulariser's options (``Optimizer.regularizer_options``: L2 and EWC-style importance both
    choose between their lambdas and none).

    Returns one dict per such configuration: ``config`` (the config of one of its regularised
    runs), ``choices``, one per seed in ascending order: ``seed``, ``reg``, ``score``, ``tag``, and
    ``shared``, the one lambda for every seed: among the lambdas every seed ran, the one whose
    mean ``selection_score`` over the seeds is highest (ties: the smaller lambda), with
    ``means`` (lambda -> that mean); ``None`` where no lambda was run by every seed."""
    def without_lambda(config: dict[str, Any]) -> str:
        rest = {k: v for k, v in configuration_of(config).items() if k != "reg"}
        return json.dumps(rest, sort_keys=True, default=str)

    groups: dict[str, dict[str, Any]] = {}
    base_of: dict[str, str] = {}
    # regularised runs first, so each lambda-0 run finds every configuration it belongs to
    for config, summary, tag in sorted(runs, key=lambda run: not float(run[0]["reg"])):
        base = without_lambda({**config, "reg": 0})
        if float(config["reg"]):
            keys = [without_lambda(config)]
            base_of[keys[0]] = base
        else:
            keys = [key for key, its_base in base_of.items() if its_base == base] or [base]
        for key in keys:
            group = groups.setdefault(key, {"regs": set(), "by_seed": {}, "config": config})
            group["regs"].add(float(config["reg"]))
            score = selection_score(summary)
            if score is not None and math.isfinite(score):
                group["by_seed"].setdefault(config["seed"], []).append((score, float(config["reg"]), tag))
    result = []
    for group in groups.values():
        if len(group["regs"]) < 2 or not group["by_seed"]:
            continue
        choices = []
        for seed in sorted(group["by_seed"]):
            score, reg, tag = max(group["by_seed"][seed], key=lambda c: (c[0], -c[1]))
            choices.append({"seed": seed, "reg": reg, "score": score, "tag": tag})
        scores: dict[float, list[float]] = {}
        for runs_of_seed in group["by_seed"].values():
            for score, reg, _ in runs_of_seed:
                scores.setdefault(reg, []).append(score)
        means = {reg: sum(v) / len(v) for reg, v in sorted(scores.items()) if len(v) == len(group["by_seed"])}
        shared = None
        if means:
            best = max(means, key=lambda reg: (means[reg], -reg))
            shared = {"reg": best, "means": means}
        result.append({"config": group["config"], "choices": choices, "shared": shared})
    return result


def model_specific_label(config: dict[str, Any], all_configs: list[dict[str, Any]]) -> str:
    """``compare``'s label of the configuration with ``reg=m.s.``, e.g. ``neat reg=m.s. red-green-red``."""
    return re.sub(r"reg=\S+", "reg=m.s.", describe_config(config, all_configs), count=1)


def model_specific_report(selections: list[dict[str, Any]], summaries: dict[Any, dict[str, Any]],
                          all_configs: list[dict[str, Any]], episodes: str = "held-out"
                          ) -> tuple[list[dict[str, Any]], str]:
    """``compare_table``'s rows and markdown for the m.s. configurations (the chosen lambdas in
    ``reg``): an overview line per m.s. configuration with the lambda per seed and the criterion,
    then its tables; means over seeds of the chosen runs with their 95% t-interval. The lambdas
    are chosen on the selection-time figures; the chosen runs are reported as ``episodes`` says
    (held-out where they have the block, by default)."""
    rows: list[dict[str, Any]] = []
    overview, sections = [], []
    for selection in selections:
        config = selection["config"]
        label = model_specific_label(config, all_configs)
        choices = selection["choices"]
        lambdas = ", ".join(f"{c['seed']}: {c['reg']:g}" for c in choices)
        shared = selection.get("shared")
        one = "" if shared is None else (f"{shared['reg']:g} (" + ", ".join(
            f"{reg:g}: {mean:.2f}" for reg, mean in shared["means"].items()) + ")")
        found = {(SELECTION_TIME, CRITERION): ("selection", Estimate.of([c["score"] for c in choices],
                                                                        [c["seed"] for c in choices])),
                 **estimates([(c["seed"], summaries[c["tag"]]) for c in choices])}
        rows += csv_rows(label, config, found, reg="m.s. " + " ".join(f"{c['reg']:g}" for c in choices))
        overview.append([label, len(choices), lambdas, one, _cell(found, (SELECTION_TIME, CRITERION)),
                         *overview_row(label, str(len(choices)), found, episodes)[2:]])
        sections.append(section(f"### {label}", f"lambda per seed: {lambdas}", found, episodes))
    markdown = "\n".join([
        "## Model-specific lambda (m.s. reg)", "",
        f"Per configuration and seed, the lambda of the sweep maximising {CRITERION} (the top individual's "
        "current performance plus its retention of the first task, at the end of the second task; ties: "
        "the smaller lambda), from summary.json: chosen on the training episodes (selection-time figures). "
        "The chosen runs are reported below with held-out figures where they have them (each table names its "
        "episodes); mean over seeds [95% t-interval]. One lambda for all seeds: among the lambdas every seed "
        "ran, the one with the highest mean of the criterion over the seeds (ties: the smaller), with each "
        "lambda's mean.", "",
        *table(["configuration", "n seeds", "lambda per seed", "one lambda for all seeds (mean per lambda)",
                f"{CRITERION} (selection-time)", *OVERVIEW], overview), "",
        *sections]).rstrip("\n")
    return rows, markdown


def _csv_value(value: Any) -> Any:
    """A number as comparison.csv writes it: exactly (``repr``), ``inf``, or empty for none/NaN."""
    if value is None or _nan(value):
        return ""
    if isinstance(value, float):
        return "inf" if math.isinf(value) else repr(value)
    return value


def write_csv(rows: list[dict[str, Any]], path: Path) -> Path:
    """comparison.csv: a line per row, ``seeds`` and ``values`` space-separated, empty cells where a
    row has no such figure."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=CSV_COLUMNS)
        writer.writeheader()
        for row in rows:
            writer.writerow({**{k: _csv_value(row.get(k)) for k in CSV_COLUMNS},
                             "seeds": " ".join(str(s) for s in row.get("seeds", ()) if s is not None),
                             "values": " ".join(repr(float(v)) for v in row.get("values", ()))})
    return path


def _overlay(ax, groups: list[list[Run]], configs: list[dict[str, Any]], series) -> bool:
    """Each configuration's ``series(group)`` (generations, values per seed; None where it has
    none) as mean over seeds with a min-max band, over the schedule's phases; False if no
    configuration had any."""
    drawn = False
    for k, group in enumerate(groups):
        found = series(group)
        if found is not None:
            generations, values = found
            band(ax, generations, values, CONFIG_COLORS[k % len(CONFIG_COLORS)], "-", _legend(group, configs),
                 marker="o" if len(generations) < 40 else None)
            drawn = True
    _finish(ax, groups)
    return drawn


RETENTION_STYLES = ("-", "--", ":", "-.")
"""Line style of each task's retention, in the schedule's order of first appearance."""


def _overlay_retention(ax, groups: list[list[Run]], configs: list[dict[str, Any]], level: str) -> bool:
    """Each configuration's retention of every task while another is current (``level``: pop or
    top), one colour per configuration and one line style per task, so a red -> green -> red
    schedule shows red kept through green and green kept through red's return; False if none."""
    tasks = list(dict.fromkeys(groups[0][0].tasks))
    drawn = False
    for k, group in enumerate(groups):
        found = retention_by_task(group, level)
        label = _legend(group, configs)
        for task, style in zip(tasks, itertools.cycle(RETENTION_STYLES)):
            if task in found:
                generations, values = found[task]
                band(ax, generations, values, CONFIG_COLORS[k % len(CONFIG_COLORS)], style, label,
                     marker="o" if len(generations) < 40 else None)
                label, drawn = None, True
    if drawn:
        for task, style in zip(tasks, itertools.cycle(RETENTION_STYLES)):
            ax.plot([], [], color="0.3", linestyle=style, label=f"retention of {task}")
    _finish(ax, groups)
    return drawn


def _legend(group: list[Run], configs: list[dict[str, Any]]) -> str:
    return f"{describe_config(group[0].config, configs)} (n={len(group)})"


def _finish(ax, groups: list[list[Run]]) -> None:
    draw_drifts(ax, groups[0][0])
    shade_phases(ax, groups[0][0])
    ax.set_xlabel("generation")
    ax.margins(y=0.08)
    ax.grid(alpha=0.25)
    # beside the axes: with a few configurations overlaid, any place inside hides some curve
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)


def _column(name: str):
    """The ``series`` of a metrics.csv column, for ``_overlay``."""
    return lambda group: stack(group, name) if name in group[0].metrics[0] else None


def _diagnostics(groups: list[list[Run]]) -> list[str]:
    """The optimisers' per-generation diagnostics (``Optimizer.diagnostics``) these runs logged."""
    names: dict[str, None] = {}
    for group in groups:
        optimizer = REGISTRY.get(str(group[0].config.get("algo")))
        names.update((name, None) for name in getattr(optimizer, "diagnostics", ()) if name in group[0].metrics[0])
    return list(names)


def overlay_figures(paths, out: Path) -> list[Path]:
    """Per schedule: every configuration's current performance, and the optimisers' diagnostics
    where they logged any, as mean over seeds with a min-max band."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    runs = [r for r in load_runs(paths) if r.metrics]
    by_schedule: dict[str, list[list[Run]]] = {}
    for group in _sorted_groups(group_runs(runs)):
        config = group[0].config
        phases = parse_schedule(str(config.get("schedule")), int(config.get("generations", 0)))
        by_schedule.setdefault(repr([(p.name, p.generations) for p in phases]), []).append(group)
    configs = [g[0].config for groups in by_schedule.values() for g in groups]
    written = []
    for index, groups in enumerate(by_schedule.values()):
        schedule = str(groups[0][0].config.get("schedule", ""))
        suffix = "" if len(by_schedule) == 1 else f"-{index}-" + re.sub(r"[^A-Za-z0-9]+", "-", schedule).strip("-")
        fig, ax = plt.subplots(figsize=(13, 5), constrained_layout=True)
        _overlay(ax, groups, configs, _column("best"))
        ax.set_title(f"Current performance C (best of the population on the current task), schedule {schedule}\n"
                     "mean over seeds, band: min-max; coloured strip: the current task", fontsize=10)
        ax.set_ylabel("fitness (reward per episode)")
        written.append(save(fig, out / f"comparison-current{suffix}.png"))
        fig, axes = plt.subplots(2, 1, figsize=(13, 8), sharex=True, constrained_layout=True)
        drawn = [_overlay_retention(ax, groups, configs, level) for ax, level in zip(axes, ("pop", "top"))]
        if any(drawn):
            axes[0].set_xlabel("")
            axes[0].set_ylabel("R_pop")
            axes[1].set_ylabel("R_top")
            axes[0].set_title(f"Retention of each earlier task while another is current (population: best; "
                              f"top individual), schedule {schedule}\n"
                              "mean over seeds, band: min-max; line style: the task; coloured strip: the current task",
                              fontsize=10)
            written.append(save(fig, out / f"comparison-retention{suffix}.png"))
        else:
            plt.close(fig)
        names = _diagnostics(groups)
        if names:
            fig, axes = plt.subplots(len(names), 1, figsize=(13, 3.2 * len(names)), sharex=True,
                                     constrained_layout=True, squeeze=False)
            for ax, name in zip(axes[:, 0], names):
                _overlay(ax, groups, configs, _column(name))
                ax.set_ylabel(name)
            axes[0, 0].set_title(f"Optimiser diagnostics per generation, schedule {schedule}\n"
                                 "mean over seeds, band: min-max; coloured strip: the current task", fontsize=10)
            written.append(save(fig, out / f"comparison-diagnostics{suffix}.png"))
    return written


def default_out(paths) -> Path:
    if len(paths) == 1 and Path(paths[0]).is_dir() and not is_run_dir(Path(paths[0])):
        return Path(paths[0])
    return Path("comparison")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("paths", nargs="+", metavar="RUN_OR_DIR", help="run directories or folders holding them")
    parser.add_argument("--out", default=None, metavar="DIR",
                        help="where to write comparison.md/.csv and the figure (default: the one folder given, "
                             "else comparison/)")
    parser.add_argument("--baseline", action="append", default=None, metavar="KEY=VALUE[,KEY=VALUE...]",
                        help="the configuration the others are compared with, named by its settings (algo, reg, "
                             "schedule, an option such as genetics, env.NAME): one per schedule, e.g. "
                             "algo=neat,reg=0 (default: for each configuration with a regulariser, lambda 0 of the "
                             "same algorithm and otherwise the same settings)")
    parser.add_argument("--episodes", choices=EPISODES_CHOICES, default="held-out",
                        help="the deployed controllers' figures in the tables: held-out (the default: where the "
                             "runs have summary.json's held_out block, else the selection-time ones), training "
                             "(the selection-time ones) or both; the population's are training figures always")


@dataclass
class Comparison:
    """What ``compare`` writes, computed before anything is written."""

    rows: list[dict[str, Any]]
    markdown: str
    model_specific_markdown: str | None
    model_specific_json: list[dict[str, Any]]


def comparison(paths, episodes: str = "held-out", baseline: dict[str, str] | None = None) -> Comparison:
    """``compare_table`` of the runs at or under ``paths`` plus, where a configuration ran several
    lambdas, the model-specific lambda rows."""
    runs = load_runs(paths, with_metrics=False)
    rows, markdown = _table(runs, episodes, baseline)
    names = [run.path.name for run in runs]
    tags = names if len(set(names)) == len(names) else [str(run.path) for run in runs]
    configs = [run.config for run in runs]
    selections = select_model_specific([(run.config, run.summary, tag) for run, tag in zip(runs, tags)])
    if not selections:
        return Comparison(rows, markdown, None, [])
    ms_rows, ms_markdown = model_specific_report(selections, dict(zip(tags, (r.summary for r in runs))), configs,
                                                 episodes)
    ms_json = [{"configuration": model_specific_label(s["config"], configs), "criterion": CRITERION,
                "choices": s["choices"],
                "one_lambda_for_all_seeds": None if s["shared"] is None else {
                    "reg": s["shared"]["reg"],
                    "mean_per_lambda": [{"reg": r, "mean": m} for r, m in s["shared"]["means"].items()]}}
               for s in selections]
    return Comparison(rows + ms_rows, markdown + "\n" + ms_markdown, ms_markdown, ms_json)


def write_report(report: Comparison, out: Path) -> str:
    """Writes ``report`` to ``out``/comparison.md and comparison.csv, the m.s. part also to
    model_specific_lambda.md and .json. Returns the markdown."""
    out.mkdir(parents=True, exist_ok=True)
    if report.model_specific_markdown is not None:
        atomic_write_bytes(out / "model_specific_lambda.md", (report.model_specific_markdown + "\n").encode())
        write_json(out / "model_specific_lambda.json", report.model_specific_json)
    atomic_write_bytes(out / "comparison.md", (report.markdown + "\n").encode())
    write_csv(report.rows, out / "comparison.csv")
    return report.markdown


def write_comparison(paths, out: Path, episodes: str = "held-out", baseline: dict[str, str] | None = None) -> str:
    """``comparison`` written to ``out`` (``write_report``); returns the markdown."""
    return write_report(comparison(paths, episodes, baseline), out)


def main(args: argparse.Namespace) -> int:
    out = Path(args.out) if args.out else default_out(args.paths)
    report = comparison(args.paths, args.episodes, parse_baseline(args.baseline))  # a bad --baseline writes nothing
    figures = overlay_figures(args.paths, out)  # reads every metrics.csv before it writes: a bad one writes nothing
    markdown = write_report(report, out)
    print(markdown)
    print(f"wrote {out / 'comparison.md'}, {out / 'comparison.csv'}" + "".join(f", {f}" for f in figures))
    return 0
