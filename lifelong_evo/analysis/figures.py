"""Every figure, as PNG (matplotlib, Agg): ``plot``'s per configuration (``plot_runs``) and
``compare``'s overlays (``overlay_figures``).

It reads run directories through ``lifelong_evo.runs`` and only draws. For each group of runs
that share a configuration (``runs.group_runs``: repetitions that differ in seed or speed settings),
with ``<prefix>`` = ``<algo>-<schedule>-reg<lambda>``, a regulariser other than the family's
default before ``-reg`` as in run names (``<algo>-<schedule>-wp-reg<lambda>``), followed by whatever
else sets the configuration apart from the others plotted (``runs.config_differences``, e.g. ``-sigma-0.05``):

``<prefix>-retention-pop.png``  current performance C (solid) and population retention R_pop
                                 (dashed, dots where measured) per task colour over generations
                                 (a second task of one colour: dash-dot and dotted; later ones
                                 those again with a marker each: ``TASK_STYLES``); drifts as grey
                                 dashed vertical lines
``<prefix>-retention-top.png``  the top individual's current fitness (solid) and retention
                                 R_top (dashed); without a regulariser its current fitness is C
                                 (both: where summary.json has the ``stability_gap`` block, each
                                 seed's lowest retention after a switch as a triangle, in the
                                 earlier task's colour)
``<prefix>-species.png``        NEAT: the number of species over generations
``<prefix>-lifespans[-seed<S>].png``  NEAT: each species' life (birth to extinction) and size,
                                 from ``species.csv`` (generation, species_id, size); one per seed
``<prefix>-network-task<i>-<task>[-seed<S>].png``  per task end, its top controller against the
                                 reference written beside it (``task<i>-<task>-reference.json``,
                                 ``lifelong_evo.networks``, as the recording draws it): NEAT's
                                 network (inputs read, hidden nodes, outputs; enabled connections,
                                 red positive, blue negative, width by weight, dashed where the
                                 reference lacks them) and what was measured (genetic distance,
                                 or weight protection's sums); an ES's per-layer distance to the
                                 reference; one per seed

A group of several seeds is drawn as the mean over seeds with a shaded min-max band. Colours are
the task colours. Without ``--out`` the figures go next to the runs they plot: into the deepest
folder that holds them all (a single run's directory; a sweep's directory for its trials).

Every input is read and checked (each run's metrics.csv and species.csv, the output folder)
before the first figure is drawn: a bad one is a one-line error with nothing written.
"""
from __future__ import annotations

import os
import re
import textwrap
from pathlib import Path
from typing import Any

import numpy as np

from algorithms import REGISTRY
from envs import color_rgb, task_rgb

from ..config import DEFAULT_REGULARISER, name_stem
from ..errors import UserError
from ..metrics import CURRENT_LEVELS, current_curve
from ..metrics_csv import retention_columns
from ..networks import NetworkView, columns, describe, task_end_views
from ..rundir import RunDir
from ..runs import Run, config_differences, configuration_of, describe_config, group_runs, load_runs
from ..schedule import distinct_tasks, schedule_of
from ..summary_json import SummaryLayout
from .tables import sorted_groups


_RANK_MARKERS = (None, "s", "^", "D", "P", "X", "*", "h", "d", "p", "<", ">", "8", "H")
"""Markers that set tasks of one colour apart (not ``o``, a measured retention point, nor
``GAP_MARKER``)."""
TASK_STYLES = tuple((current, retention, marker) for marker in _RANK_MARKERS
                    for current, retention in (("-", "--"), ("-.", ":")))
"""The looks (current performance's line style, retention's line style, marker) of a run's first,
second, ... task of one target colour, so that tasks sharing a colour (red, and red with the nest
at the bottom) stay apart: the first two solid/dashed and dash-dot/dotted, each later pair of
those again with a marker of its own; no two alike. ``plot`` refuses a run with more tasks of one
colour than there are looks (``check_task_looks``)."""


def _task_looks(run: Run | None) -> dict[str, tuple[int, int]]:
    """Each task of ``run``'s schedule: its target colour id and its rank among the schedule's
    tasks of that colour (0 for the first)."""
    looks: dict[str, tuple[int, int]] = {}
    if run is not None:
        for task in distinct_tasks(schedule_of(run.config)):
            looks[task.name] = (task.target, sum(target == task.target for target, _ in looks.values()))
    return looks


def task_color(task: str, run: Run | None = None) -> tuple[float, float, float]:
    """A task's display colour, its target colour's (a task ``run`` defines, or a built-in one:
    ``envs.task_rgb``), as matplotlib wants it (0..1)."""
    looks = _task_looks(run)
    return tuple(c / 255 for c in (color_rgb(looks[task][0]) if task in looks else task_rgb(task)))


def task_styles(task: str, run: Run | None = None) -> tuple:
    """The looks (current line style, retention line style, marker) of ``task`` in ``run``
    (``TASK_STYLES``; ``check_task_looks`` has checked that there is one)."""
    return TASK_STYLES[_task_looks(run).get(task, (0, 0))[1]]


def check_task_looks(run: Run) -> None:
    """Refuse, before anything is drawn, a run whose schedule has more tasks of one target colour
    than ``TASK_STYLES`` tells apart."""
    looks = _task_looks(run)
    for target in {target for target, _ in looks.values()}:
        names = [name for name, (colour, _) in looks.items() if colour == target]
        if len(names) > len(TASK_STYLES):
            raise UserError(f"{run.path}: the schedule has {len(names)} tasks of one target colour "
                            f"({', '.join(names)}), and plot tells at most {len(TASK_STYLES)} apart: read this run's "
                            "metrics.csv (docs/metrics.md) for the others")


# ---------------------------------------------------------------------------------------------
# Series over seeds


def drift_generations(run: Run) -> list[int]:
    """Generations at which a new phase starts (from task_index in metrics.csv)."""
    index = [int(row["task_index"]) for row in run.metrics]
    return [int(run.metrics[i]["generation"]) for i in range(1, len(index)) if index[i] != index[i - 1]]


def stack(group: list[Run], column: str) -> tuple[np.ndarray, np.ndarray]:
    """(generations, values (seeds, generations)) of a column, cut to the shortest run."""
    length = min(len(run.metrics) for run in group)
    generations = group[0].generations[:length]
    return generations, np.stack([run.column(column)[:length] for run in group])


def stack_current(group: list[Run], level: str = "pop") -> tuple[np.ndarray, np.ndarray]:
    """``stack`` of the current task's score (``metrics.current_curve``), cut to the shortest run."""
    length = min(len(run.metrics) for run in group)
    values = [[np.nan if v is None else v for v in current_curve(run.metrics[:length], level)] for run in group]
    return group[0].generations[:length], np.array(values, dtype=float)


def current_by_task(group: list[Run], column: str = "best") -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per task: (generations, values (seeds, generations)) of ``column`` masked to the generations
    where that task is the current one (NaN elsewhere, so that phases are separate lines); for
    ``best`` and ``top``, the current task's own score (``metrics.current_curve``: where training
    mixed tasks, not the mixture's)."""
    level = {value: key for key, value in CURRENT_LEVELS.items()}.get(column)
    generations, values = stack(group, column) if level is None else stack_current(group, level)
    tasks = np.array(group[0].tasks[:len(generations)])
    out = {}
    for task in dict.fromkeys(tasks):
        masked = np.where(tasks[None, :] == task, values, np.nan)
        out[str(task)] = (generations, masked)
    return out


def retention_by_task(group: list[Run], level: str) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per earlier task: the measured retention points (generations where any seed measured it),
    with NaN at the generations where that task is the current one (a break in the line)."""
    out = {}
    columns = retention_columns(group[0].metrics[0], level) if group[0].metrics else {}
    for task, column in columns.items():
        generations, values = stack(group, column)
        current = np.array(group[0].tasks[:len(generations)]) == task
        measured = ~np.all(np.isnan(values), axis=0) & ~current
        if measured.any():
            keep = measured | current
            out[task] = (generations[keep], np.where(current[None, keep], np.nan, values[:, keep]))
    return out


def band(ax, generations, values, color, linestyle, label, marker=None, markevery=None):
    """Mean over seeds (rows) and, with several seeds, a min-max band; ``marker`` on every point,
    or spaced as matplotlib's ``markevery`` says (a measured point's dot small, a task's marker
    large enough to tell apart)."""
    with np.errstate(all="ignore"):
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            mean = np.nanmean(values, axis=0)
            low, high = np.nanmin(values, axis=0), np.nanmax(values, axis=0)
    ax.plot(generations, mean, color=color, linestyle=linestyle, label=label, linewidth=1.6, marker=marker,
            markersize=3 if marker == "o" else 5, markevery=markevery)
    if values.shape[0] > 1:
        ax.fill_between(generations, low, high, color=color, alpha=0.18, linewidth=0)


GAP_MARKER = "v"
"""The marker of a stability gap's minimum."""


def mark_stability_gaps(ax, group: list[Run], level: str) -> None:
    """Each run's stability-gap minima of ``level`` (summary.json's ``stability_gap`` block: the
    lowest retention of an earlier task in the first generations after a switch) as a triangle at
    (``generation_<level>``, ``min_<level>``) in that task's colour: one per seed, since the mean
    curve of several seeds need not pass through any seed's minimum."""
    label = "stability gap: lowest retention after a switch"
    for run in group:
        for entry in run.summary.get(SummaryLayout.STABILITY_GAP) or []:
            if entry.get(f"min_{level}") is not None:
                ax.plot([entry[f"generation_{level}"]], [entry[f"min_{level}"]], linestyle="none", marker=GAP_MARKER,
                        markersize=8, color=task_color(entry["task"], run), markeredgecolor="0.1", zorder=4,
                        label=label)
                label = None


def draw_drifts(ax, run: Run) -> None:
    for i, g in enumerate(drift_generations(run)):
        ax.axvline(g - 0.5, color="0.3", linestyle=(0, (6, 4)), linewidth=1.1, label="drift" if i == 0 else None)


def _title(group: list[Run], label: str) -> str:
    seeds = [r.seed for r in group]
    return label + (f" ({len(group)} seeds, mean and min-max)" if len(group) > 1 else f" (seed {seeds[0]})")


# ---------------------------------------------------------------------------------------------
# Figures


def figure_retention(group: list[Run], level: str, path: Path, label: str) -> Path:
    import matplotlib.pyplot as plt

    what = {"pop": "population retention R_pop", "top": "top-individual retention R_top"}[level]
    # runs from before the "top" column draw C: the same curve unless a regulariser ranked them
    current = "top" if level == "top" and np.isfinite(group[0].column("top")).any() else "best"
    label = {"best": "current C", "top": "top individual, current"}[current]
    fig, ax = plt.subplots(figsize=(9, 4.8), constrained_layout=True)
    run = group[0]
    spaced = 0.04  # a task's marker every 4% of the axes' diagonal along a dense curve
    for task, (generations, values) in current_by_task(group, current).items():
        style, _, marker = task_styles(task, run)
        band(ax, generations, values, task_color(task, run), style, f"{task}: {label}", marker, spaced)
    for task, (generations, values) in retention_by_task(group, level).items():
        _, style, marker = task_styles(task, run)
        measured = len(generations) < 40  # few points: mark each, with the task's marker or a dot
        band(ax, generations, values, task_color(task, run), style, f"{task}: {what.split(' R_')[0]}",
             marker or ("o" if measured else None), None if measured else spaced)
    mark_stability_gaps(ax, group, level)
    draw_drifts(ax, group[0])
    ax.set_xlabel("generation")
    ax.set_ylabel("fitness (reward per episode)")
    ax.set_title(f"Current performance and {what}\n{_title(group, label)}", fontsize=10)
    ax.grid(alpha=0.25)
    ax.legend(fontsize=8, loc="best")
    return save(fig, path)


def figure_species(group: list[Run], path: Path, label: str) -> Path | None:
    import matplotlib.pyplot as plt

    if not group[0].metrics or "species" not in group[0].metrics[0]:
        return None
    generations, values = stack(group, "species")
    if np.all(np.isnan(values)):
        return None
    fig, ax = plt.subplots(figsize=(9, 3.6), constrained_layout=True)
    band(ax, generations, values, "0.2", "-", "species")
    draw_drifts(ax, group[0])
    shade_phases(ax, group[0])
    ax.set_xlabel("generation")
    ax.set_ylabel("species")
    ax.margins(y=0.08)
    ax.yaxis.get_major_locator().set_params(integer=True)
    ax.set_title(f"Number of species\n{_title(group, label)}", fontsize=10)
    ax.grid(alpha=0.25)
    ax.legend(fontsize=8, loc="best")
    return save(fig, path)


def shade_phases(ax, run: Run) -> None:
    """A faint band of each phase's task colour along the bottom of the axes."""
    generations = run.generations
    tasks = run.tasks
    start = 0
    for i in range(1, len(tasks) + 1):
        if i == len(tasks) or run.metrics[i]["task_index"] != run.metrics[start]["task_index"]:
            ax.axvspan(generations[start] - 0.5, generations[i - 1] + 0.5, ymin=0, ymax=0.025,
                       color=task_color(tasks[start], run), alpha=0.8, linewidth=0)
            start = i


def figure_lifespans(run: Run, rows: list[tuple[int, int, int]] | None, path: Path, label: str) -> Path | None:
    """One horizontal bar per species from its first to its last generation, from the run's
    species.csv ``rows`` (``Run.species_rows``); thickness and shade follow its size (members),
    drifts as dotted lines."""
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection

    if not rows:
        return None
    by_species: dict[int, list[tuple[int, int]]] = {}
    for generation, species_id, size in rows:
        by_species.setdefault(species_id, []).append((generation, size))
    order = sorted(by_species, key=lambda s: (min(g for g, _ in by_species[s]), s))
    biggest = max(size for _, _, size in rows)
    fig, ax = plt.subplots(figsize=(9, max(3.0, min(12.0, 1.2 + 0.22 * len(order)))), constrained_layout=True)
    segments, widths, colors = [], [], []
    cmap = plt.get_cmap("viridis")
    for y, species_id in enumerate(order):
        for generation, size in sorted(by_species[species_id]):
            segments.append([(generation - 0.5, y), (generation + 0.5, y)])
            widths.append(1.0 + 7.0 * size / biggest)
            colors.append(cmap(0.15 + 0.8 * size / biggest))
    ax.add_collection(LineCollection(segments, linewidths=widths, colors=colors))
    ax.set_xlim(run.generations.min() - 1, run.generations.max() + 1)
    ax.set_ylim(-1, len(order))
    ax.set_yticks(range(len(order)))
    ax.set_yticklabels([str(s) for s in order], fontsize=7 if len(order) < 40 else 5)
    draw_drifts(ax, run)
    ax.set_xlabel("generation")
    ax.set_ylabel("species id (by birth)")
    scale = plt.cm.ScalarMappable(cmap=cmap, norm=plt.Normalize(0, biggest))
    fig.colorbar(scale, ax=ax, label="members", shrink=0.8)
    ax.set_title(f"Species lifespans\n{label} (seed {run.seed})", fontsize=10)
    ax.grid(alpha=0.2, axis="x")
    if drift_generations(run):
        ax.legend(fontsize=8, loc="upper right")
    return save(fig, path)


def figure_network(view: NetworkView, path: Path, label: str) -> Path:
    """A task end's top controller (``networks.NetworkView``): NEAT's network in columns by depth
    (``networks.columns``), or an MLP's distance to its reference per layer (without a reference:
    its parameters per layer)."""
    import matplotlib.pyplot as plt

    network = view.network
    if view.is_neat:
        fig, ax = plt.subplots(figsize=(9, 7), constrained_layout=True)
        stacked: dict[int, list[int]] = {}
        for key, column in columns(network).items():
            stacked.setdefault(column, []).append(key)
        where = {key: (column, (len(keys) - 1) / 2 - row) for column, keys in stacked.items()
                 for row, key in enumerate(keys)}
        biggest = max((abs(e.weight) for e in network.connections), default=1.0) or 1.0
        for edge in network.connections:
            (x0, y0), (x1, y1) = where[edge.source], where[edge.target]
            ax.plot([x0, x1], [y0, y1], color="tab:red" if edge.weight > 0 else "tab:blue",
                    linewidth=0.3 + 2.5 * abs(edge.weight) / biggest, linestyle="--" if edge.new else "-", alpha=0.6)
        for role, color in (("input", "0.6"), ("hidden", "#f0c850"), ("output", "#5aaaf9")):
            keys = [key for key, kind in network.nodes if kind == role]
            ax.scatter([where[k][0] for k in keys], [where[k][1] for k in keys], s=60, color=color,
                       edgecolor="black", zorder=3, label=f"{role} ({len(keys)})")
            for key in keys:
                ax.annotate(str(key), where[key], fontsize=6, ha="center", va="center", zorder=4)
        ax.set_axis_off()
        ax.legend(fontsize=8, loc="lower right")
    else:
        fig, ax = plt.subplots(figsize=(7, 4), constrained_layout=True)
        sizes = network.layer_sizes
        layers = [f"{a} -> {b}" for a, b in zip(sizes, sizes[1:])]
        if network.layer_distances:
            ax.bar(layers, network.layer_distances, color="tab:gray")
            ax.set_ylabel(f"Euclidean distance to {view.reference}")
        else:
            ax.bar(layers, [(a + 1) * b for a, b in zip(sizes, sizes[1:])], color="tab:gray")
            ax.set_ylabel("parameters (reference unknown)")
        ax.set_xlabel("layer (inputs -> outputs)")
    # lines as long as the figure is wide (a 9-point character is about 5.4 points wide): the ES's narrower
    # figure cut a 120-character line off at both sides
    width = int(fig.get_figwidth() * 72 / 5.4)
    title = "\n".join(textwrap.fill(text, width, break_on_hyphens=False) for text in (label, describe(view)))
    ax.set_title(title, fontsize=9)
    return save(fig, path)


CONFIG_COLORS = ("#1f77b4", "#ff7f0e", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#000000", "#17becf",
                  "#9467bd", "#d62728", "#2ca02c")
"""Line colours of configurations in overlays: the first ones avoid the task colours."""


def save(fig, path: Path) -> Path:
    import matplotlib.pyplot as plt

    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def slug(config: dict[str, Any], differences: list[str] = ()) -> str:
    """A file-name prefix: ``neat-red-green-red-reg11``, with a regulariser other than the family's
    default before lambda as in run names (``name_stem``: ``neat-red-green-red-wp-reg0.4``, at lambda
    > 0, where it is a setting), then what else sets the configuration apart (``config_differences``:
    ``openai-es-red-green-red-reg0-sigma-0.05``)."""
    regulariser = configuration_of(config).get("regulariser", DEFAULT_REGULARISER)
    stem = name_stem(config.get("algo"), config.get("schedule"), regulariser, config.get("reg", 0))
    text = "-".join([stem, *(item for item in differences if not item.startswith("regulariser="))])
    return re.sub(r"[^A-Za-z0-9.]+", "-", text).strip("-")


def plot_group(group: list[Run], species: dict[Path, list[tuple[int, int, int]] | None], out: Path, prefix: str,
               label: str, networks: dict[Path, list[tuple[int, NetworkView]]]) -> list[Path]:
    """Every figure of one configuration's runs, titled ``label`` (``species``: each run's
    species.csv rows, by path; ``networks``: its task ends' networks); returns the files written."""
    written = [figure_retention(group, "pop", out / f"{prefix}-retention-pop.png", label),
               figure_retention(group, "top", out / f"{prefix}-retention-top.png", label),
               figure_species(group, out / f"{prefix}-species.png", label)]
    for run in group:  # lifespans are per run: one figure per seed
        name = f"{prefix}-lifespans.png" if len(group) == 1 else f"{prefix}-lifespans-seed{run.seed}.png"
        written.append(figure_lifespans(run, species[run.path], out / name, label))
        for i, view in networks[run.path]:
            seed = "" if len(group) == 1 else f"-seed{run.seed}"
            task = re.sub(r"[^A-Za-z0-9.]+", "-", view.controller.removesuffix("-top"))
            written.append(figure_network(view, out / f"{prefix}-network-{task}{seed}.png", label))
    return [path for path in written if path is not None]


def plot_runs(paths, out: str | Path | None = None) -> list[Path]:
    """Figures for every run at or under ``paths``, grouped by configuration."""
    import matplotlib

    matplotlib.use("Agg")
    runs = [r for r in load_runs(paths) if r.metrics]
    if not runs:
        raise UserError("the runs have no metrics.csv rows yet: let a run write some generations first")
    for run in runs:
        check_task_looks(run)
    groups = group_runs(runs)
    target = Path(out) if out is not None else Path(os.path.commonpath([r.path.resolve() for r in runs]))
    species = {run.path: run.species_rows() for run in runs}  # read and checked before anything is drawn
    networks = {run.path: task_end_views(run.config, [phase.name for phase in schedule_of(run.config)],
                                         RunDir(run.path).read_controllers(), RunDir(run.path).controllers)
                for run in runs}
    check_writable(target)
    configs = [group[0].config for group in groups]
    written = []
    for group in groups:
        differences = config_differences(group[0].config, configs)
        written += plot_group(group, species, target, slug(group[0].config, differences),
                              describe_config(group[0].config, configs), networks)
    return written


def check_writable(folder: Path) -> None:
    """Refuse, before anything is drawn, an output folder that cannot be made or written to."""
    existing = next(p for p in (folder, *folder.parents) if p.exists())
    if not existing.is_dir():
        raise UserError(f"--out {folder}: {existing} is a file, not a folder: give a folder for the figures")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise UserError(f"--out {folder}: {existing} cannot be written to: give a folder you can write to")


# ------------------------------------------------------------------ comparison overlays

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


RETENTION_LOOKS = tuple((style, marker) for marker in _RANK_MARKERS
                        for style in ("-", ":", "-.", (0, (5, 1, 1, 1, 1, 1))))
"""The look (line style, marker) of each task's retention in ``compare``'s figure, in the
schedule's order of first appearance: four line styles (none of them the drift lines' dashes, so
that a legend entry names one kind of line), each later four again with a marker of their own; no
two alike. ``compare`` refuses a schedule with more tasks than there are looks."""


def _retention_look(task_rank: int, points: int) -> tuple[Any, str | None, int | None]:
    """Line style, marker and marker spacing of the retention of a schedule's ``task_rank``-th task
    over ``points`` generations: a measured point's dot on a short curve, a task's marker spaced."""
    style, marker = RETENTION_LOOKS[task_rank]
    if marker is None:
        return style, "o" if points < 40 else None, None
    return style, marker, max(1, points // 12)


def _overlay_retention(ax, groups: list[list[Run]], configs: list[dict[str, Any]], level: str) -> bool:
    """Each configuration's retention of every task while another is current (``level``: pop or
    top), one colour per configuration and one line style per task, so a red -> green -> red
    schedule shows red kept through green and green kept through red's return; False if none."""
    tasks = list(dict.fromkeys(groups[0][0].tasks))
    drawn = False
    for k, group in enumerate(groups):
        found = retention_by_task(group, level)
        label = _legend(group, configs)
        for rank, task in enumerate(tasks):
            if task in found:
                generations, values = found[task]
                style, marker, spacing = _retention_look(rank, len(generations))
                band(ax, generations, values, CONFIG_COLORS[k % len(CONFIG_COLORS)], style, label,
                     marker=marker, markevery=spacing)
                label, drawn = None, True
    if drawn:
        for task, (style, marker) in zip(tasks, RETENTION_LOOKS):
            ax.plot([], [], color="0.3", linestyle=style, marker=marker, label=f"retention of {task}")
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
    for group in sorted_groups(group_runs(runs)):
        config = group[0].config
        phases = schedule_of(config)
        by_schedule.setdefault(repr([(p.name, p.generations) for p in phases]), []).append(group)
    configs = [g[0].config for groups in by_schedule.values() for g in groups]
    for groups in by_schedule.values():  # before anything is drawn
        tasks = list(dict.fromkeys(groups[0][0].tasks))
        if len(tasks) > len(RETENTION_LOOKS):
            raise UserError(f"the schedule {groups[0][0].config.get('schedule')} has {len(tasks)} tasks, and the "
                            f"retention figure tells at most {len(RETENTION_LOOKS)} apart: compare runs of a "
                            "shorter schedule, or read their metrics.csv (docs/metrics.md)")
    written = []
    for index, groups in enumerate(by_schedule.values()):
        schedule = str(groups[0][0].config.get("schedule", ""))
        suffix = "" if len(by_schedule) == 1 else f"-{index}-" + re.sub(r"[^A-Za-z0-9]+", "-", schedule).strip("-")
        fig, ax = plt.subplots(figsize=(13, 5), constrained_layout=True)
        _overlay(ax, groups, configs, stack_current)
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
