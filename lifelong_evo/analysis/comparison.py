"""The comparison of configurations over seeds, each against its baseline: what ``compare``
prints and writes, computed here and usable from Python without the command line.

``comparison(paths, ...)`` finds every run directory (config.json + summary.json) at or under
``paths`` (so a sweep folder works), groups the runs by configuration (``runs.group_runs``: runs
that differ only in the seed, the speed settings and the output settings of ``RunConfig``, or at
lambda 0 in the regulariser's options, are one) and returns a ``Comparison``: its ``markdown`` is
what ``compare`` prints, the same text for the same runs and options. ``write_report`` writes it,
and ``figures.overlay_figures`` draws the figures, into a folder (``compare``'s ``--out``):

``comparison.md``    an overview (one line per configuration: ACC/BWT/FWT); per schedule of at
                     least two tasks the paper's tables, one line per configuration: one table per
                     deployed controller (the top individual; for an ES also the centre and the
                     best sample: the first task's C, the second's, the first task's retention R
                     and forgetting F at the second's end, the third task's C, ACC/BWT/FWT) and one
                     for the population (its best: C, R_pop, F_pop, ACC_pop/BWT_pop/FWT_pop, the
                     wall time per run), and one of controllers and budget (evaluations per
                     generation, the top controller's size at each task end); then each
                     configuration against its baseline (paired
                     by seed within an algorithm, or Welch across algorithms and where they
                     share fewer than two seeds: difference, 95%
                     interval, p, effect size, seeds for 80% power, per outcome of the paper's
                     tables and per curve figure both have: stability gaps, forward transfer
                     areas, phase starts); then, where rehearsal ran beside fine-tuning, each
                     configuration compared with that fine-tuning placed between the two on the
                     first task's retention (``placements``, ``statistics.position``); then per
                     configuration its tables in full: C per phase, R and F at each later task
                     end, ACC/BWT/FWT, and where the runs have them the stability gaps, forward
                     transfer areas and phase starts (below). Values are means over seeds with their
                     95% t-interval (one seed: the value alone); ``analysis.statistics`` has
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

Episodes. Every figure names the episodes it was scored on (held-out, selection-time or
training: ``analysis/tables.py``). ``--episodes held-out`` (the default) shows the controllers'
held-out figures where the runs have the block and their selection-time ones elsewhere;
``training`` shows the selection-time ones; ``both`` shows both. The population's figures are
always training ones. comparison.csv holds every kind whatever ``--episodes`` says.

Baselines. Without ``--baseline`` each configuration with a regulariser or a baseline setting
(rehearsal, joint, from scratch, reference_every, archive) is compared with fine-tuning (lambda 0 without
them) of the same algorithm and otherwise the same settings, where such runs exist.
``--baseline KEY=VALUE,...`` names one configuration per schedule by its settings
(``baseline_settings``: ``algo``, ``reg``, ``schedule``, the other settings of ``RunConfig``, the
algorithm's options by name, the environment's as ``env.NAME``) and compares every other
configuration of that schedule with it; naming none, or several of one schedule, is a UserError.

``compare_table(paths)`` returns ``(rows, markdown)``; ``write_comparison`` writes the tables
(``sweep`` uses it for its own directory).

Curve figures (``analysis/tables.py``, Curve figures). The stability gap comes from summary.json's
``stability_gap`` block (``metrics.stability_gap``); runs without it have no such cells. The
forward transfer area (``metrics.forward_transfer_area``) needs a from-scratch partner: a run with
``from_scratch`` true among the runs compared, of the same configuration apart from
``SCRATCH_APART`` and of the same seed (``scratch_partners``). Every run that is no from-scratch
run and has one gets ``FT_area phase <k> (<task>)`` for each phase k >= 1 that both have ended,
and their mean ``FT_area`` once both have ended every phase, from the two metrics.csv files
(with several partners of one seed, the mean of their areas). Its configuration shows the mean
over the seeds that have a partner. Every run with metrics.csv gets its phase starts,
``start_pop`` and ``start_top phase <k> (<task>)`` (``metrics.phase_start_scores``).

Model-specific lambda ("m.s. reg"): where a configuration ran several lambdas, the lambda per
seed that ``analysis/model_specific.py`` chooses (on the training episodes, or with
``--choose-lambda-on held-out`` on the held-out ones), reported as a configuration of its own; with
``--per-seed-lambda``, beside it the lambdas given per seed (``reg=given``). The
tables and their figures are ``analysis/tables.py``, the statistics ``analysis/statistics.py``,
the overlay figures ``analysis/figures.py``.
"""
from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from ..checkpoint import atomic_write_bytes
from ..errors import UserError
from algorithms import controller_size

from ..json_files import write_json
from ..metrics import controller_key, forward_transfer_area, phase_start_scores
from ..rundir import RunDir
from ..runs import BASELINES_OFF, Run, config_key, configuration_of, describe_config, group_runs, load_runs
from ..schedule import schedule_of
from ..summary_json import SummaryLayout
from .model_specific import (CRITERION, given_choices, held_out_selection_score, model_specific_label,
                             model_specific_report, select_model_specific)
from .statistics import Difference, difference, holm, position, seed_order
from .tables import (
    CONTROLLERS,
    FT_AREA,
    HELD_OUT,
    OVERVIEW,
    PHASE_START,
    SELECTION_TIME,
    SIZE,
    STABILITY_GAP,
    START_KINDS,
    TRAINING,
    TRAINING_KIND,
    Configuration,
    Figure,
    Key,
    csv_head,
    csv_rows,
    curve_outcomes,
    ft_area_name,
    group_estimates,
    is_nan,
    outcomes,
    overview_row,
    paper_tables,
    section,
    seed_count,
    shown_controllers,
    size_name,
    sorted_groups,
    start_name,
    table,
    top_is_centre_name,
    write_csv,
)

EPISODES_CHOICES = ("held-out", "training", "both")
"""``--episodes``: which figures of the deployed controllers the tables show."""


def baseline_settings(config: dict[str, Any]) -> dict[str, Any]:
    """The settings ``--baseline`` matches, by name: RunConfig's configuration settings (``algo``,
    ``reg``, ``schedule``, ``generations``, ...), the algorithm's options by their own names
    (``genetics``, ``sigma``, ``importance``) and the environment's as ``env.NAME``
    (``runs.configuration_of``: as resolved, regulariser options dropped at lambda 0)."""
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


FINE_TUNING = {"reg": 0.0, **BASELINES_OFF}
"""The settings of fine-tuning, every configuration's default baseline: no regulariser and none of
the baselines of docs/metrics.md (the values as config.json writes them)."""


KINDS = (HELD_OUT, SELECTION_TIME, TRAINING)
"""The kinds of episodes a figure is scored on."""
HolmFamily = tuple[tuple[str, str], ...]
"""(kind of episodes, outcome) pairs tested as one family (``--holm``)."""


def parse_holm(given: list[str] | None) -> HolmFamily:
    """``--holm KIND:OUTCOME`` (each given once or more) as (kind, outcome) pairs."""
    family = []
    for item in given or []:
        kind, colon, outcome = item.partition(":")
        if not colon or kind not in KINDS or not outcome.strip():
            raise UserError(f"--holm {item!r} is not KIND:OUTCOME with KIND one of {', '.join(KINDS)}: name an "
                            "outcome as the differences tables do, e.g. --holm 'held-out:green C_top'")
        family.append((kind, outcome.strip()))
    if len(set(family)) != len(family):
        raise UserError("--holm names an outcome twice: give each outcome of the family once")
    return tuple(family)


def _check_family(family: HolmFamily, configurations: list[Configuration], baselines: list[int | None]) -> None:
    """UserError where an outcome of ``family`` is in no difference table: a misspelt one would
    otherwise leave the family smaller than stated, and its p-values too small."""
    present = {(kind, heading) for c, b in zip(configurations, baselines) if b is not None
               for _, heading, (kind, _), _ in differences(c, configurations[b])}
    missing = [f"{kind}:{heading}" for kind, heading in family if (kind, heading) not in present]
    if missing:
        raise UserError(f"--holm {', '.join(missing)}: no difference table has that outcome; name outcomes as the "
                        "tables do (outcome column, with its episodes), e.g. --holm 'held-out:green C_top'")


def _p(value: float | None) -> str:
    return "-" if value is None else f"{value:.3g}"


def choose_baselines(configurations: list[Configuration], items: dict[str, str] | None) -> list[int | None]:
    """The index of each configuration's baseline in ``configurations`` (None: none, or itself).
    Without ``items``: fine-tuning (``FINE_TUNING``: lambda 0 and no baseline setting) of the
    same algorithm and otherwise the same settings, for a configuration with a regulariser or a
    baseline setting. With ``items`` (``--baseline``): in each schedule, the one
    configuration whose ``baseline_settings`` has every item; UserError where no configuration
    matches, or several of one schedule do."""
    if items is None:
        def fine_tuned(config: dict[str, Any]) -> str:
            return config_key({**config, **FINE_TUNING})

        keys = [config_key(c.config) for c in configurations]
        fine_tuning = {fine_tuned(c.config): i for i, (c, key) in enumerate(zip(configurations, keys))
                       if key == fine_tuned(c.config)}
        return [None if key == fine_tuned(c.config) else fine_tuning.get(fine_tuned(c.config))
                for c, key in zip(configurations, keys)]
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


def differences(config: Configuration, baseline: Configuration, family: HolmFamily = ()
                ) -> list[tuple[str | None, str, Key, Difference]]:
    """(controller, heading, (kind, metric name), configuration minus baseline) for each outcome both have,
    of every kind: the paper's figures (``outcomes``) of each controller, then of the population,
    then the curve figures (``curve_outcomes``: stability gaps, forward transfer areas; controller
    None, as no ``--episodes`` choice hides them). Paired by seed where the runs are ``pairable``
    and share at least two seeds, else Welch (``statistics.difference``). The outcomes of
    ``family`` ((kind, outcome) pairs, ``--holm``) get their Holm-Bonferroni p (``p_holm``) over
    those of them this pair of configurations has."""
    same_algo = pairable(config, baseline)
    found: list[tuple[str | None, str, Key, Difference]] = []
    kinds = [*((level, HELD_OUT) for level in CONTROLLERS), *TRAINING_KIND.items(), ("pop", TRAINING)]
    for level, kind in kinds:
        for heading, name in outcomes(config.phases, level):
            mine, theirs = config.found.get((kind, name)), baseline.found.get((kind, name))
            if mine and theirs and mine[1].values and theirs[1].values:
                found.append((level, heading, (kind, name),
                              difference(mine[1].by_seed(), theirs[1].by_seed(), same_algo)))
    for key in curve_outcomes(config.found):
        mine, theirs = config.found[key], baseline.found.get(key)
        if theirs and mine[1].values and theirs[1].values:
            found.append((None, key[1], key, difference(mine[1].by_seed(), theirs[1].by_seed(), same_algo)))
    tested = [i for i, (_, heading, (kind, _), d) in enumerate(found) if (kind, heading) in family and d.p is not None]
    for i, adjusted in zip(tested, holm([found[i][3].p for i in tested])):
        found[i] = (*found[i][:3], replace(found[i][3], p_holm=adjusted))
    return found


def format_difference(d: Difference) -> list[str]:
    """The cells of a differences-table row: difference [interval], p, effect size, n, seeds for 80% power."""
    interval = "" if is_nan(d.low) else f" [{d.low:+.2f}, {d.high:+.2f}]"
    p = "-" if d.p is None else f"{d.p:.3g}" + ("" if d.p_exact or d.test == "Welch" else " (random flips)")
    effect = "-" if d.effect is None else f"{d.effect:+.2f}"
    n = str(d.n) if d.test == "paired" else f"{d.n} + {d.n_baseline} (Welch)"
    power = "-" if d.seeds_for_power is None else ("inf" if math.isinf(d.seeds_for_power) else str(d.seeds_for_power))
    return [f"{d.mean:+.2f}{interval}", p, effect, n, power]


def differences_section(config: Configuration, baseline: Configuration, episodes: str, family: HolmFamily = ()
                        ) -> str:
    """The markdown of ``config`` against ``baseline``: a row per outcome shown (the population's,
    training; the controllers' kinds per ``shown_controllers`` of both), and the seeds left out."""
    shown = {("pop", TRAINING), *shown_controllers([config.found, baseline.found], episodes)}
    rows = [[heading, kind, *format_difference(d)] + ([_p(d.p_holm)] if family else [])
            for level, heading, (kind, _), d in differences(config, baseline, family)
            if level is None or (level, kind) in shown]
    seeds = {run.seed for run in config.runs}
    theirs = {run.seed for run in baseline.runs}
    paired = pairable(config, baseline) and len(seeds & theirs) >= 2
    lines = [f"### {config.label} against {baseline.label}", ""]
    if paired:
        lines.append("Paired by seed: per outcome the mean of the per-seed differences (this configuration minus "
                     "the baseline) with its 95% t-interval, the exact two-sided sign-flip permutation p-value (never "
                     f"below 2/2^n with n pairs: {2 / 2 ** len(seeds & theirs):.3g} with {len(seeds & theirs)}), "
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
    holm_column = ["p (Holm)"] if family else []
    lines += ["", *table(["outcome", "episodes", "difference [95% interval]", "p", effect, "n seeds",
                          "seeds for 80% power", *holm_column], rows), ""]
    if family:
        lines += [f"p (Holm): Holm-Bonferroni over the {len(family)} outcomes named by --holm "
                  f"({'; '.join(f'{heading}, {kind}' for kind, heading in family)}).", ""]
    return "\n".join(lines)


def difference_rows(config: Configuration, baseline: Configuration, family: HolmFamily = ()) -> list[dict[str, Any]]:
    """comparison.csv's rows of ``config`` against ``baseline``: every outcome of every kind."""
    rows = []
    for _, _, (kind, name), d in differences(config, baseline, family):
        rows.append({**csv_head(config.label, config.config), "statistic": f"{d.test} difference", "episodes": kind,
                     "metric": name, "baseline": baseline.label, "n": d.n, "n_baseline": d.n_baseline,
                     "mean": d.mean, "ci_low": d.low, "ci_high": d.high, "p": d.p,
                     "p_method": ("Welch t-test" if d.test == "Welch" else
                                  "exact sign-flip" if d.p_exact else "random sign-flip"),
                     "effect_size": d.effect, "seeds_for_80_power": d.seeds_for_power, "p_holm": d.p_holm,
                     "seeds": d.seeds, "values": d.differences})
    return rows


@dataclass(frozen=True)
class Placed:
    """A configuration's position between fine-tuning and rehearsal on one outcome (``placements``)."""

    config: Configuration
    rehearsal: Configuration
    level: str
    heading: str
    key: Key
    difference: Difference
    """The configuration minus fine-tuning."""
    scale: Difference
    """Rehearsal minus fine-tuning."""
    position: float | None
    seeds: tuple[Any, ...]
    """The seeds ``position`` is computed on: those all three configurations ran."""

    @property
    def established(self) -> bool:
        """Whether rehearsal's 95% interval against fine-tuning excludes 0 (the baselines' rule)."""
        return self.scale.low > 0 or self.scale.high < 0  # NaN (one pair) compares False


def rehearsal_scales(configurations: list[Configuration], baselines: list[int | None]) -> dict[int, list[int]]:
    """Fine-tuning's index -> the configurations compared with it that differ from it only in
    rehearsal: each sets a scale from fine-tuning (0) to itself (1)."""
    off = BASELINES_OFF["rehearsal"]
    scales: dict[int, list[int]] = {}
    for i, (c, b) in enumerate(zip(configurations, baselines)):
        if b is None or c.config.get("rehearsal", off) == off:
            continue
        base = configurations[b].config
        if config_key(base) == config_key({**base, **FINE_TUNING}) and \
                config_key({**c.config, "rehearsal": off}) == config_key(base):
            scales.setdefault(b, []).append(i)
    return scales


def placements(configurations: list[Configuration], baselines: list[int | None]) -> list[Placed]:
    """Each configuration compared with fine-tuning, other than a scale's own rehearsal, placed on
    every rehearsal scale of that fine-tuning (``rehearsal_scales``), on the first task's retention
    at the end of the second (``R_<controller>``) of every controller and kind of episodes the
    three have: ``statistics.position`` of their paired differences from fine-tuning."""
    placed = []
    for fine, scales in rehearsal_scales(configurations, baselines).items():
        base = configurations[fine]
        for r in scales:
            theirs = {key: d for _, _, key, d in differences(configurations[r], base)}
            for i, c in enumerate(configurations):
                if baselines[i] != fine or i in scales:
                    continue
                for level, heading, key, d in differences(c, base):
                    if level is not None and heading == f"{c.phases[0]} R_{level}" and key in theirs:
                        value, seeds = position(d, theirs[key])
                        placed.append(Placed(c, configurations[r], level, heading, key, d, theirs[key], value, seeds))
    return placed


def positions_section(placed: list[Placed], episodes: str) -> list[str]:
    """The markdown of ``placements``: the controllers and kinds of episodes the tables show
    (``shown_controllers``), and the population's (training)."""
    rows = []
    for p in placed:
        shown = {("pop", TRAINING), *shown_controllers([p.config.found, p.rehearsal.found], episodes)}
        if (p.level, p.key[0]) in shown:
            value = "-" if p.position is None else f"{p.position:.2f}"
            rows.append([p.config.label, p.rehearsal.label, p.heading, p.key[0], format_difference(p.difference)[0],
                         format_difference(p.scale)[0], "yes" if p.established else "no", value, str(len(p.seeds))])
    if not rows:
        return []
    return ["## Between fine-tuning and rehearsal", "",
            "Where each configuration compared with fine-tuning stands on the first task's retention at the end "
            "of the second (R), between fine-tuning (0) and rehearsal of otherwise the same settings (1): the mean "
            "of its paired differences from fine-tuning over the mean of rehearsal's, on the seeds all three ran "
            "(n seeds; each difference shown is over its own pairs). A point estimate, with no interval of its "
            "own: the scale is established where rehearsal's 95% interval excludes 0, and a position on a scale "
            "that is not says little.", "",
            *table(["configuration", "rehearsal", "outcome", "episodes", "difference from fine-tuning [95% interval]",
                    "rehearsal's difference [95% interval]", "scale established", "position", "n seeds"], rows), ""]


def position_rows(placed: list[Placed]) -> list[dict[str, Any]]:
    """comparison.csv's rows of ``placements``: every controller and kind of episodes."""
    return [{**csv_head(p.config.label, p.config.config), "statistic": "position", "episodes": p.key[0],
             "metric": p.key[1], "baseline": p.rehearsal.label, "n": len(p.seeds), "mean": p.position,
             "seeds": p.seeds} for p in placed]


def compare_table(paths, episodes: str = "held-out", baseline: dict[str, str] | None = None
                  ) -> tuple[list[dict[str, Any]], str]:
    """Rows (comparison.csv's: see CSV_COLUMNS; ``seeds`` and ``values`` are sequences) and the
    markdown report, for every run at or under ``paths``; ``episodes`` and ``baseline`` as
    ``--episodes`` and ``--baseline`` (``parse_baseline``) take them."""
    return _table(load_runs(paths, with_metrics=False), episodes, baseline)


SCRATCH_APART = ("from_scratch", "reg", "rehearsal", "joint", "reference_every", "training_episodes")
"""The config.json keys in which a run and its from-scratch partner may differ: the partner is the
same configuration learning each task afresh, whatever the run does to keep earlier tasks
(``training_episodes`` only restates the rehearsal and joint settings)."""


def is_from_scratch(config: dict[str, Any]) -> bool:
    return bool(config.get("from_scratch", False))  # runs from before the setting lack it


def scratch_key(config: dict[str, Any]) -> str:
    """What a run and its from-scratch partner share: the configuration (``configuration_of``, at
    lambda 0 so that the regulariser's options drop out as well) without ``SCRATCH_APART``."""
    settings = configuration_of({**config, "reg": 0.0})
    return json.dumps({k: v for k, v in settings.items() if k not in SCRATCH_APART}, sort_keys=True)


def scratch_partners(runs: list[Run]) -> dict[Path, list[Run]]:
    """Each run that is no from-scratch run -> the from-scratch runs among ``runs`` with its
    ``scratch_key`` and its seed (runs without any are left out). Only the same seed: the two then
    share their first task's sample path, and the seeds' variation does not enter the area."""
    scratch: dict[tuple[str, Any], list[Run]] = {}
    for run in runs:
        if is_from_scratch(run.config):
            scratch.setdefault((scratch_key(run.config), run.seed), []).append(run)
    partners = {run.path: scratch.get((scratch_key(run.config), run.seed), [])
                for run in runs if not is_from_scratch(run.config)}
    return {path: found for path, found in partners.items() if found}


MetricsReader = Callable[[Run], list[dict[str, str]]]
"""Reads a run's metrics.csv rows (``Run.metrics_rows``)."""


def metrics_reader() -> MetricsReader:
    """``Run.metrics_rows`` reading each run once: the curve and size figures all read the rows,
    and a from-scratch run may partner several runs."""
    rows: dict[Path, list[dict[str, str]]] = {}

    def read(run: Run) -> list[dict[str, str]]:
        if run.path not in rows:
            rows[run.path] = run.metrics_rows()
        return rows[run.path]

    return read


def forward_transfer_figures(runs: list[Run], metrics: MetricsReader | None = None) -> dict[Path, list[Figure]]:
    """Per run with from-scratch partners (``scratch_partners``), its forward transfer areas as
    figures: ``FT_area phase <k> (<task>)`` for each phase k >= 1 that the run and every partner
    have ended (the mean over the partners), and ``FT_area``, their mean, once that is every phase
    of the schedule. Reads the metrics.csv of those runs only (with ``metrics``)."""
    partners = scratch_partners(runs)
    metrics = metrics or metrics_reader()
    figures: dict[Path, list[Figure]] = {}
    for run in runs:
        if run.path not in partners:
            continue
        schedule = schedule_of(run.config)
        phases = [phase.name for phase in schedule]
        ended = min(len(r.summary.get(SummaryLayout.PHASES, [])) for r in [run, *partners[run.path]])
        areas = [forward_transfer_area(metrics(run), metrics(partner), ended) for partner in partners[run.path]]
        per_phase = {k: sum(area[k] for area in areas) / len(areas) for k in range(1, ended)
                     if all(k in area for area in areas)}
        found: list[Figure] = [(FT_AREA, (TRAINING, ft_area_name(k, phases[k])), value)
                               for k, value in per_phase.items()]
        if len(phases) > 1 and len(per_phase) == len(phases) - 1:
            found.append((FT_AREA, (TRAINING, ft_area_name()), sum(per_phase.values()) / len(per_phase)))
        if found:
            figures[run.path] = found
    return figures


def phase_start_figures(runs: list[Run], metrics: MetricsReader = Run.metrics_rows) -> dict[Path, list[Figure]]:
    """Per run, the current task's score in the first generation of each phase k >= 1
    (``metrics.phase_start_scores``): ``start_pop phase <k> (<task>)`` (training) and
    ``start_top ...`` (selection-time). Against fine-tuning it shows what a run brings back to a
    task at once, as an archive run's put-back controller does when its task returns."""
    figures: dict[Path, list[Figure]] = {}
    for run in runs:
        rows = metrics(run)
        phases = [phase.name for phase in schedule_of(run.config)]
        found: list[Figure] = [(PHASE_START, (kind, start_name(level, k, phases[k])), value)
                               for level, kind in START_KINDS.items()
                               for k, value in phase_start_scores(rows, level).items()]
        if found:
            figures[run.path] = found
    return figures


def size_figures(runs: list[Run], metrics: MetricsReader = Run.metrics_rows) -> dict[Path, list[Figure]]:
    """Per run, what its controllers are made of and what a generation costs, so that no difference
    between families is read as the optimiser's that belongs to the representation: for the top
    controller exported at each task end, ``algorithms.controller_size`` (a NEAT genome's nodes and
    enabled connections, changing as it evolves; an MLP's parameters, fixed), the evaluations
    per generation (controllers, an ES centre included, times training episodes), and for an ES the
    share of each phase's generations whose top individual is the centre (``top_is_centre_name``)."""
    figures: dict[Path, list[Figure]] = {}
    for run in runs:
        found: list[Figure] = []
        controllers = RunDir(run.path).read_controllers()
        has_centre = SummaryLayout.CENTRE_CURRENT in run.summary
        rows = metrics(run) if has_centre else []  # none without metrics.csv
        for i, task in enumerate(run.summary.get(SummaryLayout.PHASES, [])):
            exported = controllers.get(controller_key(i, task, "top"))
            if exported is not None:
                found += [(SIZE, ("", size_name(what, i, task)), n) for what, n in controller_size(exported).items()]
            in_phase = [row for row in rows if row["task_index"] == str(i) and row.get("centre", "") != ""]
            if in_phase:
                # the top's training score is the centre's: the centre itself, or a sample that ties it
                share = sum(float(row["top"]) == float(row["centre"]) for row in in_phase) / len(in_phase)
                found.append((SIZE, ("", top_is_centre_name(i, task)), 100 * share))
        population = run.config.get("population")
        if population is not None and SummaryLayout.CURRENT in run.summary:
            controllers_scored = int(population) + has_centre
            found.append((SIZE, ("", size_name("evaluations per generation")),
                          controllers_scored * int(run.config.get("evals", 0))))
        figures[run.path] = found
    return figures


def configurations(runs: list[Run]) -> list[Configuration]:
    """The runs' configurations, in table order, with their estimates (the forward transfer areas,
    phase starts and sizes included, each run's metrics.csv read once)."""
    # each group by seed (numerically), so nothing below depends on the order the runs came in
    groups = [sorted(g, key=lambda r: (seed_order(r.seed), str(r.path))) for g in sorted_groups(group_runs(runs))]
    configs = [g[0].config for g in groups]
    metrics = metrics_reader()
    transfer = forward_transfer_figures(runs, metrics)
    starts, sizes = phase_start_figures(runs, metrics), size_figures(runs, metrics)
    extra = {path: [*transfer.get(path, []), *starts.get(path, []), *sizes.get(path, [])]
             for path in {*transfer, *starts, *sizes}}
    return [Configuration(describe_config(config, configs), config, group,
                          [p.name for p in schedule_of(config)],
                          group_estimates(group, extra), seed_count(group))
            for group, config in zip(groups, configs)]


CURVE_LEGEND = {STABILITY_GAP: "; gap: the stability gap (an earlier task's score at a switch minus its lowest "
                               "retention in the first generations after it)",
                FT_AREA: "; FT_area: forward transfer, the mean over a phase of C minus C of a from-scratch run of "
                         "the same seed",
                PHASE_START: "; start: the current task's score in a phase's first generation, before any selection "
                             "on it"}
"""The header's words on each section of curve figures, where some configuration has it."""


def curve_legend(configurations: list[Configuration]) -> str:
    sections = {c.found[key][0] for c in configurations for key in curve_outcomes(c.found)}
    return "".join(words for section_name, words in CURVE_LEGEND.items() if section_name in sections)


def _table(runs: list[Run], episodes: str = "held-out", baseline: dict[str, str] | None = None,
           family: HolmFamily = ()) -> tuple[list[dict[str, Any]], str]:
    found = configurations(runs)
    baselines = choose_baselines(found, baseline)
    rows: list[dict[str, Any]] = []
    overview, sections, compared = [], [], []
    for c, b in zip(found, baselines):
        rows += csv_rows(c.label, c.config, c.found)
        if b is not None:
            rows += difference_rows(c, found[b], family)
            compared.append(differences_section(c, found[b], episodes, family))
        overview.append(overview_row(c.label, c.n, c.found, episodes))
        seeds = ", ".join(f"{r.seed}{'' if r.finished else ' (unfinished)'}" for r in c.runs)
        sections.append(section(f"## {c.label}", f"{len(c.runs)} seed(s): {seeds}", c.found, episodes))
    against = (["## Differences from the baseline", "",
                "Each configuration against its baseline (" + ("named by --baseline" if baseline else
                "fine-tuning: lambda 0 without rehearsal, joint or from scratch, of the same algorithm and "
                "otherwise the same settings") + "), per outcome of the paper's "
                "tables" + (" and per curve figure both have" if curve_legend(found) else "") + ".", "", *compared]
               if compared else [])
    header = [f"# Comparison of {len(runs)} run(s) in {len(found)} configuration(s)", "",
              "Mean over seeds [95% t-interval]; a single seed shows its value. C: current performance at the end "
              "of a phase (the population's: its best; C_top: that of the top individual, the best by selection "
              "fitness; for an ES C_centre and C_best_sample: the search distribution's centre and the best "
              "sample); R/F: retention/forgetting of an earlier task; ACC/BWT/FWT: average final performance, "
              "backward and forward transfer" + curve_legend(found)
              + ". Episodes: held-out (the exported controllers re-scored on the "
              "fixed held-out episodes), selection-time (the top individual on the training episodes it was "
              "selected on) or training (the population's best; an ES centre).", "",
              *table(["configuration", "n seeds", *OVERVIEW], overview), "", *paper_tables(found, episodes), *against]
    _check_family(family, found, baselines)
    placed = placements(found, baselines)
    rows += position_rows(placed)
    return rows, "\n".join(header + positions_section(placed, episodes) + sections)


@dataclass
class Comparison:
    """What ``compare`` writes, computed before anything is written."""

    rows: list[dict[str, Any]]
    markdown: str
    model_specific_markdown: str | None
    model_specific_json: list[dict[str, Any]]


def comparison(paths, episodes: str = "held-out", baseline: dict[str, str] | None = None,
               family: HolmFamily = (), lambda_per_seed: dict[int, float] | None = None,
               choose_on: str = SELECTION_TIME) -> Comparison:
    """``compare_table`` of the runs at or under ``paths`` plus, where a configuration ran several
    lambdas, the model-specific lambda rows, chosen on ``choose_on``'s figures (held-out: UserError
    where a run chosen among has no held-out scores), and with ``lambda_per_seed`` the given ones
    (``--per-seed-lambda``: UserError where no such configuration ran every run it names)."""
    runs = load_runs(paths, with_metrics=False)
    rows, markdown = _table(runs, episodes, baseline, family)
    names = [run.path.name for run in runs]
    tags = names if len(set(names)) == len(names) else [str(run.path) for run in runs]
    configs = [run.config for run in runs]
    triples = [(run.config, run.summary, tag) for run, tag in zip(runs, tags)]
    summaries = {tag: summary for _, summary, tag in triples}
    if choose_on == HELD_OUT:
        _check_held_out(select_model_specific(triples), summaries)
    selections = select_model_specific(triples, choose_on)
    if lambda_per_seed:
        selections = _with_given(selections, lambda_per_seed)
    if not selections:
        return Comparison(rows, markdown, None, [])
    ms_rows, ms_markdown = model_specific_report(selections, summaries, configs, episodes, choose_on)
    ms_json = [{"configuration": model_specific_label(s["config"], configs), "criterion": CRITERION,
                "chosen_on": choose_on,
                "choices": s["choices"], "left_out": [{"seed": seed, "lambdas": regs}
                                                      for seed, regs in s["left_out"].items()],
                "one_lambda_for_all_seeds": {
                    "reg": s["shared"]["reg"],
                    "mean_per_lambda": [{"reg": r, "mean": m} for r, m in s["shared"]["means"].items()],
                    **({"lambda_0_point_of_comparison": s["shared"]["lambda_0"]} if "lambda_0" in s["shared"] else {})},
                **({"given": s["given"]} if s.get("given") else {})}
               for s in selections]
    return Comparison(rows + ms_rows, markdown + "\n" + ms_markdown, ms_markdown, ms_json)


def _check_held_out(selections: list[dict[str, Any]], summaries: dict[Any, dict[str, Any]]) -> None:
    """UserError naming the runs a lambda is chosen among (``selections``, chosen on the training
    episodes) whose held-out scores the criterion cannot be read from; otherwise nothing."""
    lacking = sorted({str(tag) for selection in selections for found in selection["candidates"].values()
                      for _, _, tag in found if held_out_selection_score(summaries[tag]) is None})
    if lacking:
        shown = ", ".join(lacking[:3]) + (f" and {len(lacking) - 3} more" if len(lacking) > 3 else "")
        raise UserError(f"--choose-lambda-on held-out: {shown} has no held-out score of {CRITERION} "
                        "(summary.json's held_out block, written by runs with held-out episodes): choose on the "
                        "training episodes (--choose-lambda-on selection-time, the default), or compare runs "
                        "scored held-out")


def _with_given(selections: list[dict[str, Any]], lambda_per_seed: dict[int, float]) -> list[dict[str, Any]]:
    """``selections`` with ``given`` choices where a configuration ran every run ``lambda_per_seed``
    names; the first configuration's UserError where none did."""
    if not selections:
        raise UserError("--per-seed-lambda: no configuration was run with several lambdas; compare the runs of "
                        "every lambda named together")
    result, errors = [], []
    for selection in selections:
        try:
            selection = {**selection, "given": given_choices(selection, lambda_per_seed)}
        except UserError as error:
            errors.append(error)
        result.append(selection)
    if len(errors) == len(selections):
        raise errors[0]
    return result


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
