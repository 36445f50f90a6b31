"""``python -m lifelong_evo compare RUN_OR_DIR... [--out DIR]``: configurations side by side.

Finds every run directory (config.json + summary.json) at or under the given paths (so a sweep
folder works), groups the runs by configuration (``rundir.group_runs``: runs that differ only in
the seed, the speed settings and the output settings of ``RunConfig``, or at lambda 0 in the
regulariser's options, are one) and writes, to
``--out`` (default: the one folder given, else ``comparison/``):

``comparison.md``    an overview (one line per configuration: ACC/BWT/FWT), the paper's table (one
                     line per configuration, per schedule of at least two tasks: the first task's
                     C, the second's C_top, the first task's retention and forgetting at the
                     second's end, C of the third task, ACC/BWT/FWT of the population and the
                     wall time per run), then per configuration the paper's tables in full:
                     current performance C per phase (and C_top, the top individual's),
                     retention R and forgetting F of the population and the top individual at
                     each later task end, ACC/BWT/FWT; every value is the mean over seeds with its
                     95% bootstrap interval (2000 resamples, fixed seed; one seed: the value alone)
``comparison.csv``   the same values, one line per configuration and metric (with the raw values)
``comparison-current[-<schedule>].png``  each configuration's current-performance curve (mean
                     over seeds, min-max band) on a shared drift schedule
``comparison-retention[-<schedule>].png``  the same for the retention of every task while another
                     is current (red through green, green through red's return), the population's
                     and the top individual's, one line style per task
``comparison-diagnostics[-<schedule>].png``  the same for each diagnostic the optimisers log
                     (``Optimizer.diagnostics``: the distance to the regulariser's reference and
                     its spread; NEAT's fraction of disabled connections), one panel each
``model_specific_lambda.md`` / ``.json``  where a configuration ran several lambdas (below)

The markdown is printed too. ``compare_table(paths)`` returns ``(rows, markdown)`` for reuse;
``write_comparison`` writes the tables (``sweep`` uses it for its own directory).

Model-specific lambda ("m.s. reg"): for each configuration without lambda and each seed, the
lambda maximising ``C_top(phase 1) + R_top(task of phase 0 at the end of phase 1)`` (the top
individual's current performance plus its retention of the first task at the end of the second
task: the controller one would deploy, good at both; ties go to the smaller lambda), reported as a
configuration of its own with the chosen lambda per seed; beside it the one lambda for all seeds,
the highest mean of the same criterion over the seeds (``select_model_specific``,
``model_specific_report``).
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

import numpy as np

from algorithms import REGISTRY

from .plots import CONFIG_COLORS, band, draw_drifts, retention_by_task, save, shade_phases, stack
from .checkpoint import atomic_write_bytes
from .rundir import Run, configuration_of, describe_config, group_runs, is_run_dir, load_runs, write_json
from .schedule import parse_schedule

RESAMPLES = 2000
BOOTSTRAP_SEED = 0
CSV_COLUMNS = ["configuration", "algo", "reg", "schedule", "metric", "n", "mean", "ci_low", "ci_high", "values"]
TRANSFER = ("ACC_pop", "BWT_pop", "FWT_pop", "ACC_top", "BWT_top", "FWT_top")


def bootstrap_ci(values, resamples: int = RESAMPLES, seed: int = BOOTSTRAP_SEED) -> tuple[float, float, float]:
    """(mean, low, high): the mean and the 2.5/97.5 percentiles of the means of ``resamples``
    resamples with replacement (numpy, fixed seed). One value: (v, v, v)."""
    data = np.asarray([v for v in values if v is not None and not _nan(v)], dtype=float)
    if data.size == 0:
        return math.nan, math.nan, math.nan
    mean = float(data.mean())
    if data.size == 1:
        return mean, mean, mean
    rng = np.random.default_rng(seed)
    means = data[rng.integers(0, data.size, size=(resamples, data.size))].mean(axis=1)
    low, high = np.percentile(means, [2.5, 97.5])
    return mean, float(low), float(high)


def _nan(value) -> bool:
    return isinstance(value, float) and math.isnan(value)


@dataclass(frozen=True)
class Estimate:
    """One metric over seeds: the values present, their mean and its 95% bootstrap interval."""

    values: list[float]
    mean: float
    low: float
    high: float

    @classmethod
    def of(cls, values) -> Estimate:
        present = [v for v in values if v is not None and not _nan(v)]
        return cls(present, *bootstrap_ci(present))

    def __str__(self) -> str:
        """A table cell: ``-`` for none, the value for one seed, else ``mean [low, high]``."""
        if math.isnan(self.mean):
            return "-"
        if len(self.values) <= 1:
            return f"{self.mean:.2f}"
        return f"{self.mean:.2f} [{self.low:.2f}, {self.high:.2f}]"


def run_metrics(summary: dict[str, Any]) -> list[tuple[str, str, float | None]]:
    """(section, metric name, value) of one run's summary.json, in table order."""
    out: list[tuple[str, str, float | None]] = []
    for name, key in (("C", "current"), ("C_top", "current_top")):
        for i, (task, value) in enumerate(zip(summary.get("phases", []), summary.get(key, []))):
            out.append(("current", f"{name} phase {i} ({task})", value))
    for row in summary.get("forgetting", []):
        where = f"{row['task']} at end of phase {row['at_end_of']}"
        for key in ("R_pop", "F_pop", "R_top", "F_top"):
            out.append(("forgetting", f"{key} {where}", row.get(key)))
    for level in ("pop", "top"):
        for key in ("ACC", "BWT", "FWT"):
            name = f"{key}_{level}"
            if name in summary:
                out.append(("transfer", name, summary[name]))
    if summary.get("wall_time_s") is not None:
        out.append(("cost", "wall time (min)", summary["wall_time_s"] / 60))
    return out


Estimates = dict[str, tuple[str, Estimate]]
"""Metric name -> (its section in ``run_metrics``, its estimate over seeds)."""


def estimates(summaries: list[dict[str, Any]]) -> Estimates:
    """Every metric of ``run_metrics`` over the runs whose summary.json are ``summaries``."""
    per_metric: dict[str, tuple[str, list]] = {}
    for summary in summaries:
        for section, name, value in run_metrics(summary):
            per_metric.setdefault(name, (section, []))[1].append(value)
    return {name: (section, Estimate.of(values)) for name, (section, values) in per_metric.items()}


def table(header: list[str], rows: list[list[Any]]) -> list[str]:
    """A markdown table's lines."""
    return ["| " + " | ".join(header) + " |", "|" + "---|" * len(header),
            *("| " + " | ".join(map(str, row)) + " |" for row in rows)]


def _cell(found: Estimates, name: str) -> str:
    return str(found[name][1]) if name in found else "-"


def section(heading: str, intro: str, found: Estimates) -> str:
    """One configuration's tables: C and C_top per phase, R and F at each later task end, ACC/BWT/FWT."""
    lines = [heading, "", intro, ""]
    phases = [k[len("C "):] for k, (kind, _) in found.items() if kind == "current" and k.startswith("C phase ")]
    if phases:
        lines += table(["phase", "C (current)", "C_top (top individual)"],
                       [[where, *(_cell(found, f"{m} {where}") for m in ("C", "C_top"))] for where in phases])
        lines.append("")
    wheres = [k[len("R_pop "):] for k, (kind, _) in found.items() if kind == "forgetting" and k.startswith("R_pop ")]
    if wheres:
        lines += table(["task at end of phase", "R_pop", "F_pop", "R_top", "F_top"],
                       [[where, *(_cell(found, f"{m} {where}") for m in ("R_pop", "F_pop", "R_top", "F_top"))]
                        for where in wheres])
        lines.append("")
    if any(kind == "transfer" for kind, _ in found.values()):
        lines += table(["level", "ACC", "BWT", "FWT"],
                       [[level, *(_cell(found, f"{m}_{level}") for m in ("ACC", "BWT", "FWT"))] for level in ("pop", "top")])
        lines.append("")
    return "\n".join(lines)


def paper_columns(phases: list[str]) -> list[tuple[str, str]]:
    """(heading, metric name) of the paper's one-line-per-configuration table for a schedule of
    ``phases`` (task names; at least two): the first task learnt (C), the second learnt by the top
    individual (C_top), the first task's retention and forgetting at the second's end, the third
    task's C (in the paper's red -> green -> red, red when it returns), transfer and cost."""
    first, second = phases[0], phases[1]
    where = f"{first} at end of phase 1"
    columns = [(f"{first} C", f"C phase 0 ({first})"), (f"{second} C_top", f"C_top phase 1 ({second})"),
               *((f"{first} {key}", f"{key} {where}") for key in ("R_pop", "F_pop", "R_top", "F_top"))]
    if len(phases) > 2:
        returns = " (returns)" if phases[2] == first else ""
        columns.append((f"{phases[2]} C{returns}", f"C phase 2 ({phases[2]})"))
    return columns + [(name, name) for name in ("ACC_pop", "BWT_pop", "FWT_pop")] + [("wall time per run (min)",
                                                                                       "wall time (min)")]


def paper_tables(labelled: list[tuple[str, int, list[str], Estimates]]) -> list[str]:
    """The paper's table for each schedule among ``labelled`` (label, seeds, phases, estimates)
    with at least two tasks, configurations in the given order."""
    lines: list[str] = []
    schedules = list(dict.fromkeys(tuple(phases) for _, _, phases, _ in labelled if len(phases) >= 2))
    for phases in schedules:
        columns = paper_columns(list(phases))
        rows = [[label, n, *(_cell(found, name) for _, name in columns)]
                for label, n, their, found in labelled if tuple(their) == phases]
        lines += [f"The paper's table ({' -> '.join(phases)}): the first task's retention at the end of the "
                  "second; mean over seeds [95% bootstrap interval].", "",
                  *table(["configuration", "n seeds", *(heading for heading, _ in columns)], rows), ""]
    return lines


def csv_rows(label: str, config: dict[str, Any], found: Estimates, reg: Any = None) -> list[dict[str, Any]]:
    """comparison.csv's rows of one configuration (``reg``: what its reg column says, default its lambda)."""
    return [{"configuration": label, "algo": config.get("algo"), "reg": config.get("reg") if reg is None else reg,
             "schedule": config.get("schedule"), "metric": name, "n": len(estimate.values), "mean": estimate.mean,
             "ci_low": estimate.low, "ci_high": estimate.high, "values": estimate.values}
            for name, (_, estimate) in found.items()]


def compare_table(paths) -> tuple[list[dict[str, Any]], str]:
    """Rows (one per configuration and metric: see CSV_COLUMNS; ``values`` is the list over
    seeds) and the markdown report, for every run at or under ``paths``."""
    return _table(load_runs(paths, with_metrics=False))


def _table(runs: list[Run]) -> tuple[list[dict[str, Any]], str]:
    groups = _sorted_groups(group_runs(runs))
    configs = [g[0].config for g in groups]
    rows: list[dict[str, Any]] = []
    overview, sections, labelled = [], [], []
    for group, config in zip(groups, configs):
        label = describe_config(config, configs)
        found = estimates([run.summary for run in group])
        rows += csv_rows(label, config, found)
        n = seed_count(group)
        overview.append([label, n, *(_cell(found, name) for name in TRANSFER)])
        phases = [p.name for p in parse_schedule(str(config.get("schedule")), int(config.get("generations", 0)))]
        labelled.append((label, n, phases, found))
        seeds = ", ".join(f"{r.seed}{'' if r.finished else ' (unfinished)'}" for r in group)
        sections.append(section(f"## {label}", f"{len(group)} seed(s): {seeds}", found))
    header = [f"# Comparison of {len(runs)} run(s) in {len(groups)} configuration(s)", "",
              "Mean over seeds [95% bootstrap interval, "
              f"{RESAMPLES} resamples]; a single seed shows its value. C: current performance at the end of "
              "a phase (C_top: that of the top individual, the best by selection fitness); R/F: "
              "retention/forgetting of an earlier task (pop: best of the population, top: the "
              "current top individual); ACC/BWT/FWT: average final performance, backward and forward transfer.",
              "", *table(["configuration", "n seeds", *TRANSFER], overview), "", *paper_tables(labelled)]
    return rows, "\n".join(header + sections)


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
                          all_configs: list[dict[str, Any]]) -> tuple[list[dict[str, Any]], str]:
    """``compare_table``'s rows and markdown for the m.s. configurations (the chosen lambdas in
    ``reg``): an overview line per m.s. configuration with the lambda per seed and the criterion,
    then its tables; means over seeds of the chosen runs, with their 95% bootstrap interval."""
    rows: list[dict[str, Any]] = []
    overview, sections = [], []
    for selection in selections:
        config = selection["config"]
        label = model_specific_label(config, all_configs)
        lambdas = ", ".join(f"{c['seed']}: {c['reg']:g}" for c in selection["choices"])
        shared = selection.get("shared")
        one = "" if shared is None else (f"{shared['reg']:g} (" + ", ".join(
            f"{reg:g}: {mean:.2f}" for reg, mean in shared["means"].items()) + ")")
        found = {CRITERION: ("selection", Estimate.of([c["score"] for c in selection["choices"]])),
                 **estimates([summaries[c["tag"]] for c in selection["choices"]])}
        rows += csv_rows(label, config, found, reg="m.s. " + " ".join(f"{c['reg']:g}" for c in selection["choices"]))
        overview.append([label, len(selection["choices"]), lambdas, one,
                         *(_cell(found, k) for k in (CRITERION, *TRANSFER))])
        sections.append(section(f"### {label}", f"lambda per seed: {lambdas}", found))
    markdown = "\n".join([
        "## Model-specific lambda (m.s. reg)", "",
        f"Per configuration and seed, the lambda of the sweep maximising {CRITERION} (the top individual's "
        "current performance plus its retention of the first task, at the end of the second task; ties: "
        "the smaller lambda), from summary.json. Mean over seeds [95% bootstrap interval] of the chosen runs. "
        "One lambda for all seeds: among the lambdas every seed ran, the one with the highest mean of the "
        "criterion over the seeds (ties: the smaller), with each lambda's mean.", "",
        *table(["configuration", "n seeds", "lambda per seed", "one lambda for all seeds (mean per lambda)",
                CRITERION, *TRANSFER], overview), "",
        *sections]).rstrip("\n")
    return rows, markdown


def write_csv(rows: list[dict[str, Any]], path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=CSV_COLUMNS)
        writer.writeheader()
        for row in rows:
            writer.writerow({**row, "values": " ".join(repr(float(v)) for v in row["values"]),
                             **{k: ("" if _nan(row[k]) else repr(row[k])) for k in ("mean", "ci_low", "ci_high")}})
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


def write_comparison(paths, out: Path) -> str:
    """``compare_table`` of the runs at or under ``paths`` plus, where a configuration ran several
    lambdas, the model-specific lambda rows: written to ``out``/comparison.md and comparison.csv,
    the m.s. part also to model_specific_lambda.md and .json. Returns the markdown."""
    runs = load_runs(paths, with_metrics=False)
    rows, markdown = _table(runs)
    names = [run.path.name for run in runs]
    tags = names if len(set(names)) == len(names) else [str(run.path) for run in runs]
    configs = [run.config for run in runs]
    selections = select_model_specific([(run.config, run.summary, tag) for run, tag in zip(runs, tags)])
    out.mkdir(parents=True, exist_ok=True)
    if selections:
        ms_rows, ms_markdown = model_specific_report(selections, dict(zip(tags, (r.summary for r in runs))), configs)
        rows += ms_rows
        markdown += "\n" + ms_markdown
        atomic_write_bytes(out / "model_specific_lambda.md", (ms_markdown + "\n").encode())
        write_json(out / "model_specific_lambda.json",
                   [{"configuration": model_specific_label(s["config"], configs), "criterion": CRITERION,
                     "choices": s["choices"],
                     "one_lambda_for_all_seeds": None if s["shared"] is None else {
                         "reg": s["shared"]["reg"],
                         "mean_per_lambda": [{"reg": r, "mean": m} for r, m in s["shared"]["means"].items()]}}
                    for s in selections])
    atomic_write_bytes(out / "comparison.md", (markdown + "\n").encode())
    write_csv(rows, out / "comparison.csv")
    return markdown


def main(args: argparse.Namespace) -> int:
    out = Path(args.out) if args.out else default_out(args.paths)
    figures = overlay_figures(args.paths, out)  # reads every metrics.csv before it writes: a bad one writes nothing
    markdown = write_comparison(args.paths, out)
    print(markdown)
    print(f"wrote {out / 'comparison.md'}, {out / 'comparison.csv'}" + "".join(f", {f}" for f in figures))
    return 0
