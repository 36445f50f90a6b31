"""``python -m lifelong_evo compare RUN_OR_DIR... [--out DIR]``: configurations side by side.

Finds every run directory (config.json + summary.json) at or under the given paths (so a sweep
folder works), groups the runs by configuration (``rundir.group_runs``: runs that differ only in
the seed, the speed settings and the output settings of ``RunConfig`` are one) and writes, to ``--out`` (default: the one folder given, else ``comparison/``):

``comparison.md``    an overview (one line per configuration), then per configuration the paper's
                     table: current performance C per phase (and C_top, the top individual's),
                     retention R and forgetting F of the
                     population and the top individual at each later task end, ACC/BWT/FWT;
                     every value is the mean over seeds with its 95% bootstrap interval
                     (2000 resamples, fixed seed; one seed: the value alone)
``comparison.csv``   the same values, one line per configuration and metric (with the raw values)
``comparison-current[-<schedule>].png``  each configuration's current-performance curve (mean
                     over seeds, min-max band) on a shared drift schedule

The markdown is printed too. ``compare_table(paths)`` returns ``(rows, markdown)`` for reuse.
"""
from __future__ import annotations

import argparse
import csv
import math
import re
from pathlib import Path
from typing import Any

import numpy as np

from .plots import CONFIG_COLORS, band, draw_drifts, save, shade_phases, stack
from .rundir import Run, describe_config, group_runs, is_run_dir, load_runs
from .schedule import parse_schedule

RESAMPLES = 2000
BOOTSTRAP_SEED = 0
CSV_COLUMNS = ["configuration", "algo", "reg", "schedule", "metric", "n", "mean", "ci_low", "ci_high", "values"]


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
    return out


def _fmt(mean: float, low: float, high: float, n: int) -> str:
    if math.isnan(mean):
        return "-"
    if n <= 1:
        return f"{mean:.2f}"
    return f"{mean:.2f} [{low:.2f}, {high:.2f}]"


def compare_table(paths) -> tuple[list[dict[str, Any]], str]:
    """Rows (one per configuration and metric: see CSV_COLUMNS; ``values`` is the list over
    seeds) and the markdown report, for every run at or under ``paths``."""
    runs = load_runs(paths, with_metrics=False)
    groups = _sorted_groups(group_runs(runs))
    configs = [g[0].config for g in groups]
    rows: list[dict[str, Any]] = []
    sections: list[str] = []
    overview = ["| configuration | n seeds | ACC_pop | BWT_pop | FWT_pop | ACC_top | BWT_top | FWT_top |",
                "|---|---|---|---|---|---|---|---|"]
    for group, config in zip(groups, configs):
        label = describe_config(config, configs)
        per_metric: dict[str, tuple[str, list]] = {}
        for run in group:
            for section, name, value in run_metrics(run.summary):
                per_metric.setdefault(name, (section, []))[1].append(value)
        stats = {}
        for name, (section, values) in per_metric.items():
            present = [v for v in values if v is not None and not _nan(v)]
            mean, low, high = bootstrap_ci(present)
            stats[name] = (section, mean, low, high, len(present))
            rows.append({"configuration": label, "algo": config.get("algo"), "reg": config.get("reg"),
                         "schedule": config.get("schedule"), "metric": name, "n": len(present), "mean": mean,
                         "ci_low": low, "ci_high": high, "values": present})
        cells = [_fmt(*stats[k][1:]) if k in stats else "-"
                 for k in ("ACC_pop", "BWT_pop", "FWT_pop", "ACC_top", "BWT_top", "FWT_top")]
        overview.append(f"| {label} | {len(group)} | " + " | ".join(cells) + " |")
        sections.append(_section(label, group, stats))
    header = [f"# Comparison of {len(runs)} run(s) in {len(groups)} configuration(s)", "",
              "Mean over seeds [95% bootstrap interval, "
              f"{RESAMPLES} resamples]; a single seed shows its value. C: current performance at the end of "
              "a phase (C_top: that of the top individual, the best by selection fitness); R/F: "
              "retention/forgetting of an earlier task (pop: best of the population, top: the "
              "current top individual); ACC/BWT/FWT: average final performance, backward and forward transfer.",
              "", *overview, ""]
    return rows, "\n".join(header + sections)


def _section(label: str, group: list[Run], stats: dict) -> str:
    seeds = ", ".join(str(r.seed) for r in group)
    lines = [f"## {label}", "", f"{len(group)} seed(s): {seeds}", ""]
    phases = [k[len("C "):] for k, v in stats.items() if v[0] == "current" and k.startswith("C phase ")]
    if phases:
        lines += ["| phase | C (current) | C_top (top individual) |", "|---|---|---|"]
        for where in phases:
            cells = [_fmt(*stats[f"{m} {where}"][1:]) if f"{m} {where}" in stats else "-" for m in ("C", "C_top")]
            lines.append(f"| {where} | " + " | ".join(cells) + " |")
        lines.append("")
    forgetting = [k for k, v in stats.items() if v[0] == "forgetting" and k.startswith("R_pop ")]
    if forgetting:
        lines += ["| task at end of phase | R_pop | F_pop | R_top | F_top |", "|---|---|---|---|---|"]
        for key in forgetting:
            where = key[len("R_pop "):]
            cells = [_fmt(*stats[f"{m} {where}"][1:]) if f"{m} {where}" in stats else "-"
                     for m in ("R_pop", "F_pop", "R_top", "F_top")]
            lines.append(f"| {where} | " + " | ".join(cells) + " |")
        lines.append("")
    transfer = [k for k, v in stats.items() if v[0] == "transfer"]
    if transfer:
        lines += ["| level | ACC | BWT | FWT |", "|---|---|---|---|"]
        for level in ("pop", "top"):
            cells = [_fmt(*stats[f"{m}_{level}"][1:]) if f"{m}_{level}" in stats else "-"
                     for m in ("ACC", "BWT", "FWT")]
            lines.append(f"| {level} | " + " | ".join(cells) + " |")
        lines.append("")
    return "\n".join(lines)


def _sorted_groups(groups: list[list[Run]]) -> list[list[Run]]:
    return sorted(groups, key=lambda g: (str(g[0].config.get("schedule")), str(g[0].config.get("algo")),
                                         float(g[0].config.get("reg") or 0), g[0].key))


def write_csv(rows: list[dict[str, Any]], path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=CSV_COLUMNS)
        writer.writeheader()
        for row in rows:
            writer.writerow({**row, "values": " ".join(repr(float(v)) for v in row["values"]),
                             **{k: ("" if _nan(row[k]) else repr(row[k])) for k in ("mean", "ci_low", "ci_high")}})
    return path


def overlay_figures(paths, out: Path) -> list[Path]:
    """Per schedule: every configuration's current performance (mean over seeds, min-max band)."""
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
        fig, ax = plt.subplots(figsize=(10, 5), constrained_layout=True)
        for k, group in enumerate(groups):
            label = f"{describe_config(group[0].config, configs)} (n={len(group)})"
            generations, values = stack(group, "best")
            band(ax, generations, values, CONFIG_COLORS[k % len(CONFIG_COLORS)], "-", label)
        draw_drifts(ax, groups[0][0])
        shade_phases(ax, groups[0][0])
        schedule = str(groups[0][0].config.get("schedule", ""))
        ax.set_title(f"Current performance C (best of the population on the current task), schedule {schedule}\n"
                     "mean over seeds, band: min-max; coloured strip: the current task", fontsize=10)
        ax.set_xlabel("generation")
        ax.set_ylabel("fitness (reward per episode)")
        ax.margins(y=0.08)
        ax.grid(alpha=0.25)
        ax.legend(fontsize=8, loc="best")
        suffix = "" if len(by_schedule) == 1 else f"-{index}-" + re.sub(r"[^A-Za-z0-9]+", "-", schedule).strip("-")
        written.append(save(fig, out / f"comparison-current{suffix}.png"))
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


def main(args: argparse.Namespace) -> int:
    rows, markdown = compare_table(args.paths)
    out = Path(args.out) if args.out else default_out(args.paths)
    figures = overlay_figures(args.paths, out)  # reads every metrics.csv before it writes: a bad one writes nothing
    out.mkdir(parents=True, exist_ok=True)
    (out / "comparison.md").write_text(markdown + "\n")
    write_csv(rows, out / "comparison.csv")
    print(markdown)
    print(f"wrote {out / 'comparison.md'}, {out / 'comparison.csv'}" + "".join(f", {f}" for f in figures))
    return 0
