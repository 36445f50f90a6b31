"""The model-specific lambda ("m.s. reg", the paper's per-seed lambda row): for each configuration
without lambda and each seed, the lambda maximising ``C_top(phase 1) + R_top(task of phase 0 at
the end of phase 1)`` (the top individual's current performance plus its retention of the first
task at the end of the second task: the controller one would deploy, good at both; ties go to the
smaller lambda), chosen on the selection-time figures (the training episodes; ``--choose-lambda-on
held-out``: on the held-out episodes, ``CHOOSE_ON``) and reported as a configuration of its own
with the chosen lambda per seed, its tables held-out where the chosen runs have the block; beside it the one lambda for all seeds, the highest mean of the same
criterion over the seeds (``select_model_specific``, ``model_specific_report``). Every seed chooses
among the same lambdas: a seed without a finished run of each is left out, and named. Weight
protection's (lambda_1, lambda_2) pairs are one swept value each; a lambda-0 run is a candidate of
its own regulariser's configuration, and beside another's lambdas the point of comparison. A lambda
given per seed instead (``given_choices``: a paper's own per-seed table) is reported the same way,
as ``reg=given``. A lambda chosen
per seed on the seed it is reported on is optimistic: the report says so, and by how much where
the runs have held-out scores (``optimism_rows``: the criterion on the training episodes minus the
same criterion held-out, for the chosen runs and, as the reference, for each lambda on every seed).
"""
from __future__ import annotations

import json
import math
import re
from dataclasses import asdict
from typing import Any

from algorithms import REGISTRY

from ..config import RunConfig
from ..errors import UserError
from ..runs import configuration_of, describe_config
from ..summary_json import SummaryLayout
from .tables import (HELD_OUT, OVERVIEW, SELECTION_TIME, Estimate, cell, csv_rows, estimates, overview_row, section,
                     table)

CRITERION = "C_top(phase 1) + R_top(task of phase 0 at end of phase 1)"

CHOOSE_ON = (SELECTION_TIME, HELD_OUT)
"""The episodes a lambda can be chosen on (``compare --choose-lambda-on``): the top individual's
figures on the training episodes it was selected on (the paper's rule, the default), or on the
held-out episodes (a study whose plan chooses on held-out figures; every candidate run needs the
held-out block)."""


def selection_score(summary: dict[str, Any]) -> float | None:
    """``C_top(phase 1) + R_top(task of phase 0 at the end of phase 1)``; None before phase 1 ended."""
    current = summary.get(SummaryLayout.CURRENT_TOP) or []
    phases = summary.get(SummaryLayout.PHASES) or []
    if len(current) < 2 or len(phases) < 2:
        return None
    rows = [r for r in summary.get(SummaryLayout.FORGETTING, []) if r["at_end_of"] == 1 and r["task"] == phases[0]]
    if not rows or current[1] is None or rows[0]["R_top"] is None:
        return None
    return float(current[1]) + float(rows[0]["R_top"])


def held_out_selection_score(summary: dict[str, Any]) -> float | None:
    """``selection_score`` on the held-out episodes (the held-out block's top-controller figures);
    None where the run has no such figures."""
    keys = SummaryLayout
    held = summary.get(keys.HELD_OUT) or {}
    return selection_score({keys.PHASES: held.get(keys.PHASES), keys.CURRENT_TOP: held.get(keys.CURRENT_TOP),
                            keys.FORGETTING: held.get(keys.FORGETTING, [])})


def optimism_rows(selection: dict[str, Any], summaries: dict[Any, dict[str, Any]]) -> list[list[str]]:
    """How optimistic the per-seed choice is: for the chosen runs and for each lambda run on every
    seed chosen for, the criterion's mean on the training episodes (selection-time), held-out, and the mean of
    the per-seed differences with its t-interval. The chosen runs' difference holds the selection
    bias every lambda has plus what choosing on the evaluated seed adds. Empty without held-out scores."""
    def row(label: str, picks: list[tuple[Any, float, Any]]) -> list[str] | None:
        pairs = [(seed, selection_score(summaries[tag]), held_out_selection_score(summaries[tag]))
                 for seed, _, tag in picks]
        if not pairs or any(score is None or held is None for _, score, held in pairs):
            return None
        seeds = [seed for seed, _, _ in pairs]
        return [label, str(len(pairs)), str(Estimate.of([s for _, s, _ in pairs], seeds)),
                str(Estimate.of([h for _, _, h in pairs], seeds)), str(Estimate.of([s - h for _, s, h in pairs], seeds))]

    chosen = row("chosen per seed", [(c["seed"], c["score"], c["tag"]) for c in selection["choices"]])
    seeds = {c["seed"] for c in selection["choices"]}
    rows = [chosen] + [row(f"lambda {lambda_text(reg)}, every seed", [(seed, score, tag) for seed, runs in
                                                           sorted(selection["candidates"].items()) if seed in seeds
                                                           for score, r, tag in runs if r == reg])
                       for reg in selection["lambdas"]]
    return [r for r in rows if r is not None] if chosen is not None else []


def weights_read(config: dict[str, Any]) -> tuple[str, ...]:
    """The options of a run's regulariser that weigh its penalty beside lambda
    (``Optimizer.lambda_options`` that the regulariser reads, ``Optimizer.options_used_by``: NEAT's
    ``lambda_2`` under wp); a lambda choice sweeps them with lambda."""
    algo = REGISTRY.get(str(config.get("algo")))
    if algo is None:
        return ()
    regulariser = RunConfig.regulariser_of(config)
    return tuple(name for name in algo.lambda_options if regulariser in algo.options_used_by.get(name, (regulariser,)))


def swept_value(config: dict[str, Any]) -> float | tuple[float, ...]:
    """What a lambda choice chooses among for a run: its lambda, or where its regulariser has
    weights beside lambda (``weights_read``) lambda with them, ``(lambda_1, lambda_2)`` (all 0 at
    lambda 0, where no penalty plays)."""
    names = weights_read(config)
    reg = float(config["reg"])
    if not names:
        return reg
    options = {**asdict(REGISTRY[config["algo"]].Options()),
               **(config.get("algo_options_resolved") or config.get("algo_options") or {})}
    return (reg, *(float(options[name]) if reg else 0.0 for name in names))


def lambda_text(value: float | tuple[float, ...]) -> str:
    """A swept value as the report writes it: ``0.4``, or a pair ``(0.4, 0.3)``."""
    return f"{value:g}" if isinstance(value, float) else "(" + ", ".join(f"{v:g}" for v in value) + ")"


def _without_lambda(config: dict[str, Any]) -> str:
    """The configuration of a run without what a lambda choice sweeps (``swept_value``)."""
    rest = {k: v for k, v in configuration_of(config).items() if k != "reg"}
    names = weights_read(config)
    for key in ("algo_options", "algo_options_resolved"):
        if isinstance(rest.get(key), dict):
            rest[key] = {k: v for k, v in rest[key].items() if k not in names}
    return json.dumps(rest, sort_keys=True, default=str)


def select_model_specific(runs: list[tuple[dict[str, Any], dict[str, Any], Any]],
                          choose_on: str = SELECTION_TIME) -> list[dict[str, Any]]:
    """The model-specific lambda: ``runs`` are (config.json dict, summary.json dict, tag) triples;
    for each configuration without lambda that was run with several lambdas, and each of its seeds
    that ran every one of them (and has reached the end of phase 1), the run whose lambda maximises
    ``selection_score`` (``choose_on`` held-out: ``held_out_selection_score``; ties: the smaller
    lambda). What is chosen among is ``swept_value``: lambda,
    or for weight protection the pair (lambda_1, lambda_2), one value. A run without regulariser
    (lambda 0) that differs from such a configuration only in the regulariser and its options
    (``Optimizer.regularizer_options``) is a candidate where its regulariser (config.json's: the
    family's default where it named none) is the configuration's (NEAT's gd and lambda 0; an ES's
    l2 and lambda 0), and otherwise the choice's point of comparison, not a candidate (wp,
    functional or ewc beside a lambda-0 run that named none: the lambda is chosen among the grid's).

    Returns one dict per such configuration with at least one such seed: ``config`` (the config
    of one of its regularised runs), ``lambdas`` (ascending), ``choices``, one per such seed in
    ascending order: ``seed``, ``reg`` (its swept value), ``score``, ``tag``; ``shared``, the one
    lambda for every seed: the one whose mean of that score over those seeds is highest (ties:
    the smaller lambda), with ``means`` (lambda -> that mean) and, where every such seed has a
    lambda-0 run that is the point of comparison, ``lambda_0`` (its mean); ``left_out``: the seeds
    that ran only some of the lambdas, with those they ran (every seed chooses among the same
    lambdas, or a seed that ran fewer would have an easier choice); and ``candidates``: per chosen
    seed, every run's (score, lambda, tag)."""
    groups: dict[str, dict[str, Any]] = {}
    # regularised runs first: they make the configurations, which each lambda-0 run then joins
    ordered = sorted(runs, key=lambda run: not float(run[0]["reg"]))
    criterion = held_out_selection_score if choose_on == HELD_OUT else selection_score
    for config, summary, tag in ordered:
        score = criterion(summary)
        scored = score is not None and math.isfinite(score)
        seed, value = config.get("seed"), swept_value(config)
        if float(config["reg"]):
            found = [groups.setdefault(_without_lambda(config), {
                "values": set(), "by_seed": {}, "comparison": {}, "config": config,
                "base": _without_lambda({**config, "reg": 0}), "regulariser": RunConfig.regulariser_of(config)})]
            compared = []
        else:
            base, regulariser = _without_lambda(config), RunConfig.regulariser_of(config)
            found = [g for g in groups.values() if g["base"] == base and g["regulariser"] == regulariser]
            compared = [g for g in groups.values() if g["base"] == base and g["regulariser"] != regulariser]
        for group in found:
            group["values"].add(value)
            if scored:
                group["by_seed"].setdefault(seed, []).append((score, value, tag))
        for group in compared:
            if scored:
                group["comparison"][seed] = score
    result = []
    for group in groups.values():
        lambdas = sorted(group["values"])
        ran = {seed: {value for _, value, _ in runs_of_seed} for seed, runs_of_seed in group["by_seed"].items()}
        # every seed chooses among the same lambdas: a seed that ran fewer would have an easier choice
        complete = sorted(seed for seed in ran if ran[seed] == group["values"])
        if len(lambdas) < 2 or not complete:
            continue
        choices = []
        for seed in complete:
            score, value, tag = min(group["by_seed"][seed], key=lambda c: (-c[0], c[1]))
            choices.append({"seed": seed, "reg": value, "score": score, "tag": tag})
        means = {value: sum(score for seed in complete for score, v, _ in group["by_seed"][seed] if v == value)
                 / len(complete) for value in lambdas}
        shared = {"reg": min(means, key=lambda value: (-means[value], value)), "means": means}
        if group["comparison"] and all(seed in group["comparison"] for seed in complete):
            shared["lambda_0"] = sum(group["comparison"][seed] for seed in complete) / len(complete)
        result.append({"config": group["config"], "lambdas": lambdas, "choices": choices, "shared": shared,
                       "left_out": {seed: sorted(ran[seed]) for seed in sorted(ran) if seed not in complete},
                       "candidates": {seed: group["by_seed"][seed] for seed in complete}})
    return result


def given_choices(selection: dict[str, Any], lambda_per_seed: dict[int, float]) -> list[dict[str, Any]]:
    """``selection``'s choices replaced by a lambda given per seed (``compare --per-seed-lambda``,
    e.g. the paper's own per-seed table), in ascending seed order; UserError where a named seed has
    no finished run of its lambda among the seeds the selection chose for."""
    runs = {seed: {reg: (score, tag) for score, reg, tag in found} for seed, found in selection["candidates"].items()}
    missing = [f"seed {seed} lambda {lambda_text(reg)}" for seed, reg in sorted(lambda_per_seed.items())
               if reg not in runs.get(seed, {})]
    if missing:
        lambdas = ", ".join(lambda_text(reg) for reg in selection["lambdas"])
        raise UserError(f"--per-seed-lambda: no finished run of {', '.join(missing)} among the seeds that finished every "
                        f"lambda of {lambdas} ({', '.join(str(seed) for seed in runs) or 'none'}): name those seeds, "
                        "each with one of those lambdas")
    return [{"seed": seed, "reg": reg, "score": runs[seed][reg][0], "tag": runs[seed][reg][1]}
            for seed, reg in sorted(lambda_per_seed.items())]


def parse_per_seed_lambda(text: str | None) -> dict[int, float] | None:
    """``--per-seed-lambda SEED=LAMBDA,...`` as seed -> lambda."""
    if text is None:
        return None
    given: dict[int, float] = {}
    for item in text.split(","):
        seed, equals, reg = (part.strip() for part in item.partition("="))
        try:
            value = float(reg)
            if not equals or not seed.lstrip("-").isdigit() or not math.isfinite(value) or int(seed) in given:
                raise ValueError
        except ValueError:
            raise UserError(f"--per-seed-lambda {item.strip()!r} is not SEED=LAMBDA, or names its seed twice: give "
                            "each seed once with its lambda, e.g. --per-seed-lambda 13=5,17=5,24=5,31=11,42=11") from None
        given[int(seed)] = value
    return given


def model_specific_label(config: dict[str, Any], all_configs: list[dict[str, Any]]) -> str:
    """``compare``'s label of the configuration with ``reg=m.s.``, e.g. ``neat reg=m.s. red-green-red``,
    naming none of the weights chosen with lambda (``weights_read``: wp's ``lambda_2``)."""
    names = weights_read(config)
    unswept = {**config, **{key: {k: v for k, v in config[key].items() if k not in names}
                            for key in ("algo_options", "algo_options_resolved") if isinstance(config.get(key), dict)}}
    return re.sub(r"reg=\S+", "reg=m.s.", describe_config(unswept, all_configs), count=1)


def left_out_note(selection: dict[str, Any]) -> str:
    """The seeds a selection left out, with the lambdas each finished; empty if none."""
    if not selection["left_out"]:
        return ""
    every = ", ".join(lambda_text(reg) for reg in selection["lambdas"])
    seeds = ", ".join(f"{seed} (finished {' and '.join(lambda_text(reg) for reg in regs)})"
                      for seed, regs in selection["left_out"].items())
    return f". Left out, as they did not finish every lambda of {every}: seeds {seeds}"


def model_specific_report(selections: list[dict[str, Any]], summaries: dict[Any, dict[str, Any]],
                          all_configs: list[dict[str, Any]], episodes: str = "held-out",
                          choose_on: str = SELECTION_TIME) -> tuple[list[dict[str, Any]], str]:
    """``compare_table``'s rows and markdown for the m.s. configurations (the chosen lambdas in
    ``reg``): an overview line per m.s. configuration with the lambda per seed and the criterion,
    then its tables; means over seeds of the chosen runs with their 95% t-interval. The lambdas
    were chosen on ``choose_on``'s figures (``select_model_specific``); the chosen runs are
    reported as ``episodes`` says (held-out where they have the block, by default). A selection with ``given`` choices
    (``given_choices``) adds a configuration ``reg=given`` with those, reported the same way."""
    rows: list[dict[str, Any]] = []
    overview, sections = [], []
    chosen_on = ("held-out episodes (--choose-lambda-on held-out)" if choose_on == HELD_OUT
                 else "training episodes (selection-time figures)")
    seen = {kind: " it was chosen on" if kind == choose_on else "" for kind in CHOOSE_ON}
    for selection in selections:
        label = model_specific_label(selection["config"], all_configs)
        shared = selection["shared"]
        compared = f"; lambda 0, not a candidate: {shared['lambda_0']:.2f}" if "lambda_0" in shared else ""
        one = (f"{lambda_text(shared['reg'])} ("
               + ", ".join(f"{lambda_text(reg)}: {mean:.2f}" for reg, mean in shared["means"].items()) + compared + ")")
        reported = [(label, "m.s.", selection["choices"], f"lambda per seed: %s{left_out_note(selection)}")]
        if selection.get("given"):
            reported.append((label.replace("reg=m.s.", "reg=given", 1), "given", selection["given"],
                             "lambda per seed, as given (--per-seed-lambda): %s"))
        for name, tag, choices, intro in reported:
            lambdas = ", ".join(f"{c['seed']}: {lambda_text(c['reg'])}" for c in choices)
            found = {(choose_on, CRITERION): ("selection", Estimate.of([c["score"] for c in choices],
                                                                            [c["seed"] for c in choices])),
                     **estimates([(c["seed"], summaries[c["tag"]]) for c in choices])}
            rows += csv_rows(name, selection["config"], found, reg=f"{tag} " + " ".join(lambda_text(c["reg"]) for c in choices))
            overview.append([name, len(choices), lambdas, one if tag == "m.s." else "",
                             cell(found, (choose_on, CRITERION)),
                             *overview_row(name, str(len(choices)), found, episodes)[2:]])
            sections.append(section(f"### {name}", intro % lambdas, found, episodes))
            optimism = optimism_rows({**selection, "choices": choices}, summaries)
            if optimism:
                sections.append("\n".join([
                    f"How optimistic the choice is: {CRITERION} on the training episodes{seen[SELECTION_TIME]} "
                    f"(selection-time) and on the held-out episodes{seen[HELD_OUT]}, and the per-seed difference; "
                    "beside it each lambda run on every seed, whose difference is the selection bias any top "
                    "individual has.", "",
                    *table(["runs", "n seeds", "selection-time", "held-out", "selection-time - held-out"], optimism),
                    ""]))
    markdown = "\n".join([
        "## Model-specific lambda (m.s. reg)", "",
        f"Per configuration and seed, the lambda of the sweep maximising {CRITERION} (the top individual's "
        "current performance plus its retention of the first task, at the end of the second task; ties: "
        f"the smaller lambda), from summary.json: chosen on the {chosen_on}. "
        "The chosen runs are reported below with held-out figures where they have them (each table names its "
        "episodes); mean over seeds [95% t-interval]. Every seed chooses among the same lambdas: a seed that "
        "did not finish every lambda's second task is left out (each section names it). One lambda for all "
        "seeds: the one with the highest mean of the criterion over those seeds (ties: the smaller), with each "
        "lambda's mean.", "",
        *table(["configuration", "n seeds", "lambda per seed", "one lambda for all seeds (mean per lambda)",
                f"{CRITERION} ({choose_on})", *OVERVIEW], overview), "",
        *sections]).rstrip("\n")
    return rows, markdown
