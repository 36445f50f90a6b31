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
Read back from metrics.csv rows (``stability_gap``, ``forward_transfer_area``), for each switch to
a phase k >= 1:
  gap_u = (u's score at the last generation of phase k-1) - min over the first G generations of
          phase k of R_u                  stability gap (De Lange et al. 2023), per earlier task u
  FT_area_k = mean over phase k's generations g of (C(g) - C_scratch(g))   forward transfer as the
          area between the run's curve and a from-scratch run's (Wolczyk et al. 2021)
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Any

import torch

from .summary_json import SummaryLayout


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


def retention_column(level: str, task: str) -> str:
    """The metrics.csv column of ``level``'s retention of ``task``: ``retention_pop_red``."""
    return f"retention_{level}_{task}"


def retention(scores: torch.Tensor, selection: torch.Tensor, centre_index: int | None) -> Retention:
    """Population, top-individual (and centre) retention from one task's fitness ``scores``; the
    top individual is the best by ``selection``, the fitness selection uses on the current task."""
    top = int(selection.argmax())
    return Retention(pop=scores.max().item(), top=scores[top].item(),
                     centre=None if centre_index is None else scores[centre_index].item())


@dataclass(frozen=True)
class GenerationRecord:
    """What the lifelong loop measured in one generation: ``metrics_csv.MetricsLayout`` flattens it
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
              held_out_episodes: int | None = None, first_task_from: str = "", *,
              stability_gap: list[dict[str, Any]] | None = None,
              machines: list[dict[str, Any]] | None = None, numerics: str | None = None,
              archive: bool = False) -> dict[str, Any]:
    """summary.json from the task-end records (``loop.LoopState.phase_ends``), the generation-0
    scores and, where given, the exported controllers' held-out scores (``held_out_summary``);
    ``first_task_from``: the run whose first task this one took over (the wall time counts it);
    ``stability_gap``: the entries of ``stability_gap``, written as they are (None: no such key);
    ``machines``: where the generations ran (``loop.LoopState.machines``), written as they are;
    ``numerics``: the arithmetic of the fitness (``RunConfig.numerics``); ``archive``: the run
    keeps a skill archive (``RunConfig.archive``), which the held-out block scores."""
    keys = SummaryLayout
    summary: dict[str, Any] = {keys.PHASES: phase_names[:len(phase_ends)], keys.WALL_TIME: wall_time_s,
                               **({keys.MACHINES: machines} if machines else {}),
                               **({keys.NUMERICS: numerics} if numerics else {}),
                               **({keys.FIRST_TASK_FROM: first_task_from} if first_task_from else {}),
                               keys.CURRENT: [end["C"] for end in phase_ends],
                               keys.CURRENT_TOP: [end["R_top"][end["task"]] for end in phase_ends],
                               keys.FORGETTING: []}
    if has_centre:
        summary[keys.CENTRE_CURRENT] = [end["R_centre"][end["task"]] for end in phase_ends]
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
            summary[keys.FORGETTING].append(row)
    if len(phase_ends) == len(phase_names):
        for level in ("pop", "top"):
            matrix = [[end[f"R_{level}"][name] for name in phase_names] for end in phase_ends]
            summary[keys.matrix(level)] = matrix
            summary.update(_transfer(matrix, [initial["pop"][name] for name in phase_names], level))
    if stability_gap is not None:
        summary[keys.STABILITY_GAP] = stability_gap
    if held_out:
        summary[keys.HELD_OUT] = held_out_summary(phase_names, held_out, held_out_episodes, archive)
    return summary


HELD_OUT_LEVELS = {"top": "top", "centre": "centre", "best-sample": "best_sample"}
"""The kinds of controller exported at a task end -> their suffix in the held-out block: the top
individual (the best by selection fitness, what one would deploy), and for an ES also the search
distribution's centre and the best sampled solution (the best by selection fitness among the
samples), each scored on its own."""
INITIAL = "initial"
"""The name of the generation-0 controllers (``initial-top``): the forward-transfer baseline."""
REFERENCE = "reference"
"""The kind of the controller a task end writes beside its top one where the regulariser has a
reference (``task1-green-reference``): the one that task's last generation was regularised
against (``networks``). It is no phase's own controller, so it is never scored on held-out
episodes (``parse_controller_key`` does not name it)."""


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


def held_out_summary(phase_names: list[str], scores: dict[str, dict[str, float]], episodes: int,
                     archive: bool = False) -> dict[str, Any]:
    """summary.json's ``held_out`` block from the held-out scores of the exported controllers
    (``{"task<i>-<task>-<kind>": {task: score}}``, ``"initial-<kind>"`` for generation 0): the
    scores themselves, then per kind of controller (top; for an ES also centre and best sample)
    its C per finished phase, a forgetting row per earlier task at each later task end (C, R and
    F of that kind, as the training rows define them) and, once every phase has ended, the R
    matrix and ACC/BWT/FWT (FWT's baseline: the generation-0 controller of that kind, where it
    was scored). ``archive`` (a run with a skill archive): the archived controllers, each task's
    top controller at its latest finished end, with their scores on their own task
    (``archive``) and the mean of those scores over the tasks (``archive_mean``)."""
    finished = 0
    while finished < len(phase_names) and controller_key(finished, phase_names[finished], "top") in scores:
        finished += 1
    ordered = {key: scores[key] for key in sorted(scores, key=_controller_order)}  # the same bytes however scored
    keys = SummaryLayout
    block: dict[str, Any] = {keys.EPISODES: episodes, keys.PHASES: phase_names[:finished], keys.SCORES: ordered}
    kinds = [kind for kind in HELD_OUT_LEVELS
             if all(controller_key(i, phase_names[i], kind) in scores for i in range(finished))] if finished else []
    for kind in kinds:
        level = HELD_OUT_LEVELS[kind]
        block[f"current_{level}"] = [scores[controller_key(i, phase_names[i], kind)][phase_names[i]] for i in range(finished)]
    block[keys.FORGETTING] = []
    for i in range(finished):
        for earlier in _earlier_tasks(phase_names, i):
            s = max(j for j in range(i) if phase_names[j] == earlier)
            row: dict[str, Any] = {"at_end_of": i, "task": earlier}
            for kind in kinds:
                level = HELD_OUT_LEVELS[kind]
                kept = scores[controller_key(s, phase_names[s], kind)][earlier]
                now = scores[controller_key(i, phase_names[i], kind)][earlier]
                row.update({f"C_{level}": kept, f"R_{level}": now, f"F_{level}": kept - now})
            block[keys.FORGETTING].append(row)
    if finished == len(phase_names):
        for kind in kinds:
            level = HELD_OUT_LEVELS[kind]
            matrix = [[scores[controller_key(i, phase_names[i], kind)][name] for name in phase_names]
                      for i in range(finished)]
            block[keys.matrix(level)] = matrix
            initial = scores.get(controller_key(None, None, kind))
            transfer = _transfer(matrix, [initial[name] for name in phase_names] if initial else None, level)
            block.update(transfer)
    if archive and finished:
        latest = {name: i for i, name in enumerate(phase_names[:finished])}  # each task's last finished phase
        block[keys.ARCHIVE] = {name: {"controller": controller_key(i, name, "top"),
                                      "score": scores[controller_key(i, name, "top")][name]}
                               for name, i in latest.items()}
        block[keys.ARCHIVE_MEAN] = sum(kept["score"] for kept in block[keys.ARCHIVE].values()) / len(latest)
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
        return {SummaryLayout.transfer("ACC", level): acc, SummaryLayout.transfer("BWT", level): None,
                SummaryLayout.transfer("FWT", level): None}
    bwt = sum(matrix[T - 1][j] - matrix[j][j] for j in range(T - 1)) / (T - 1)
    fwt = None if baseline is None else sum(matrix[j - 1][j] - baseline[j] for j in range(1, T)) / (T - 1)
    return {SummaryLayout.transfer("ACC", level): acc, SummaryLayout.transfer("BWT", level): bwt,
            SummaryLayout.transfer("FWT", level): fwt}


CURRENT_COLUMNS = {"pop": "best", "top": "top", "centre": "centre"}
"""A retention level -> the metrics.csv column of the same level's score on the current task."""


def stability_gap(rows: list[dict[str, str]], phase_names: list[str], window: int) -> list[dict[str, Any]]:
    """summary.json's ``stability_gap`` block from metrics.csv ``rows`` (as ``csv.DictReader``
    yields them) of a run on the schedule ``phase_names``: for each switch to a phase k >= 1 that
    the rows reach and each earlier task u (``_earlier_tasks``), one entry with ``after_switch_to``
    (k), ``task`` (u), ``window`` (the generations among phase k's first ``window`` in which u was
    scored) and per level (pop, top; centre where the run has its column):

    - ``before_<level>``: u's score at the last generation of phase k-1; for phase k-1's own task
      the current-task column (``CURRENT_COLUMNS``), for another task its retention cell, which a
      task end always fills (None where the cell is empty: a run from before the ``top`` column);
    - ``min_<level>``, ``generation_<level>``: the lowest retention of u over the
      ``generation_in_task`` 0 .. ``window`` - 1 of phase k (empty cells skipped) and the global
      generation of the first such minimum;
    - ``gap_<level>``: before - min, positive for a dip (None where either is).

    A (switch, task) pair without any retention value in the window has no entry."""

    by_phase: dict[int, list[dict[str, str]]] = {}
    for row in rows:
        by_phase.setdefault(int(row["task_index"]), []).append(row)
    columns = set(rows[0]) if rows else set()
    entries: list[dict[str, Any]] = []
    for k in range(1, len(phase_names)):
        if k not in by_phase or k - 1 not in by_phase:
            continue
        before_row = max(by_phase[k - 1], key=lambda row: int(row["generation"]))
        opening = sorted((row for row in by_phase[k] if int(row["generation_in_task"]) < window),
                         key=lambda row: int(row["generation"]))
        for task in _earlier_tasks(phase_names, k):
            kept = {level: retention_column(level, task) for level in CURRENT_COLUMNS
                    if retention_column(level, task) in columns}
            covered = sum(any(row[column] for column in kept.values()) for row in opening)
            if not covered:
                continue
            entry: dict[str, Any] = {"after_switch_to": k, "task": task, "window": covered}
            for level, column in kept.items():
                cell = before_row.get(CURRENT_COLUMNS[level] if task == phase_names[k - 1] else column, "")
                before = float(cell) if cell else None
                measured = [(float(row[column]), int(row["generation"])) for row in opening if row[column]]
                # min keeps the first of equal values, and ``opening`` runs in generation order
                low, at = min(measured, key=lambda pair: pair[0]) if measured else (None, None)
                entry.update({f"before_{level}": before, f"min_{level}": low, f"generation_{level}": at,
                              f"gap_{level}": None if before is None or low is None else before - low})
            entries.append(entry)
    return entries


CURRENT_LEVELS = {"pop": "best", "top": "top"}
"""A level of the current task's score -> its metrics.csv column."""


def current_curve(rows: list[dict[str, str]], level: str = "pop") -> list[float | None]:
    """The current task's score per metrics.csv row (None where there is none): the ``best``
    (pop) or ``top`` column; but in a phase where the current task's own retention cells are
    filled, as a run whose training mixes tasks writes them (its ``best`` and ``top`` are the
    mixture's: docs/metrics.md, Baselines), those cells alone."""
    own_phases = {row["task_index"] for row in rows if row.get(retention_column(level, row["task"]))}
    return [_number(row.get(retention_column(level, row["task"]) if row["task_index"] in own_phases
                            else CURRENT_LEVELS[level], "")) for row in rows]


def phase_start_scores(rows: list[dict[str, str]], level: str = "pop") -> dict[int, float]:
    """Per phase k >= 1 in metrics.csv ``rows``, the current task's score (``current_curve``) in
    the phase's first generation: what the population (pop: its best) or its top individual (top)
    brings to the task before any selection on it, an archived controller put back included.
    A phase whose first generation has no score of its own (a blend's) has none."""
    starts: dict[int, float] = {}
    for row, value in zip(rows, current_curve(rows, level)):
        k = int(row["task_index"])
        if k >= 1 and row["generation_in_task"] == "0" and value is not None:
            starts[k] = value
    return starts


def _number(cell: str) -> float | None:
    return float(cell) if cell else None


def forward_transfer_area(rows: list[dict[str, str]], scratch_rows: list[dict[str, str]], phases: int
                          ) -> dict[int, float]:
    """FT_area_k per phase k in 1 .. ``phases`` - 1 (the phases both runs have ended): the mean
    over phase k's generations of C(g) - C_scratch(g), C the run's ``current_curve`` (the ``best``
    column, or a mixed run's own cells) from its metrics.csv ``rows`` and C_scratch that of
    ``scratch_rows``, a from-scratch run of the same configuration and seed (``from_scratch``:
    the optimiser starts afresh at every task end), at the same ``generation_in_task``; over the
    generations both have. Reward units, not normalised; positive where what the run carried
    over from earlier tasks helped it on phase k."""
    def curves(table: list[dict[str, str]]) -> dict[int, dict[int, float]]:
        found: dict[int, dict[int, float]] = {}
        for row, value in zip(table, current_curve(table)):
            if value is not None:
                found.setdefault(int(row["task_index"]), {})[int(row["generation_in_task"])] = value
        return found

    mine, theirs = curves(rows), curves(scratch_rows)
    areas: dict[int, float] = {}
    for k in range(1, phases):
        shared = sorted(mine.get(k, {}).keys() & theirs.get(k, {}).keys())
        if shared:
            areas[k] = sum(mine[k][g] - theirs[k][g] for g in shared) / len(shared)
    return areas
