"""The tables of ``compare``: the figures of each run (``run_metrics``: every number of its
summary.json, each labelled with the episodes it was scored on), their estimates over seeds
(``Estimate``: mean and 95% t-interval, ``analysis.statistics``), and the one writer
of markdown tables and comparison.csv rows that ``compare`` and the model-specific lambda share.

Episodes. Every figure names the episodes it was scored on: ``held-out`` (summary.json's
``held_out`` block: the exported controllers re-scored on the fixed held-out episodes, the same
for every run), ``selection-time`` (the top individual's score on the training episodes it was
selected on) or ``training`` (the population's best, and an ES centre's, on the training
episodes; no held-out counterpart).

Curve figures. Besides the task-end figures, three are read off the per-generation curves
(``CURVE_SECTIONS``; none has a held-out counterpart, so every table shows them whatever
``--episodes`` says): the stability gap of summary.json's ``stability_gap`` block,
``gap_<level> <task> after switch to phase <k>`` (``gap_pop``: training, ``gap_top``:
selection-time, ``gap_centre``: training), and the forward transfer area against a from-scratch
run of the same seed, ``FT_area phase <k> (<task>)`` and their mean ``FT_area`` (training: the
population's best), and the phase start, the current task's score in the first generation of
each phase k >= 1, ``start_<level> phase <k> (<task>)`` (``start_pop``: training, ``start_top``:
selection-time); ``compare`` computes the last two from the runs' metrics.csv and passes them in
as ``extra`` figures.
"""
from __future__ import annotations

import csv
import itertools
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..metrics import HELD_OUT_LEVELS
from ..runs import Run
from ..summary_json import SummaryLayout
from .statistics import seed_order, t_interval

HELD_OUT, SELECTION_TIME, TRAINING = "held-out", "selection-time", "training"
"""The kinds of episodes a figure was scored on (the module docstring says which is which)."""


CONTROLLERS = ("top", *(level for level in HELD_OUT_LEVELS.values() if level != "top"))
"""The deployed controllers in table order: the top individual, an ES centre and best sample."""


CONTROLLER_NAMES = {"top": "top individual", "centre": "centre (ES)", "best_sample": "best sample (ES)"}


TRAINING_KIND = {"top": SELECTION_TIME, "centre": TRAINING}
"""The kind of a controller's training-episode figures (none for the best sample: only held-out)."""


CSV_COLUMNS = ["configuration", "algo", "reg", "schedule", "statistic", "episodes", "metric", "baseline", "n",
               "n_baseline", "mean", "ci_low", "ci_high", "p", "p_method", "effect_size", "seeds_for_80_power", "p_holm",
               "seeds", "values"]


def is_nan(value) -> bool:
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
                 if v is not None and not is_nan(v)]
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


Figure = tuple[str, Key, float | None]
"""One run's figure: (its section, its key, its value)."""


STABILITY_GAP, FT_AREA, PHASE_START = "stability gap", "forward transfer area", "phase start"
SIZE = "size"
"""The section of a run's controller sizes and evaluation budget (``compare.size_figures``)."""
CURVE_SECTIONS = (STABILITY_GAP, FT_AREA, PHASE_START)
"""The sections of the figures read off per-generation curves (the module docstring)."""


GAP_KINDS = {"pop": TRAINING, "top": SELECTION_TIME, "centre": TRAINING}
"""The episodes of each level's stability gap: those of its retention figures (R_pop, R_top, R_centre)."""


def gap_name(level: str, task: str, switch: int) -> str:
    """The metric name of a stability gap: ``gap_top red after switch to phase 1``."""
    return f"gap_{level} {task} after switch to phase {switch}"


def ft_area_name(phase: int | None = None, task: str | None = None) -> str:
    """The metric name of phase ``phase``'s forward transfer area, ``FT_area phase 1 (green)``, or
    of their mean over the phases, ``FT_area`` (no phase)."""
    return "FT_area" if phase is None else f"FT_area phase {phase} ({task})"


START_KINDS = {"pop": TRAINING, "top": SELECTION_TIME}
"""The episodes of each level's score in a phase's first generation (``metrics.phase_start_scores``)."""


def start_name(level: str, phase: int, task: str) -> str:
    """The metric name of phase ``phase``'s first-generation score: ``start_top phase 2 (red)``."""
    return f"start_{level} phase {phase} ({task})"


def run_metrics(summary: dict[str, Any]) -> list[Figure]:
    """(section, (kind, metric name), value) of one run's summary.json, in table order: the
    training-episode figures (the population's: training; the top individual's: selection-time;
    an ES centre's: training), then those of the ``held_out`` block (held-out), then the stability
    gaps (``gap_name``; none where the summary has no ``stability_gap`` block), then the wall time
    (kind ``""``)."""
    out: list[Figure] = []

    def add(kind: str, part: dict[str, Any], current: dict[str, str], forgetting: dict[str, str],
            transfer: list[str]) -> None:
        phases = part.get(SummaryLayout.PHASES, [])
        for name, key in current.items():
            for i, (task, value) in enumerate(zip(phases, part.get(key) or [])):
                out.append(("current", (kind[name], f"{name} phase {i} ({task})"), value))
        for row in part.get(SummaryLayout.FORGETTING, []):
            where = f"{row['task']} at end of phase {row['at_end_of']}"
            for key, kind_of in forgetting.items():
                if key in row:
                    out.append(("forgetting", (kind_of, f"{key} {where}"), row[key]))
        for name in transfer:
            if name in part:
                out.append(("transfer", (kind[name], name), part[name]))

    train = {"C": TRAINING, "C_top": SELECTION_TIME, "C_centre": TRAINING,
             **{SummaryLayout.transfer(m, level): kind for m in SummaryLayout.TRANSFER for level, kind in
                (("pop", TRAINING), ("top", SELECTION_TIME))}}
    add(train, summary, {"C": SummaryLayout.CURRENT, "C_top": SummaryLayout.CURRENT_TOP,
                         "C_centre": SummaryLayout.CENTRE_CURRENT},
        {"R_pop": TRAINING, "F_pop": TRAINING, "R_top": SELECTION_TIME, "F_top": SELECTION_TIME,
         "R_centre": TRAINING, "F_centre": TRAINING},
        [SummaryLayout.transfer(m, level) for level in ("pop", "top") for m in SummaryLayout.TRANSFER])
    held = summary.get(SummaryLayout.HELD_OUT)
    if held:
        levels = [level for level in CONTROLLERS if f"current_{level}" in held]
        transfer = [SummaryLayout.transfer(m, level) for level in levels for m in SummaryLayout.TRANSFER]
        add({name: HELD_OUT for name in [f"C_{level}" for level in levels] + transfer}, held,
            {f"C_{level}": f"current_{level}" for level in levels},
            {f"{m}_{level}": HELD_OUT for level in levels for m in ("R", "F")}, transfer)
    for entry in summary.get(SummaryLayout.STABILITY_GAP) or []:
        for level, kind in GAP_KINDS.items():
            if f"gap_{level}" in entry:
                out.append((STABILITY_GAP, (kind, gap_name(level, entry["task"], entry["after_switch_to"])),
                            entry[f"gap_{level}"]))
    if summary.get(SummaryLayout.WALL_TIME) is not None:
        out.append(("cost", ("", "wall time (min)"), summary[SummaryLayout.WALL_TIME] / 60))
    return out


Estimates = dict[Key, tuple[str, Estimate]]
"""(kind, metric name) -> (its section in ``run_metrics``, its estimate over seeds)."""


def estimates(runs: list[tuple[Any, dict[str, Any]]], extra: list[list[Figure]] | None = None) -> Estimates:
    """Every figure of ``run_metrics`` over ``runs``, (seed, summary.json dict) pairs, and of
    ``extra``: per run, in the same order, figures that its summary.json does not hold."""
    per_metric: dict[Key, tuple[str, list, list]] = {}
    for (seed, summary), more in zip(runs, extra if extra is not None else [[] for _ in runs], strict=True):
        for section_name, key, value in [*run_metrics(summary), *more]:
            _, seeds, values = per_metric.setdefault(key, (section_name, [], []))
            seeds.append(seed)
            values.append(value)
    return {key: (section_name, Estimate.of(values, seeds)) for key, (section_name, seeds, values) in per_metric.items()}


def group_estimates(group: list[Run], extra: dict[Path, list[Figure]] | None = None) -> Estimates:
    """``estimates`` of a configuration's runs; ``extra``: figures by run directory."""
    return estimates([(run.seed, run.summary) for run in group], [(extra or {}).get(run.path, []) for run in group])


def curve_outcomes(found: Estimates) -> list[Key]:
    """The figures of ``found`` read off per-generation curves (``CURVE_SECTIONS``), in order."""
    return [key for key, (section_name, _) in found.items() if section_name in CURVE_SECTIONS]


def has_figures(found: Estimates, level: str, kind: str) -> bool:
    prefix = f"C_{level} phase "
    return any(k == kind and name.startswith(prefix) and est.values for (k, name), (_, est) in found.items())


def shown_controllers(founds: list[Estimates], episodes: str) -> list[tuple[str, str]]:
    """(controller, kind) whose figures the tables show for configurations whose estimates are
    ``founds`` (all of them must have the figures), in order: with ``episodes`` ``held-out``
    the held-out ones where present, else the training ones; ``training``: the training ones;
    ``both``: both."""
    held = [(level, HELD_OUT) for level in CONTROLLERS if all(has_figures(f, level, HELD_OUT) for f in founds)]
    trained = [(level, kind) for level, kind in TRAINING_KIND.items() if all(has_figures(f, level, kind) for f in founds)]
    if episodes == "training":
        return trained
    if episodes == "both":
        return held + trained
    return held or trained


def table(header: list[str], rows: list[list[Any]]) -> list[str]:
    """A markdown table's lines."""
    return ["| " + " | ".join(header) + " |", "|" + "---|" * len(header),
            *("| " + " | ".join(map(str, row)) + " |" for row in rows)]


def cell(found: Estimates, key: Key) -> str:
    return str(found[key][1]) if key in found else "-"


def present(found: Estimates, keys: list[Key]) -> bool:
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
                       [[where, *(cell(found, (kind, f"{m} {where}")) for _, (kind, m) in columns)] for where in phases])
        lines.append("")
    wheres = [name[len("R_pop "):] for (kind, name), (sec, _) in found.items()
              if sec == "forgetting" and name.startswith("R_pop ")]
    if wheres:
        columns = [(f"{m} (training)", (TRAINING, m)) for m in ("R_pop", "F_pop")]
        columns += [(f"{m}_{level} ({kind})", (kind, f"{m}_{level}")) for level, kind in shown for m in ("R", "F")]
        columns = [(heading, (kind, m)) for heading, (kind, m) in columns
                   if present(found, [(kind, f"{m} {where}") for where in wheres])]
        lines += table(["task at end of phase", *(heading for heading, _ in columns)],
                       [[where, *(cell(found, (kind, f"{m} {where}")) for _, (kind, m) in columns)] for where in wheres])
        lines.append("")
    levels = [("pop", TRAINING), *shown]
    rows = [[f"{level} ({kind})", *(cell(found, (kind, f"{m}_{level}")) for m in ("ACC", "BWT", "FWT"))]
            for level, kind in levels if present(found, [(kind, f"{m}_{level}") for m in ("ACC", "BWT", "FWT")])]
    if rows:
        lines += table(["controller (episodes)", "ACC", "BWT", "FWT"], rows)
        lines.append("")
    lines += _curve_tables(found)
    lines += _size_table(found)
    return "\n".join(lines)


def size_name(what: str, phase: int | None = None, task: str | None = None) -> str:
    """The metric name of a size: ``connections of the top at end of phase 1 (green)``, or of the
    run as a whole (``evaluations per generation``)."""
    return what if phase is None else f"{what} of the top at end of phase {phase} ({task})"


def top_is_centre_name(phase: int, task: str) -> str:
    """The metric name of an ES's share of a phase's generations whose top individual is the centre."""
    return f"% of the generations of phase {phase} ({task}) whose top scores as the centre"


def _size_table(found: Estimates) -> list[str]:
    """The controllers' sizes and the evaluation budget of ``found``, where it has them."""
    rows = [[name, str(estimate)] for (_, name), (sec, estimate) in found.items() if sec == SIZE]
    if not rows:
        return []
    return ["Controllers and budget: the exported top controllers' size (a NEAT genome's hidden and output "
            "nodes and enabled connections; an MLP's parameters), the controllers times training episodes "
            "each generation and, for an ES, how often the top individual is the centre (the noise-free mean, "
            "or a sample that scores exactly as it does) rather than a sample.", "", *table(["what", "value"], rows), ""]


def _levels_table(found: Estimates, section_name: str, stem: str, kinds: dict[str, str], row_heading: str,
                  intro: str) -> list[str]:
    """A table of ``found``'s figures of ``section_name`` named ``<stem>_<level> <where>``: a row
    per ``where`` (those the population has), a column per level of ``kinds`` (level -> its
    episodes) that has any; nothing where there are none."""
    prefix = f"{stem}_pop "
    wheres = [name[len(prefix):] for (_, name), (sec, _) in found.items()
              if sec == section_name and name.startswith(prefix)]
    if not wheres:
        return []
    columns = [(level, kind) for level, kind in kinds.items()
               if present(found, [(kind, f"{stem}_{level} {where}") for where in wheres])]
    return [intro, "", *table([row_heading, *(f"{stem}_{level} ({kind})" for level, kind in columns)],
                              [[where, *(cell(found, (kind, f"{stem}_{level} {where}")) for level, kind in columns)]
                               for where in wheres]), ""]


def _curve_tables(found: Estimates) -> list[str]:
    """The stability gaps (a row per earlier task and switch, a column per level), the forward
    transfer areas (a row per phase, then their mean) and the phase starts (a row per phase, a
    column per level) of ``found``, where it has them."""
    # every entry of the stability gap block has the population's gap
    lines = _levels_table(found, STABILITY_GAP, "gap", GAP_KINDS, "earlier task after the switch",
                          "Stability gap: an earlier task's score at the switch minus its lowest retention in the "
                          "first generations after it (positive: a dip).")
    phases = [name for (_, name), (sec, _) in found.items() if sec == FT_AREA and name != ft_area_name()]
    if phases:
        rows = [[name[len(ft_area_name()) + 1:], cell(found, (TRAINING, name))] for name in phases]
        if (TRAINING, ft_area_name()) in found:
            rows.append(["mean over phases >= 1", cell(found, (TRAINING, ft_area_name()))])
        lines += ["Forward transfer area: mean over a phase's generations of C minus C of the from-scratch run "
                  "of the same seed.", "", *table(["phase", "FT_area (training)"], rows), ""]
    return lines + _levels_table(found, PHASE_START, "start", START_KINDS, "phase",
                                 "Phase start: the current task's score in the phase's first generation, before "
                                 "any selection on it.")


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
            rows = [[c.label, c.n, kind, *(cell(c.found, (kind, name)) for _, name in outcomes(list(phases), level))]
                    for c in mine for shown, kind in shown_controllers([c.found], episodes) if shown == level]
            if rows:
                lines += [f"The paper's table ({drift}), the {CONTROLLER_NAMES[level]}: C on its own task at the "
                          f"task's end, the first task's retention R and forgetting F at the end of the second; "
                          "mean over seeds [95% t-interval]; episodes: held-out or selection-time (the training "
                          "episodes it was selected on).", "",
                          *table(["configuration", "n seeds", "episodes",
                                  *(heading for heading, _ in outcomes(list(phases), level))], rows), ""]
        columns = outcomes(list(phases), "pop")
        rows = [[c.label, c.n, *(cell(c.found, (TRAINING, name)) for _, name in columns),
                 cell(c.found, ("", "wall time (min)"))] for c in mine]
        lines += [f"The paper's table ({drift}), the population (its best, on the training episodes: no "
                  "held-out counterpart) and the wall time per run; mean over seeds [95% t-interval].", "",
                  *table(["configuration", "n seeds", *(heading for heading, _ in columns),
                          "wall time per run (min)"], rows), ""]
        lines += _budget_table(mine, list(phases))
    return lines


SIZE_MEASURES = ("nodes", "connections", "parameters")
"""What ``algorithms.controller_size`` counts: a NEAT genome's nodes and connections, an MLP's parameters."""


def _budget_table(configurations: list[Configuration], phases: list[str]) -> list[str]:
    """One line per configuration: its evaluations per generation and the size of the top
    controller exported at each task end, in its family's measure (``size_figures``), so that the
    families' rows of the paper's tables are read with what their controllers and budgets are;
    nothing where no configuration has these figures."""
    def sizes(found: Estimates, phase: int, task: str) -> str:
        parts = [f"{what} {found[key][1]}" for what in SIZE_MEASURES
                 if (key := ("", size_name(what, phase, task))) in found]
        return "; ".join(parts) or "-"

    if not any(sec == SIZE for c in configurations for sec, _ in c.found.values()):
        return []
    rows = [[c.label, c.n, cell(c.found, ("", size_name("evaluations per generation"))),
             *(sizes(c.found, i, task) for i, task in enumerate(phases))] for c in configurations]
    return [f"Controllers and budget ({' -> '.join(phases)}): the controllers times training episodes each "
            "generation, and the size of the top controller exported at each task end (a NEAT genome's hidden and "
            "output nodes and enabled connections; an MLP's parameters); mean over seeds [95% t-interval].", "",
            *table(["configuration", "n seeds", "evaluations per generation",
                    *(f"top at end of phase {i} ({task})" for i, task in enumerate(phases))], rows), ""]


def csv_rows(label: str, config: dict[str, Any], found: Estimates, reg: Any = None) -> list[dict[str, Any]]:
    """comparison.csv's mean rows of one configuration (``reg``: what its reg column says, default its lambda)."""
    return [{**csv_head(label, config, reg), "statistic": "mean", "episodes": kind, "metric": name,
             "n": len(estimate.values), "mean": estimate.mean, "ci_low": estimate.low, "ci_high": estimate.high,
             "seeds": estimate.seeds, "values": estimate.values}
            for (kind, name), (_, estimate) in found.items()]


def csv_head(label: str, config: dict[str, Any], reg: Any = None) -> dict[str, Any]:
    return {"configuration": label, "algo": config.get("algo"), "reg": config.get("reg") if reg is None else reg,
            "schedule": config.get("schedule")}


OVERVIEW = ("ACC_pop", "BWT_pop", "FWT_pop", "ACC_top", "BWT_top", "FWT_top", "episodes (top)")


def overview_row(label: str, n: str, found: Estimates, episodes: str) -> list[str]:
    """A configuration's overview line: the population's ACC/BWT/FWT (training) and the top
    individual's, of the first kind ``shown_controllers`` shows."""
    kinds = [kind for level, kind in shown_controllers([found], episodes) if level == "top"]
    kind = kinds[0] if kinds else SELECTION_TIME
    return [label, n, *(cell(found, (TRAINING, f"{m}_pop")) for m in ("ACC", "BWT", "FWT")),
            *(cell(found, (kind, f"{m}_top")) for m in ("ACC", "BWT", "FWT")), kind]


def seed_count(group: list[Run]) -> str:
    """A configuration's seeds for the tables: ``5``, or ``5 (2 unfinished)`` while some of its
    runs have not ended every task (their later metrics are missing, so a row's cells can rest
    on fewer seeds than its count)."""
    unfinished = sum(not run.finished for run in group)
    return f"{len(group)} ({unfinished} unfinished)" if unfinished else str(len(group))


def sorted_groups(groups: list[list[Run]]) -> list[list[Run]]:
    return sorted(groups, key=lambda g: (str(g[0].config.get("schedule")), str(g[0].config.get("algo")),
                                         float(g[0].config.get("reg") or 0), g[0].key))


def csv_value(value: Any) -> Any:
    """A number as comparison.csv writes it: exactly (``repr``), ``inf``, or empty for none/NaN."""
    if value is None or is_nan(value):
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
            writer.writerow({**{k: csv_value(row.get(k)) for k in CSV_COLUMNS},
                             "seeds": " ".join(str(s) for s in row.get("seeds", ()) if s is not None),
                             "values": " ".join(repr(float(v)) for v in row.get("values", ()))})
    return path
