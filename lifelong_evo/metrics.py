"""The paper's metrics and the continual-learning ones, from fitness tensors.

Per generation g of phase t with population P_t (fitness f over the controllers, s_t the
fitness selection uses: f_t itself, or with a regulariser on the regularised fitness):
  C(P_t)        = max_pi f_t(pi)                        current performance
  top(P_t)      = argmax_pi s_t(pi)                     the top individual, the one selection favours
  R_pop_u(P_t)  = max_pi f_u(pi)                        population retention of an earlier task u
  R_top_u(P_t)  = f_u(top(P_t))                         retention of the current top individual
At the end of phase t, for each task u of an earlier phase (the latest such phase s):
  F_pop_u       = C(P_s at its end) - R_pop_u(P_t at its end)                  forgetting
  F_top_u       = R_top_u(P_s at its end) - R_top_u(P_t at its end)
(without a regulariser R_top_u(P_u) = C(P_u), so the two forgettings start from the same C). The
top individual follows the paper's code, which ranks by the fitness neat-python sees: with the
genetic-distance penalty on, its "current performance" and retention are those of the best
regularised genome, not of the best raw one.
Over the T phases of the schedule, with R[i][j] the fitness on phase j's task at the end of
phase i (R_pop: best of the population; R_top: the top individual of phase i) and b_j the best
fitness of the fresh random population (generation 0) on phase j's task:
  ACC = 1/T sum_j R[T-1][j]                 average final performance
  BWT = 1/(T-1) sum_{j<T-1} (R[T-1][j] - R[j][j])      backward transfer (Lopez-Paz & Ranzato 2017)
  FWT = 1/(T-1) sum_{j>=1} (R[j-1][j] - b_j)           forward transfer
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Any

import torch


@dataclass(frozen=True)
class FitnessStats:
    """One fitness vector summarised over the population."""

    best: float
    mean: float
    median: float
    std: float
    """Population standard deviation (not the sample's)."""

    @classmethod
    def of(cls, values: torch.Tensor) -> FitnessStats:
        values = values.double()
        return cls(best=values.max().item(), mean=values.mean().item(), median=values.median().item(),
                   std=values.std(unbiased=False).item())


@dataclass(frozen=True)
class Retention:
    """The fitness on one task of the population's best (``pop``), of the top individual
    (``top``) and, for an ES, of its centre."""

    pop: float
    top: float
    centre: float | None = None


def retention(scores: torch.Tensor, selection: torch.Tensor, centre_index: int | None) -> Retention:
    """Population, top-individual (and centre) retention from one task's fitness ``scores``; the
    top individual is the best by ``selection``, the fitness selection uses on the current task."""
    top = int(selection.argmax())
    return Retention(pop=scores.max().item(), top=scores[top].item(),
                     centre=None if centre_index is None else scores[centre_index].item())


@dataclass(frozen=True)
class GenerationRecord:
    """What the lifelong loop measured in one generation: ``rundir.MetricsLayout`` flattens it
    into a metrics.csv row, the recorder draws it as it is."""

    task: str
    """The current task."""
    task_index: int
    """Its phase of the schedule, from 0."""
    generation: int
    """Global, from 0."""
    generation_in_task: int
    fitness: FitnessStats
    """Of the raw fitness on the current task."""
    regularised: FitnessStats
    """Of the selection fitness: the raw one minus the regulariser's penalty."""
    top: float
    """Raw fitness of the top individual, the best by selection fitness."""
    retention: dict[str, Retention]
    """Per earlier task scored in this generation (every few generations and at task ends)."""
    species_sizes: dict[int, int] | None = None
    """NEAT: species id -> members."""
    centre: float | None = None
    """ES: the raw fitness of the search distribution's centre."""
    diagnostics: dict[str, float] = field(default_factory=dict)
    """The optimiser's scalars of this generation (``GenerationReport.extra``); those its class
    names in ``Optimizer.diagnostics`` are also metrics.csv columns."""


def summarise(phase_names: list[str], phase_ends: list[dict[str, Any]], initial: dict[str, dict[str, float]],
              wall_time_s: float, has_centre: bool, held_out: dict[str, dict[str, float]] | None = None,
              held_out_episodes: int | None = None, first_task_from: str = "") -> dict[str, Any]:
    """summary.json from the task-end records (``loop.LoopState.phase_ends``), the generation-0
    scores and, where given, the exported controllers' held-out scores (``held_out_summary``);
    ``first_task_from``: the run whose first task this one took over (the wall time counts it)."""
    summary: dict[str, Any] = {"phases": phase_names[:len(phase_ends)], "wall_time_s": wall_time_s,
                               **({"first_task_from": first_task_from} if first_task_from else {}),
                               "current": [end["C"] for end in phase_ends],
                               "current_top": [end["R_top"][end["task"]] for end in phase_ends], "forgetting": []}
    if has_centre:
        summary["centre_current"] = [end["R_centre"][end["task"]] for end in phase_ends]
    for i, end in enumerate(phase_ends):
        for earlier in _earlier_tasks(phase_names, i):
            s = max(j for j in range(i) if phase_names[j] == earlier)
            c_earlier, top_earlier = phase_ends[s]["C"], phase_ends[s]["R_top"][earlier]
            row = {"at_end_of": i, "task": earlier, "C": c_earlier, "C_top": top_earlier,
                   "R_pop": end["R_pop"][earlier], "R_top": end["R_top"][earlier],
                   "F_pop": c_earlier - end["R_pop"][earlier], "F_top": top_earlier - end["R_top"][earlier]}
            if has_centre:
                row["R_centre"] = end["R_centre"][earlier]
                row["F_centre"] = phase_ends[s]["R_centre"][earlier] - end["R_centre"][earlier]
            summary["forgetting"].append(row)
    if len(phase_ends) == len(phase_names):
        for level in ("pop", "top"):
            matrix = [[end[f"R_{level}"][name] for name in phase_names] for end in phase_ends]
            summary[f"R_{level}"] = matrix
            summary.update(_transfer(matrix, [initial["pop"][name] for name in phase_names], level))
    if held_out:
        summary["held_out"] = held_out_summary(phase_names, held_out, held_out_episodes)
    return summary


HELD_OUT_LEVELS = {"top": "top", "centre": "centre", "best-sample": "best_sample"}
"""The kinds of controller exported at a task end -> their suffix in the held-out block: the top
individual (the best by selection fitness, what one would deploy), and for an ES also the search
distribution's centre and the best sampled solution (the best by selection fitness among the
samples), each scored on its own."""
INITIAL = "initial"
"""The name of the generation-0 controllers (``initial-top``): the forward-transfer baseline."""


def controller_key(phase_index: int | None, task: str | None, kind: str) -> str:
    """A controller's name in controllers/ and in the held-out block: ``task1-green-top``, or
    ``initial-top`` for generation 0 (``phase_index`` None)."""
    return f"{INITIAL}-{kind}" if phase_index is None else f"task{phase_index}-{task}-{kind}"


_CONTROLLER_KEY = re.compile(rf"(?:task(?P<phase>\d+)-(?P<task>.+)|{INITIAL})-(?P<kind>{'|'.join(HELD_OUT_LEVELS)})")


def parse_controller_key(key: str) -> tuple[int | None, str | None, str] | None:
    """``(phase_index, task, kind)`` of a ``controller_key`` (phase and task None for generation
    0's), None for another name (``final-top``)."""
    found = _CONTROLLER_KEY.fullmatch(key)
    if found is None:
        return None
    phase = found["phase"]
    return (None if phase is None else int(phase)), found["task"], found["kind"]


def _controller_order(key: str) -> tuple[int, int]:
    phase, _, kind = parse_controller_key(key)
    return -1 if phase is None else phase, list(HELD_OUT_LEVELS).index(kind)


def held_out_summary(phase_names: list[str], scores: dict[str, dict[str, float]], episodes: int) -> dict[str, Any]:
    """summary.json's ``held_out`` block from the held-out scores of the exported controllers
    (``{"task<i>-<task>-<kind>": {task: score}}``, ``"initial-<kind>"`` for generation 0): the
    scores themselves, then per kind of controller (top; for an ES also centre and best sample)
    its C per finished phase, a forgetting row per earlier task at each later task end (C, R and
    F of that kind, as the training rows define them) and, once every phase has ended, the R
    matrix and ACC/BWT/FWT (FWT's baseline: the generation-0 controller of that kind, where it
    was scored)."""
    finished = 0
    while finished < len(phase_names) and controller_key(finished, phase_names[finished], "top") in scores:
        finished += 1
    ordered = {key: scores[key] for key in sorted(scores, key=_controller_order)}  # the same bytes however scored
    block: dict[str, Any] = {"episodes": episodes, "phases": phase_names[:finished], "scores": ordered}
    kinds = [kind for kind in HELD_OUT_LEVELS
             if all(controller_key(i, phase_names[i], kind) in scores for i in range(finished))] if finished else []
    for kind in kinds:
        level = HELD_OUT_LEVELS[kind]
        block[f"current_{level}"] = [scores[controller_key(i, phase_names[i], kind)][phase_names[i]] for i in range(finished)]
    block["forgetting"] = []
    for i in range(finished):
        for earlier in _earlier_tasks(phase_names, i):
            s = max(j for j in range(i) if phase_names[j] == earlier)
            row: dict[str, Any] = {"at_end_of": i, "task": earlier}
            for kind in kinds:
                level = HELD_OUT_LEVELS[kind]
                kept = scores[controller_key(s, phase_names[s], kind)][earlier]
                now = scores[controller_key(i, phase_names[i], kind)][earlier]
                row.update({f"C_{level}": kept, f"R_{level}": now, f"F_{level}": kept - now})
            block["forgetting"].append(row)
    if finished == len(phase_names):
        for kind in kinds:
            level = HELD_OUT_LEVELS[kind]
            matrix = [[scores[controller_key(i, phase_names[i], kind)][name] for name in phase_names]
                      for i in range(finished)]
            block[f"R_{level}"] = matrix
            initial = scores.get(controller_key(None, None, kind))
            transfer = _transfer(matrix, [initial[name] for name in phase_names] if initial else None, level)
            block.update(transfer)
    return block


def _earlier_tasks(phase_names: list[str], i: int) -> list[str]:
    seen: list[str] = []
    for name in phase_names[:i]:
        if name != phase_names[i] and name not in seen:
            seen.append(name)
    return seen


def _transfer(matrix: list[list[float]], baseline: list[float] | None, level: str) -> dict[str, float | None]:
    """ACC, BWT and FWT of an R matrix (FWT None without a ``baseline``)."""
    T = len(matrix)
    acc = sum(matrix[T - 1]) / T
    if T < 2:
        return {f"ACC_{level}": acc, f"BWT_{level}": None, f"FWT_{level}": None}
    bwt = sum(matrix[T - 1][j] - matrix[j][j] for j in range(T - 1)) / (T - 1)
    fwt = None if baseline is None else sum(matrix[j - 1][j] - baseline[j] for j in range(1, T)) / (T - 1)
    return {f"ACC_{level}": acc, f"BWT_{level}": bwt, f"FWT_{level}": fwt}
