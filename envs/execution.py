"""How a ``ForagingEnv``'s step runs: eagerly, compiled with ``torch.compile``, or in place in fixed
buffers that a CUDA graph replays. None of it changes a rule (those are ``envs/foraging.py``'s).

The rules give the step as three phases over the batch-last ``Arena``: ``_move_and_reach`` (the
robots move and each reaches at most one box), ``_resolve_conflicts`` (robots that reach one
cell) and ``_settle_and_sense`` (picks, drops, rewards, respawns, counters, observations).
``StepExecution``, which ``ForagingEnv`` inherits, runs them in that order:

- **plain** (the default): each step makes new state tensors; it reads back to the host whether
  two robots reach one cell and, eagerly, whether anybody drops, to skip the work those rare
  events need;
- **compiled** (``compile``): the first and last phase become two ``torch.compile`` graphs, the
  rare conflict resolution runs eagerly between them;
- **in place** (``graph_step``): the state lives in fixed buffers that each step overwrites, and
  nothing waits for the device (conflicts always resolved, dropped boxes always respawned: exact
  no-ops where nothing happens), so that a CUDA graph can record the step once and replay it.

Contract: the in-place step and its graph give the plain step's numbers bit for bit; from one
state, the compiled step gives the plain step's events and rewards, and its floats to rounding
(docs/environment.md, "Compiling"). The class that inherits this one defines the three phases,
``config``, ``device`` and ``_arena`` (the current ``Arena``, None before the first reset); it
stores every new state through ``_start``, steps through ``_run_step`` and, in
``_settle_and_sense``, asks ``_must_respawn`` whether to run the respawn.
"""
from __future__ import annotations

import functools
import threading
from dataclasses import replace
from typing import Callable

import torch
import torch._dynamo

from .config import ConfigError
from .sensing import batch_first
from .state import Arena

_CAPTURE_LOCK = threading.Lock()
COMPILED_BATCH_SIZES = 1024
"""Batch sizes for which a process may compile the step; more is an error (dynamo's default: 8)."""
GRAPH_WARM_UP_STEPS = 3
"""Steps run (and undone) before a CUDA graph is captured: capture needs warmed-up kernels."""


def compile_every_batch_size() -> None:
    """Let the step compile for up to ``COMPILED_BATCH_SIZES`` batch sizes, and make going past
    that an error, in the calling thread: ``torch._dynamo.config``'s settings are the thread's
    own (each one a context variable), and a new thread starts from dynamo's defaults.

    By default dynamo compiles a function for at most 8 input shapes, counted over the whole
    process, and then runs further shapes eagerly, with only a warning. Eager rounds some floats
    differently from the compiled step, so an evaluation's numbers would depend on which batch
    sizes the process had met before: a run resumed in a fresh process, or a sweep trial that
    follows another in the same worker, could score a generation differently from the same run
    played straight through. (NEAT under 0.92's genetics meets about ten batch sizes: its
    population drifts around ``pop_size``, and retention and held-out evaluations add more.)"""
    dynamo = torch._dynamo.config
    dynamo.recompile_limit = max(dynamo.recompile_limit, COMPILED_BATCH_SIZES)
    # both graphs of the step count against the process's total
    dynamo.accumulated_recompile_limit = max(dynamo.accumulated_recompile_limit, 2 * COMPILED_BATCH_SIZES)
    dynamo.fail_on_recompile_limit_hit = True


def in_every_thread(compiled: Callable) -> Callable:
    """``compiled`` (a ``torch.compile`` function) called with ``compile_every_batch_size``'s
    settings in force in whichever thread calls it. An environment compiled in one thread and
    stepped in another (an evaluation thread of a later generation, a sweep's next trial) would
    otherwise meet that thread's defaults: a ninth batch size would run eagerly, silently."""
    @functools.wraps(compiled)
    def call(*args, **kwargs):
        dynamo = torch._dynamo.config
        if not (dynamo.fail_on_recompile_limit_hit and dynamo.recompile_limit >= COMPILED_BATCH_SIZES):
            compile_every_batch_size()
        return compiled(*args, **kwargs)
    return call


class StepExecution:
    """The ways of running ``ForagingEnv``'s step (see the module's docstring)."""

    _arena: Arena | None
    _in_place: bool = False
    """The state lives in fixed buffers that every step overwrites (``graph_step``)."""
    _capture: bool = False
    """The in-place step is recorded as a CUDA graph at its first step and replayed from then on."""
    _graph: torch.cuda.CUDAGraph | None = None
    _graph_wheels: torch.Tensor | None = None
    """The wheel speeds the CUDA graph reads: each step copies its own into them."""
    _graph_outputs: tuple | None = None
    """The step's outputs that the CUDA graph overwrites at each replay."""

    def compile(self) -> None:
        """Compile the step with ``torch.compile``, as the two fused graphs around the rare
        pick conflicts: moving and reaching, then settling and sensing (static shapes: each
        batch size compiles once, every one of them, whichever thread steps it:
        ``in_every_thread``). Observations outside ``step`` stay eager.

        The graphs run under inductor's C++ wrapper, which releases the GIL: several Python
        threads, each stepping its own environment, then run in parallel (see
        ``lifelong_evo.evaluate``)."""
        # every gather index is clamped into range, so inductor's per-element index checks can go
        options = {"assert_indirect_indexing": False, "cpp_wrapper": True}
        self._move_and_reach = in_every_thread(torch.compile(self._move_and_reach, dynamic=False, options=options))
        self._settle_and_sense = in_every_thread(torch.compile(self._settle_and_sense, dynamic=False,
                                                               options=options))
        self._graph = None  # a graph captured before would replay the eager step: capture again

    def graph_step(self, capture: bool | None = None) -> None:
        """Step so that a CUDA graph can replay the step: one launch instead of a few hundred
        small kernels. The state then lives in fixed buffers that every step overwrites in place
        (``reset`` copies into them), and nothing in the step waits for the device: pick
        conflicts are always resolved and dropped boxes always respawned, each an exact no-op
        where no agents collide and nobody drops. The numbers are the plain step's, bit for bit,
        and ``step`` still returns fresh tensors.

        ``capture`` (default: where the device is cuda) records the step as a CUDA graph at the
        first step after this call, and replays it from then on (one graph per environment, so
        one per batch shape, as with ``compile``; call ``compile`` first to capture the compiled
        step). ``capture=False`` runs the same in-place step without a graph, on any device."""
        if capture is None:
            capture = self.device.type == "cuda"
        if capture and self.device.type != "cuda":
            raise ConfigError(f"a CUDA graph needs a cuda device, not {self.device}: use graph_step(capture=False)")
        if self._arena is not None and not self._in_place:
            self._arena = self._arena.clone()
        self._in_place, self._capture, self._graph = True, capture, None

    def _start(self, arena: Arena) -> None:
        """Make ``arena`` (made by ``Arena.from_state``) the current state."""
        if self._in_place and self._arena is not None:
            self._arena.copy_(arena)  # the buffers a captured graph reads stay where they are
        else:
            # a copy: from_state shares some of the caller's tensors, which steps in place would change
            self._arena = arena.clone() if self._in_place else arena

    def _run_step(self, wheels: torch.Tensor):
        """One step in the chosen way; returns ``step``'s outputs as fresh tensors."""
        if not self._in_place:
            new, outputs = self._advance(wheels)
            self._arena = replace(self._arena, **new)
            return outputs
        if not self._capture:
            return _fresh(self._step_in_place(wheels))
        if self._graph is None:
            self._capture_graph(wheels)
        self._graph_wheels.copy_(wheels)
        self._graph.replay()
        return _fresh(self._graph_outputs)

    def _advance(self, wheels: torch.Tensor):
        """The rules' three phases on the current arena. Returns the changed arena fields and
        the step's outputs ``(observations, rewards, done, info)``."""
        a = self._arena
        ax, ay, heading, picked, nearest, wants, rank, top_rank = self._move_and_reach(
            wheels, a.ax, a.ay, a.heading, a.carrying, a.bx, a.by, a.present, a.done)
        # two agents reach one cell: rare, so resolved apart from the fused phases. In place the
        # top rank is not read back: every rank an agent can have is resolved (ranks that nobody
        # holds leave every pick as it is)
        top_rank = self.config.n_agents - 1 if self._in_place else int(top_rank)
        if top_rank > 0:
            picked = self._resolve_conflicts(nearest, wants, rank, top_rank, a.bx, a.by, a.present)
        observations, reward, arena, info = self._settle_and_sense(
            ax, ay, heading, picked, a.carrying, a.bx, a.by, a.color, a.present, a.target,
            a.steps, a.retrieved, a.done, a.respawn_key)
        return {"ax": ax, "ay": ay, "heading": heading, **arena}, (batch_first(observations), reward, arena["done"], info)

    def _must_respawn(self, dropping: torch.Tensor) -> bool:
        """Whether this step runs the respawn of dropped boxes (``dropping``: (A, B) bool).
        Eagerly, skipping it when nobody drops saves time; in a compiled graph the branch would
        split the graph, which costs more than the fused respawn; in place, nothing is read back
        to the host. (``is_compiling`` first: a compiled graph then never reads, nor guards on,
        ``_in_place``.)"""
        return torch.compiler.is_compiling() or self._in_place or bool(dropping.any())

    def _step_in_place(self, wheels: torch.Tensor):
        """The step without waiting for the device, writing the new state into the arena's own
        buffers; returns the step's outputs (fresh tensors only until the next step)."""
        new, (observations, reward, _, info) = self._advance(wheels)
        for name, value in new.items():
            getattr(self._arena, name).copy_(value)
        return observations, reward, self._arena.done, info

    def _capture_graph(self, wheels: torch.Tensor) -> None:
        """Record ``_step_in_place`` as a CUDA graph reading ``_graph_wheels`` and the arena's
        buffers. The warm-up steps before it (which compile a compiled step and settle the
        allocator, as capture requires) change the state, which is then put back. One capture
        at a time in a process: evaluation threads capture their environments one by one."""
        with _CAPTURE_LOCK:
            self._graph_wheels = wheels.clone()
            saved = self._arena.clone()
            side = torch.cuda.Stream(self.device)
            side.wait_stream(torch.cuda.current_stream(self.device))
            with torch.cuda.stream(side):
                for _ in range(GRAPH_WARM_UP_STEPS):
                    self._step_in_place(self._graph_wheels)
            torch.cuda.current_stream(self.device).wait_stream(side)
            self._arena.copy_(saved)
            graph = torch.cuda.CUDAGraph()
            # records the kernels without running them; thread-local, so that another evaluation
            # thread stepping its own environment meanwhile does not break the capture
            with torch.cuda.graph(graph, capture_error_mode="thread_local"):
                self._graph_outputs = self._step_in_place(self._graph_wheels)
            self._graph = graph


def _fresh(outputs):
    """Copies of a step's outputs (observations, rewards, done, info), which the in-place step
    and its graph overwrite at the next step."""
    observations, reward, done, info = outputs
    return observations.clone(), reward.clone(), done.clone(), {k: v.clone() for k, v in info.items()}
