"""The lifelong loop: for each task of the schedule, for each generation, ask, evaluate on the
current task (and on earlier tasks every few generations, in the same batched call), regularise,
tell, record; a checkpoint at intervals and at every task end.

The functional regulariser (``--regulariser functional``) is the loop's, not the optimiser's: the
optimiser is built at lambda 0, its latest reference (``Optimizer.reference_export``) plays beside
the population in the same evaluation (``evaluate.BesideReference``), and the selection fitness is
the fitness less lambda times that penalty; at lambda 0 the reference does not play.

The baselines of docs/metrics.md change only what a generation trains on
(``schedule.training_episodes``: rehearsal, joint, blends), when the regulariser takes its
reference (``reference_every``) and whether the optimiser starts afresh at a task end
(``from_scratch``); the skill archive (``archive``) keeps each task's top controller at its end
and puts it back into the population (``Optimizer.adopt``) at the start of a phase whose task
returns after another one, so a checkpoint holds it. The stability gap's scores of earlier
tasks, in the first ``gap_window`` generations after a switch, are played on episodes of their
own, so that they never change the run's training numbers.

A run continues bit for bit from a checkpoint (``--resume``): everything random comes from the
optimiser's state and the run's one torch generator, both checkpointed; recorded episodes draw
from seeds of their own.

``lifelong`` is the loop itself, a generator that hands out each generation's evaluation and is
sent its fitness; ``run`` plays it alone, ``run_together`` plays several runs in step, their
evaluations in one environment batch per generation (``evaluate_together``), each run with its own
optimiser, random streams, run directory and checkpoints, and its numbers the same as alone.
"""
from __future__ import annotations

import hashlib
import math
import shutil
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Generator, Iterator, Sequence

import torch

from algorithms import ExportError, check_export, make_optimizer, policy_from_export
from algorithms.base import FUNCTIONAL
from envs import numerics

from . import checkpoint
from .config import RunConfig, check_device
from .episodes import play_episodes
from .errors import RunDirError
from .evaluate import BesideReference, Evaluation, evaluate, evaluate_together, update_threads
from .held_out import score_controllers
from .metrics import (INITIAL, REFERENCE, FitnessStats, GenerationRecord, Retention, controller_key, retention,
                      stability_gap, summarise)
from .metrics_csv import GenerationLog, MetricsLayout, check_continuable, logged_generations, read_metrics, spans
from .networks import task_end_view
from .progress import Progress
from .provenance import ARITHMETIC_FIELDS, machine, same_native_arithmetic
from .recording import Recorder
from .rundir import ResumeError, RunDir
from .schedule import Phase, distinct_tasks, training_episodes


@dataclass
class LoopState:
    """What the loop carries from one generation to the next (all of it is checkpointed)."""

    generation: int = 0
    """Generations completed so far (global)."""
    phase_ends: list[dict[str, Any]] = field(default_factory=list)
    """Per finished phase: its task, C and the retention on every task of the schedule."""
    initial: dict[str, dict[str, float]] = field(default_factory=dict)
    """The fresh population's scores on every task (the forward-transfer baseline)."""
    held_out: dict[str, dict[str, float]] = field(default_factory=dict)
    """Every exported controller's held-out score on every task (``held_out.score_controllers``)."""
    first_task_from: str = ""
    """The run whose first task this one took over (``start_from``), if any."""
    archive: dict[str, dict[str, Any]] = field(default_factory=dict)
    """The skill archive (``archive``): each finished task's top controller at its latest end, by task."""
    wall_time_s: float = 0.0
    machines: list[dict[str, Any]] = field(default_factory=list)
    """The machines the run's generations ran on (``provenance.machine``), each with the generation from
    which it ran them: one entry per change of machine, so a run resumed where it ran has one."""


Lifelong = Generator[Evaluation, torch.Tensor, dict[str, Any]]
"""A run in progress: yields each generation's evaluation, is sent its fitness ``(tasks, population)``
and returns the summary."""


def run(config: RunConfig, run_dir: RunDir, *, resume: bool = False, overwrite: bool = False,
        recorder: Recorder | None = None, progress: str | None = None,
        start_from: RunDir | None = None) -> dict[str, Any]:
    """Run (or continue) the lifelong experiment ``config`` into ``run_dir``; returns the summary.
    ``progress``: a ``progress.MODES`` display on stderr, None for the stream's default;
    ``start_from``: a run whose first task this one shares (``lifelong``)."""
    return run_alone(lifelong(config, run_dir, resume=resume, overwrite=overwrite, recorder=recorder,
                              progress=progress, start_from=start_from))


def run_alone(steps: Lifelong) -> dict[str, Any]:
    """Play one run (a ``lifelong`` generator) to its end, each evaluation on its own; returns the summary."""
    try:
        evaluation = next(steps)
        while True:
            evaluation = steps.send(evaluation.run())
    except StopIteration as finished:
        return finished.value
    finally:
        steps.close()  # interrupted between generations: the loop closes its logs and recording


def run_together(runs: Sequence[Lifelong], after_generation: Callable[[int], None] | None = None
                 ) -> Iterator[tuple[int, dict[str, Any] | Exception]]:
    """Play several runs (``lifelong`` generators) in step, each generation's evaluations in one
    environment batch; yields ``(index, summary)`` as each run finishes, or ``(index, error)``
    where one fails (the others go on). ``after_generation(runs still going)`` is called after
    each generation (for a status line)."""
    pending: dict[int, Evaluation] = {}
    try:
        for index, steps in enumerate(runs):
            outcome = _advance(steps, None)
            if isinstance(outcome, Evaluation):
                pending[index] = outcome
            else:
                yield index, outcome
        while pending:
            indices = list(pending)
            for index, fitness in zip(indices, evaluate_together([pending[i] for i in indices])):
                outcome = _advance(runs[index], fitness)
                if isinstance(outcome, Evaluation):
                    pending[index] = outcome
                else:
                    del pending[index]
                    yield index, outcome
            if after_generation is not None:
                after_generation(len(pending))
    finally:
        for steps in runs:
            steps.close()


def _advance(steps: Lifelong, fitness: torch.Tensor | None) -> Evaluation | dict[str, Any] | Exception:
    """The run's next evaluation after ``fitness`` (None: its first), or its summary once it ends,
    or the error that stopped it."""
    try:
        return steps.send(fitness)
    except StopIteration as finished:
        return finished.value
    except Exception as error:  # noqa: BLE001 - run_together reports it; the other runs go on
        return error


def lifelong(config: RunConfig, run_dir: RunDir, *, resume: bool = False, overwrite: bool = False,
             recorder: Recorder | None = None, progress: str | None = None,
             start_from: RunDir | None = None) -> Lifelong:
    """The lifelong loop of ``run``, as a generator that yields each generation's ``Evaluation``
    and is sent its fitness. ``start_from``: a new run takes over that run's first task, up to and
    including its end (``shares_first_task``), and goes on from there."""
    check_device(config.device)  # a resumed run or a sweep's trial may land on a machine without it
    torch.set_num_threads(config.threads)
    numerics.use(config.numerics)
    phases = config.phases()
    phase_names = [p.name for p in phases]
    tasks = distinct_tasks(phases)
    env_config = config.env_config()
    optimizer = _make_optimizer(config, env_config, config.seed)
    centre = optimizer.centre_index  # ES: the search distribution's centre
    generator = torch.Generator().manual_seed(config.seed)
    layout = MetricsLayout(tuple(t.name for t in tasks), species=config.algo == "neat", centre=centre is not None,
                           diagnostics=optimizer.diagnostics)
    # one writer per run directory: its lock is taken before anything is written and held to the finally below
    if resume:
        lock = run_dir.lock()
        state = _resume(config, run_dir, optimizer, generator, layout)
    else:
        state = LoopState()
        source = _first_task_of(start_from, config, run_dir) if start_from is not None else None
        lock = run_dir.create(overwrite)
        run_dir.write_config(config)
        if source is not None:
            state = _take_first_task(config, run_dir, start_from, source, optimizer, generator)
            if config.from_scratch and len(phases) > 1:  # what this run does at that end: start afresh
                optimizer = _make_optimizer(config, env_config, scratch_seed(config.seed, 1))
                run_dir.save_checkpoint(state.generation, _checkpoint_payload(config, optimizer, generator, state))
    here = machine(config.device)
    if not state.machines or {k: v for k, v in state.machines[-1].items() if k != "from_generation"} != here:
        if state.machines and config.numerics == "native" and not same_native_arithmetic(state.machines[-1], here):
            _warn_native_elsewhere(run_dir, state.machines[-1], here, state.generation)
        state.machines.append({"from_generation": state.generation, **here})
    log = GenerationLog(run_dir.path, layout, resumed_at=state.generation if resume or start_from else None)
    recorder = recorder or Recorder()
    display = Progress(sum(p.generations for p in phases), state.generation, mode=progress)
    started = time.monotonic() - state.wall_time_s
    functional = _FunctionalReference(config)

    def summary_now() -> dict[str, Any]:
        gap = stability_gap(read_metrics(run_dir.metrics), phase_names, config.gap_window) if config.gap_window else None
        return summarise(phase_names, state.phase_ends, state.initial, state.wall_time_s, centre is not None,
                         state.held_out, config.held_out_episodes, state.first_task_from, stability_gap=gap,
                         machines=state.machines, numerics=config.numerics, archive=config.archive)

    try:
        for generation, phase_index, in_task in _generations(phases, start=state.generation):
            phase = phases[phase_index]
            earlier = [t for t in tasks if t.name in phase_names[:phase_index] and t.name != phase.name]
            last = in_task == phase.generations - 1
            if in_task == 0 and phase_index > 0:
                recorder.log_drift(generation, phase_names[phase_index - 1], phase.name)
            training = training_episodes(phases, phase_index, in_task, config.evals, config.rehearsal, config.joint)
            mixed = len(training) > 1 or training[0][0].name != phase.name
            # the joint baseline reports every task's score in every generation, the others earlier tasks'
            reported = [t for t in tasks if t.name != phase.name] if config.joint else earlier
            if generation == 0 or last:
                # every task: R matrix, FWT baseline; where training mixes tasks, the current one's own score too
                others = [t for t in tasks if t.name != phase.name or mixed]
            elif config.joint or generation % config.retention_every == 0:
                others = reported
            else:
                others = []

            returns = in_task == 0 and phase_index > 0 and phase_names[phase_index - 1] != phase.name
            if returns and phase.name in state.archive:  # the task returns: its archived controller back
                optimizer.adopt(state.archive[phase.name])
            with update_threads(config.threads, config.eval_threads, config.numerics):
                policy = optimizer.ask()
            played = functional.beside(policy, optimizer)
            fitness = yield Evaluation(played, env_config, [task for task, _ in training] + others,
                                       [n for _, n in training] + [config.evals] * len(others), generator,
                                       config.device, compiled=config.compile, eval_threads=config.eval_threads,
                                       cuda_graphs=config.cuda_graphs, numerics=config.numerics)
            numerics.use(config.numerics)  # runs played in step (run_together) may compute otherwise
            raw = _mean_over_episodes(fitness[:len(training)], [n for _, n in training])
            penalty = played.penalty(sum(n for _, n in training)) if played is not policy else None
            regularised = optimizer.regularise(raw) if penalty is None else \
                (raw.double() - config.reg * penalty).to(raw.dtype)
            # the top individual is the one selection favours, as in the paper's code: with a
            # regulariser on, the best by regularised fitness, which is what one would deploy
            scores = {task.name: retention(fitness[len(training) + i], regularised, centre)
                      for i, task in enumerate(others)}
            own = [i for i, (task, _) in enumerate(training) if task.name == phase.name]
            if mixed and own and phase.name not in scores:  # the current task's share of the training episodes
                scores[phase.name] = retention(fitness[own[0]], regularised, centre)
            # where training mixes tasks, the current task's own score gets its retention cells
            current_cells = [phase.task] if mixed and phase.name in scores else []
            scores.setdefault(phase.name, retention(raw, regularised, centre))
            window = [t for t in earlier if t.name not in scores] if phase_index and in_task < config.gap_window else []
            if window:  # the stability gap's scores, on episodes of their own
                kept = evaluate(policy, env_config, window, config.evals, _gap_episodes(config.seed, generation),
                                config.device, compiled=config.compile, eval_threads=config.eval_threads,
                                cuda_graphs=config.cuda_graphs)
                scores.update({task.name: retention(kept[i], regularised, centre) for i, task in enumerate(window)})
            top = int(regularised.argmax())
            periodic = bool(config.episodes_every) and generation % config.episodes_every == 0
            # exported before tell, which replaces the asked population that export reads from; with
            # this generation's scores, which the optimiser has not been told yet
            exports = _exports(optimizer, raw, regularised, generation) if generation == 0 or last or periodic else {}
            exported = exports.get("top")
            with update_threads(config.threads, config.eval_threads, config.numerics):
                report = optimizer.tell(raw, regularised)
            if penalty is not None:  # the distance diagnostics are the penalty the selection used
                report.extra.update({name: value for name, value in (
                    ("distance_mean", penalty.mean().item()), ("distance_std", penalty.std(unbiased=False).item()))
                    if name in optimizer.diagnostics})

            record = GenerationRecord(
                task=phase.name, task_index=phase_index, generation=generation, generation_in_task=in_task,
                fitness=FitnessStats.of(raw), regularised=FitnessStats.of(regularised), top=raw[top].item(),
                retention={t.name: scores[t.name] for t in [*reported, *current_cells] if t.name in scores},
                species_sizes=report.species_sizes, centre=None if centre is None else raw[centre].item(),
                diagnostics=report.extra)
            log.write(record)
            recorder.log_generation(record)
            if generation == 0:  # scored on every task: the forward-transfer baseline
                state.initial = {level: {name: getattr(s, level) for name, s in scores.items()} for level in ("pop", "top")}
                initial = {controller_key(None, None, kind): controller for kind, controller in exports.items()}
                for name, controller in initial.items():
                    run_dir.write_controller(name, controller)
                state.held_out.update(score_controllers(initial, env_config, tasks, config.held_out_episodes))
            if (last or periodic) and recorder.wants_episodes:
                seen = [t for t in tasks if t.name in phase_names[:phase_index + 1]]
                _record_episodes(config, recorder, exported, seen, generation, phase_index, phase.name, env_config)
            if last:
                # after the task's last tell, from which end_task (below) takes the next reference: the
                # reference this generation was regularised against, written beside its top controller
                reference = optimizer.reference_export()
                _finish_phase(run_dir, optimizer, state, phase_index, phase.name, scores, exports, reference)
                state.held_out.update(score_controllers(
                    {controller_key(phase_index, phase.name, kind): controller for kind, controller in exports.items()},
                    env_config, tasks, config.held_out_episodes))
                if config.archive:
                    state.archive[phase.name] = exports["top"]
                if recorder.wants_episodes:
                    _record_network(config, recorder, exports["top"], reference, generation, phase_names, phase_index)
            # the regulariser's reference: at each task end, or boundary-free every reference_every generations
            if (generation + 1) % config.reference_every == 0 if config.reference_every else last:
                optimizer.end_task()
            state.generation = generation + 1
            state.wall_time_s = time.monotonic() - started
            # kept for runs that share this first task (start_from): its end as every run reaches it,
            # before what a baseline does there (from scratch: start afresh)
            first_task_end = _checkpoint_payload(config, optimizer, generator, state) if last and not phase_index else None
            if last and config.from_scratch and phase_index + 1 < len(phases):
                optimizer = _make_optimizer(config, env_config, scratch_seed(config.seed, phase_index + 1))
            display.update(generation, phase.name, phase_index + 1, len(phases), record.fitness.best,
                           {name: kept.pop for name, kept in record.retention.items()}, task_end=last)
            # after the task end: a run resumed from this checkpoint has the task's reference
            if last or state.generation % config.checkpoint_every == 0:
                payload = _checkpoint_payload(config, optimizer, generator, state)
                run_dir.save_checkpoint(state.generation, payload)
                if first_task_end is not None:
                    run_dir.save_first_task_end(first_task_end)
                run_dir.write_summary(summary_now())
        summary = summary_now()
        run_dir.write_summary(summary)
    finally:
        log.close()
        recorder.close()
        display.close()
        lock.release()
    return summary


def _make_optimizer(config: RunConfig, env_config, seed: int):
    """The run's optimiser; at lambda 0 under the functional regulariser, which the loop applies."""
    reg = 0.0 if config.regulariser == FUNCTIONAL else config.reg
    return make_optimizer(config.algo, obs_dim=env_config.obs_dim, population_size=config.population, seed=seed,
                          reg=reg, device=config.device, **config.algo_options)


def _warn_native_elsewhere(run_dir: RunDir, before: dict[str, Any], here: dict[str, Any], generation: int) -> None:
    """Say, once, on stderr, that a native-arithmetic run continues on another kind of machine:
    its numbers from ``generation`` on are this machine's, not those it would have had on the
    kind it last ran on (``before``)."""
    def kind(described: dict[str, Any]) -> str:
        return ", ".join(str(described[name]) for name in ARITHMETIC_FIELDS if name in described)
    print(f"warning: {run_dir.path} computes with --numerics native, whose numbers follow the machine: from "
          f"generation {generation} it continues on {kind(here)}, not {kind(before)}, so its numbers from there "
          f"are this machine's (summary.json's machines name both); resume it on {kind(before)} to keep its "
          "trajectory", file=sys.stderr, flush=True)


class _FunctionalReference:
    """The functional regulariser's reference as a policy, rebuilt only when the optimiser's
    reference (``Optimizer.reference_export``) changes. At lambda 0 it never plays: the penalty
    would weigh nothing, and the run is then the family's default-regulariser run at lambda 0,
    its distance diagnostics included (``compare`` holds them for one configuration)."""

    def __init__(self, config: RunConfig):
        self.on, self.device = config.regulariser == FUNCTIONAL and config.reg > 0, config.device
        self.exported: dict[str, Any] | None = None
        self.policy = None

    def beside(self, policy, optimizer):
        """``policy`` with the reference beside it (``evaluate.BesideReference``), or ``policy``
        itself where the regulariser is another, lambda is 0 or there is no reference yet."""
        exported = optimizer.reference_export() if self.on else None
        if exported is None:
            return policy
        if exported != self.exported:
            self.exported, self.policy = exported, policy_from_export(exported, self.device)
        return BesideReference(policy, self.policy)


def _seed_from(*parts: object, bits: int) -> int:
    """A seed of ``bits`` bits derived from ``parts`` (a hash: streams of different parts do not overlap)."""
    return int.from_bytes(hashlib.sha256(" ".join(map(str, parts)).encode()).digest()[:8], "big") >> (64 - bits)


def scratch_seed(seed: int, phase_index: int) -> int:
    """The from-scratch baseline's seed for the fresh population of phase ``phase_index``: from the
    run's seed and the phase alone, so that it does not depend on what came before."""
    return _seed_from("from-scratch", seed, phase_index, bits=32)


def _gap_episodes(seed: int, generation: int) -> torch.Generator:
    """The stability gap's episodes of one generation: a stream of their own, so that scoring them
    never shifts the run's (held-out seeds start at 2**63; these lie below)."""
    return torch.Generator().manual_seed(_seed_from("stability-gap", seed, generation, bits=63))


def _mean_over_episodes(fitness: torch.Tensor, counts: list[int]) -> torch.Tensor:
    """The mean reward over every training episode, from each task's mean and episode count."""
    if len(counts) == 1:
        return fitness[0]
    weights = torch.tensor(counts, dtype=fitness.dtype, device=fitness.device)[:, None]
    return (fitness * weights).sum(dim=0) / sum(counts)


def _generations(phases: list[Phase], start: int) -> Iterator[tuple[int, int, int]]:
    """(global generation, phase index, generation within the phase) from generation ``start`` on."""
    generation = 0
    for phase_index, phase in enumerate(phases):
        for in_task in range(phase.generations):
            if generation >= start:
                yield generation, phase_index, in_task
            generation += 1


def _exports(optimizer, raw: torch.Tensor, regularised: torch.Tensor, generation: int) -> dict[str, dict[str, Any]]:
    """The controllers exported at a task end (and at generation 0), by kind (``metrics.HELD_OUT_LEVELS``):
    the top individual, the best by selection fitness, and for an ES also the centre and the best
    sampled solution; each with the generation and its raw and selection fitness."""
    chosen = {"top": int(regularised.argmax())}
    centre = optimizer.centre_index
    if centre is not None:
        samples = regularised.clone()
        samples[centre] = -math.inf
        chosen.update({"centre": centre, "best-sample": int(samples.argmax())})
    return {kind: {**optimizer.export(index), "generation": generation, "fitness": raw[index].item(),
                   "selection_fitness": regularised[index].item()} for kind, index in chosen.items()}


def _finish_phase(run_dir: RunDir, optimizer, state: LoopState, phase_index: int, name: str,
                  scores: dict[str, Retention], exports: dict[str, dict[str, Any]],
                  reference: dict[str, Any] | None) -> None:
    """Task end: record C and the retention on every task, and write the exported controllers
    (the top one also as the latest, final-top) and, where there is one, the regulariser's
    ``reference`` they were selected against (``networks``)."""
    end = {"task": name, "C": scores[name].pop,
           "R_pop": {n: s.pop for n, s in scores.items()}, "R_top": {n: s.top for n, s in scores.items()}}
    if optimizer.centre_index is not None:
        end["R_centre"] = {n: s.centre for n, s in scores.items()}
    state.phase_ends.append(end)
    for kind, controller in exports.items():
        run_dir.write_controller(controller_key(phase_index, name, kind), controller)
    run_dir.write_controller("final-top", exports["top"])
    if reference is not None:
        run_dir.write_controller(controller_key(phase_index, name, REFERENCE), reference)


def _record_episodes(config, recorder, exported, tasks, generation, phase_index, name, env_config) -> None:
    """One episode of the current top individual on each task seen so far, for the recording."""
    policy = policy_from_export(exported, config.device)
    seed = config.seed * 1_000_003 + generation  # its own stream: recording never shifts the run's
    for task in tasks:
        episode = play_episodes(policy, env_config, task, [seed], config.device)[0]
        recorder.log_episode(generation, phase_index, name, task, episode)


def _record_network(config, recorder, top, reference, generation, phase_names, phase_index) -> None:
    """The task end's top controller against the reference written beside it (``networks``): the
    controllers of the files ``plot`` draws from."""
    name = phase_names[phase_index]
    controllers = {controller_key(phase_index, name, "top"): top}
    if reference is not None:
        controllers[controller_key(phase_index, name, REFERENCE)] = reference
    recorder.log_network(generation, task_end_view(config.to_dict(), phase_names, phase_index, controllers))


def _checkpoint_payload(config, optimizer, generator, state) -> dict[str, Any]:
    return {"config": config.to_dict(), "optimizer": optimizer.state_dict(), "generator": generator.get_state(),
            "loop": {"generation": state.generation, "phase_ends": state.phase_ends, "initial": state.initial,
                     "held_out": state.held_out, "first_task_from": state.first_task_from,
                     "wall_time_s": state.wall_time_s, "machines": state.machines, "archive": state.archive}}


def check_start_from(config: RunConfig, run_dir: RunDir, source: RunDir) -> None:
    """ResumeError, before anything is written, unless a run of ``config`` into ``run_dir`` may
    take over ``source``'s first task: ``source`` is another run directory than ``run_dir``, by any
    path, and not inside it (``--overwrite`` would empty it before it is read), keeps its first
    task's end, and the two differ in nothing that changes a number before that end
    (``RunDir.first_task_differences``): lambda, which no optimiser uses before its first
    reference (taken at that task end, whatever lambda is), the regulariser and the options that act
    only from there, and the baselines that start there."""
    if source.is_same_directory(run_dir):
        raise ResumeError(f"--start-from {source.path} is the run directory this run writes ({run_dir.path}): "
                          "a run cannot take over its own first task (--overwrite would delete it before it is "
                          "read): give this run another --name, or --out")
    if run_dir.path.resolve() in source.path.resolve().parents:
        raise ResumeError(f"--start-from {source.path} lies inside the run directory this run writes "
                          f"({run_dir.path}), which --overwrite would empty before it is read: give this run "
                          "another --name, or --out")
    different = source.first_task_differences(config.to_dict())
    if different:
        raise ResumeError(f"--start-from {source.path}: that run differs from this one in settings that act "
                          f"before its first task's end ({'; '.join(different)}), so its first task is not this "
                          "run's: start this run without --start-from")
    path = source.first_task_end
    if not path.is_file():
        raise ResumeError(f"--start-from {source.path}: it keeps no checkpoint of its first task's end ({path} "
                          "is missing: it has not reached it, or was made before runs kept it): start this run "
                          "without --start-from")


def _first_task_of(source: RunDir, config: RunConfig, run_dir: RunDir) -> tuple[dict[str, Any], dict[str, Any]]:
    """The checkpoint of ``source``'s first task end and the controllers of that task, once checked
    (``check_start_from``) that a run of ``config`` into ``run_dir`` may start from it: all read,
    and refused where damaged, before the new run directory is made."""
    check_start_from(config, run_dir, source)
    payload = checkpoint.load(source.first_task_end)
    # written by a run resumed after a default changed, it holds the values the run recorded
    if RunConfig.outcome_settings(source.with_recorded_defaults(payload.get("config") or {})) != \
            RunConfig.outcome_settings(source.with_recorded_defaults(source.read_config().to_dict())):
        raise ResumeError(f"--start-from {source.path}: its {source.first_task_end.name} belongs to another "
                          "configuration than its config.json: restore the file from a copy of that run, or start "
                          "this run without --start-from")
    generations = payload["loop"]["generation"]
    for log in (source.metrics, source.species) if config.algo == "neat" else (source.metrics,):
        held = logged_generations(log)
        missing = [g for g in range(generations) if g not in held]
        if missing:
            raise RunDirError(f"--start-from {source.path}: its {log.name} has no rows for generation(s) "
                              f"{spans(missing)}, which its first task covers: restore it from a copy of that run, "
                              "or start this run without --start-from")
    first = config.phases()[0].name
    controllers = {name: exported for name, exported in source.read_controllers().items()
                   if name.startswith((f"{INITIAL}-", f"task0-{first}-"))}
    top = controller_key(0, first, "top")
    if top not in controllers:
        raise RunDirError(f"{source.controllers} has no {top}.json, the first task's top controller this run "
                          "takes over: restore it from a copy of the run, or run without --start-from")
    return payload, controllers


def _take_first_task(config: RunConfig, run_dir: RunDir, source: RunDir,
                     first_task: tuple[dict[str, Any], dict[str, Any]], optimizer, generator) -> LoopState:
    """Make ``run_dir`` hold ``source``'s first task (``_first_task_of``) as its own (metrics and
    species rows, controllers, a checkpoint of this run's configuration at the task's end) and load
    that state."""
    payload, controllers = first_task
    top = controllers[controller_key(0, config.phases()[0].name, "top")]
    # the archive as this run keeps it at that end, whether or not the source kept one
    own = {**payload, "config": config.to_dict(),
           "loop": {**payload["loop"], "first_task_from": str(source.path.resolve()),
                    "archive": {config.phases()[0].name: top} if config.archive else {}}}
    state = _load_state(own, optimizer, generator)
    for log in ("metrics", "species"):
        if getattr(source, log).is_file():
            shutil.copyfile(getattr(source, log), getattr(run_dir, log))  # GenerationLog cuts it to the task
    for name, exported in controllers.items():
        run_dir.write_controller(name, exported)
    run_dir.write_controller("final-top", top)
    run_dir.save_checkpoint(state.generation, own)
    run_dir.save_first_task_end(own)
    return state


def _load_state(payload: dict[str, Any], optimizer, generator) -> LoopState:
    """Restore the optimiser and the run's generator from a checkpoint payload; the loop's state."""
    optimizer.load_state_dict(payload["optimizer"])
    generator.set_state(payload["generator"])
    loop = payload["loop"]
    # a checkpoint written before held-out scoring (or the machines' record, or the archive) existed has none
    return LoopState(generation=loop["generation"], phase_ends=loop["phase_ends"], initial=loop["initial"],
                     held_out=loop.get("held_out", {}), first_task_from=loop.get("first_task_from", ""),
                     wall_time_s=loop["wall_time_s"], machines=loop.get("machines", []),
                     archive=loop.get("archive", {}))


def _resume(config: RunConfig, run_dir: RunDir, optimizer, generator, layout: MetricsLayout) -> LoopState:
    """The state ``run_dir``'s newest checkpoint holds, loaded; refused (ResumeError, RunDirError)
    where config is not the run's own, the checkpoint is damaged or another configuration's, or
    the logs cannot be continued from it without losing a row (``check_continuable``)."""
    run_dir.continuation(config.to_dict())  # ResumeError unless config is the run's own
    found = run_dir.checkpoint_files()
    first_checkpoint = min(config.checkpoint_every, config.phases()[0].generations)
    if not found:
        check_continuable(run_dir.path, layout, 0, first_checkpoint)
        print(f"note: no checkpoint in {run_dir.checkpoints}: resuming from generation 0", file=sys.stderr)
        return LoopState()
    path = found[-1]
    try:
        payload = checkpoint.load(path)
    except checkpoint.CorruptCheckpointError as error:
        raise checkpoint.CorruptCheckpointError(f"{error}; {_damaged_checkpoint_advice(found, layout)}") from None
    if "pickle" in (payload.get("optimizer") or {}):
        raise checkpoint.older_version_error(path)
    # a checkpoint written before a default changed holds the options as given: both resolved as the run did
    if RunConfig.outcome_settings(run_dir.with_recorded_defaults(payload.get("config") or {})) != \
            RunConfig.outcome_settings(run_dir.with_recorded_defaults(config.to_dict())):
        raise ResumeError(f"checkpoint {path} belongs to another configuration: delete it or start a new run")
    problem = _archive_problem((payload.get("loop") or {}).get("archive", {}), config)
    if problem:
        raise checkpoint.CorruptCheckpointError(f"checkpoint {path} is damaged ({problem}); "
                                                f"{_damaged_checkpoint_advice(found, layout)}")
    state = _load_state(payload, optimizer, generator)
    check_continuable(run_dir.path, layout, state.generation, first_checkpoint)
    return state


def _archive_problem(archive: Any, config: RunConfig) -> str | None:
    """What is wrong with a checkpoint's skill archive (its loop's ``archive``: each task of the
    schedule by name, with the top controller kept at its end, as exported), or None: the run puts
    an archived controller back into its population when its task returns."""
    if not isinstance(archive, dict):
        return f"its archive is a {type(archive).__name__}, not an object of controllers by task"
    tasks = {task.name for task in distinct_tasks(config.phases())}
    obs_dim = config.env_config().obs_dim
    for name, exported in archive.items():
        if name not in tasks:
            return f"its archive holds a controller for {name!r}, no task of the schedule"
        try:
            check_export(exported, obs_dim)
        except ExportError as error:
            return f"its archived controller for {name!r} is no controller of this run: {error}"
    return None


def _damaged_checkpoint_advice(found: list[Path], layout: MetricsLayout) -> str:
    """What to do when the newest of the checkpoints ``found`` (oldest first) is damaged: delete
    it, and any damaged one before it, to resume from the newest that can be read; with none
    readable, delete them all and the logs (``layout.files``, which no checkpoint rebuilds now)
    to resume from generation 0 (first-task-end.pt is no checkpoint ``--resume`` reads, and is
    kept for the runs that start from it)."""
    *earlier, newest = found
    damaged = [newest]
    for candidate in reversed(earlier):
        try:
            checkpoint.load(candidate)
        except checkpoint.CheckpointError:
            damaged.insert(0, candidate)
            continue
        if len(damaged) == 1:
            return f"delete it to resume from {candidate.name}, the checkpoint before it"
        return (f"{_names(damaged[:-1])} before it cannot be read either: delete {_names(damaged)} to resume from "
                f"{candidate.name}")
    if len(damaged) == 1:
        return f"no earlier checkpoint is left: delete {_names(['it', *layout.files])} to resume from generation 0"
    return (f"{_names(damaged[:-1])} before it cannot be read either, so no checkpoint is left: delete "
            f"{_names([*damaged, *layout.files])}, and --resume starts again from generation 0")


def _names(paths: list[Path | str]) -> str:
    """``a.pt``, ``a.pt and b.pt``, ``a.pt, b.pt and c.pt`` (of a path, its name)."""
    names = [getattr(path, "name", path) for path in paths]
    return names[0] if len(names) == 1 else f"{', '.join(names[:-1])} and {names[-1]}"
