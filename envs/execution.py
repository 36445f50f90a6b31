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
(docs/environment.md, "Compiling"). Compiling never ends a run: inductor keeps what it builds in a
folder of its own per torch version and CPU dispatch (``compile_cache_dir``), so that code built
for one dispatch is never loaded under another, and whatever fails while compiling or running
the compiled code makes the whole process run the step eagerly from then on, with one warning
line on stderr (``compiled_phase``). The class that inherits this one defines the three phases,
``config``, ``device`` and ``_arena`` (the current ``Arena``, None before the first reset); it
stores every new state through ``_start``, steps through ``_run_step`` and, in
``_settle_and_sense``, asks ``_must_respawn`` whether to run the respawn.
"""
from __future__ import annotations

import functools
import os
import re
import sys
import threading
from dataclasses import replace
from typing import Callable

import torch

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


CACHE_FOLDER_PREFIX = "lifelong-evo-"
"""The start of the name of every inductor cache folder ``compile_cache_dir`` chooses."""


def compile_cache_dir() -> str:
    """The folder inductor keeps this process's compiled step in: one per torch version, CPU
    dispatch (``torch.backends.cpu.get_cpu_capability()``) and ``ATEN_CPU_CAPABILITY`` setting,
    inside ``TORCHINDUCTOR_CACHE_DIR`` where that is set, else inside inductor's own per-user
    default (``/tmp/torchinductor_<user>``).

    Inductor's cache key leaves the dispatch out: a process under ``ATEN_CPU_CAPABILITY=default``
    (scalar code) found the step that an AVX-512 process had generated and compiled its vector
    code without the vector headers (``'at::vec' has not been declared``), and an AVX2 process
    that found AVX-512 code read garbage through it. Within one folder, inductor's own file locks
    make processes that compile at once safe (each build runs under a lock on its key). A folder
    chosen here and inherited through ``TORCHINDUCTOR_CACHE_DIR`` (by a sweep's workers, say)
    is replaced, not nested: a child under another dispatch gets its own sibling folder."""
    # imported here, as torch._dynamo through torch's lazy attribute: loading the compiler's
    # modules costs a process more than a second that an eager run never needs
    from torch._inductor.runtime.cache_dir_utils import default_cache_dir

    root = os.environ.get("TORCHINDUCTOR_CACHE_DIR") or default_cache_dir()
    root = os.path.abspath(root)
    if os.path.basename(root).startswith(CACHE_FOLDER_PREFIX):
        root = os.path.dirname(root)
    requested = os.environ.get("ATEN_CPU_CAPABILITY") or "unset"
    name = (f"{CACHE_FOLDER_PREFIX}torch-{torch.__version__}-{torch.backends.cpu.get_cpu_capability()}"
            f"-aten-{requested}")
    return os.path.join(root, re.sub(r"[^A-Za-z0-9._+-]", "_", name))


COMPILE_OPTIONS = {
    # every gather index is clamped into range, so inductor's per-element index checks can go
    "assert_indirect_indexing": False,
    # the C++ wrapper releases the GIL while the step runs, so evaluation threads step in parallel
    "cpp_wrapper": True,
}
"""Inductor's options for the step's two graphs."""

_fallback_lock = threading.Lock()
_compiling_failed: str | None = None
"""Why compiling the step failed in this process (one line); None while it has not."""


def compiled_phase(phase: Callable) -> Callable:
    """``phase`` (a phase of the step) compiled with ``torch.compile``, called with
    ``compile_every_batch_size``'s settings in force in whichever thread calls it, and run
    eagerly once compiling has failed in this process.

    The settings: an environment compiled in one thread and stepped in another (an evaluation
    thread of a later generation, a sweep's next trial) would otherwise meet that thread's
    defaults, and a ninth batch size would run eagerly, silently.

    The fallback: torch compiles lazily, at a phase's first call for each batch size, so this
    is where a compiler error, or a failure of the compiled code, shows. The call is then
    repeated eagerly; if that fails too, the failure is the step's own and is raised as it is.
    Otherwise every compiled phase of every environment in the process runs eagerly from then
    on, which gives ``--no-compile``'s numbers, and one warning line says so (one per process,
    however many evaluation threads failed at once)."""
    compiled = torch.compile(phase, dynamic=False, options=COMPILE_OPTIONS)

    @functools.wraps(phase)
    def call(*args, **kwargs):
        if _compiling_failed is None:
            dynamo = torch._dynamo.config
            if not (dynamo.fail_on_recompile_limit_hit and dynamo.recompile_limit >= COMPILED_BATCH_SIZES):
                compile_every_batch_size()
            try:
                return compiled(*args, **kwargs)
            except Exception as failure:  # noqa: BLE001 - whatever the compiler does, the eager step decides
                outputs = phase(*args, **kwargs)
                _run_eagerly_from_now_on(failure)
                return outputs
        return phase(*args, **kwargs)
    return call


def _run_eagerly_from_now_on(failure: Exception) -> None:
    """Make every compiled phase in this process run eagerly, and say so once, on stderr."""
    global _compiling_failed
    with _fallback_lock:
        if _compiling_failed is not None:
            return
        _compiling_failed = _one_line(failure)
    print(f"warning: compiling the step failed ({_compiling_failed}); running it eagerly, which gives "
          f"--no-compile's numbers, more slowly; --no-compile skips the attempt", file=sys.stderr, flush=True)


def _one_line(failure: BaseException) -> str:
    """The innermost error of ``failure`` as one line: its class and its message's first line, and
    for a compiler's error the first line of its output that names an error (``CppCompileError``
    keeps the compiler's output in ``output``; dynamo's wrappers keep theirs in ``inner_exception``)."""
    while isinstance(getattr(failure, "inner_exception", None), BaseException):
        failure = failure.inner_exception
    text = f"{type(failure).__name__}: {_first_line(str(failure))}".rstrip(": ")
    output = getattr(failure, "output", None)
    if isinstance(output, str) and output.strip():
        lines = [line for line in output.splitlines() if line.strip()]
        text += ": " + _first_line(next((line for line in lines if "error" in line), lines[0]))
    return text


def _first_line(text: str) -> str:
    return next((line.strip() for line in text.splitlines() if line.strip()), "")


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
        ``compiled_phase``). Observations outside ``step`` stay eager.

        The graphs run under inductor's C++ wrapper, which releases the GIL: several Python
        threads, each stepping its own environment, then run in parallel (see
        ``lifelong_evo.evaluate``). Inductor keeps them in ``compile_cache_dir()``, set here,
        before the first compile (torch compiles at the first step). If compiling fails, the
        step runs eagerly, with a warning (``compiled_phase``)."""
        os.environ["TORCHINDUCTOR_CACHE_DIR"] = compile_cache_dir()
        self._move_and_reach = compiled_phase(self._move_and_reach)
        self._settle_and_sense = compiled_phase(self._settle_and_sense)
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
            wheels, a.ax, a.ay, a.heading, a.carrying, a.bx, a.by, a.present, a.done, a.failed_robots, a.motor_gain)
        # two agents reach one cell: rare, so resolved apart from the fused phases. In place the
        # top rank is not read back: every rank an agent can have is resolved (ranks that nobody
        # holds leave every pick as it is)
        top_rank = self.config.n_agents - 1 if self._in_place else int(top_rank)
        if top_rank > 0:
            picked = self._resolve_conflicts(nearest, wants, rank, top_rank, a.bx, a.by, a.present)
        observations, reward, arena, info = self._settle_and_sense(
            ax, ay, heading, picked, a.carrying, a.bx, a.by, a.color, a.present, a.target,
            a.drop_zone, a.rewards, a.failed_robots, a.steps, a.retrieved, a.done, a.respawn_key)
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
