"""Will a run fit in memory? An upper estimate of the memory a run needs, and the check that
refuses, before anything is written, a run that this machine cannot hold.

A run holds, at its peak (one generation's evaluation of every task, at generation 0 and at each
task end):

- the process itself: Python, torch and the libraries, about 430 MiB on one
  machine and 690 MiB on another (counted as 900), and 400 MiB more while
  ``--compile`` compiles the step;
- every environment played at once: ``controllers x --evals x tasks`` arenas (or ``tasks x
  --held-out-episodes`` when those are more), each agent's row costing
  ``400 + 16 x candidates + 56 x obs_dim`` bytes (candidates: the 4 walls, the boxes, and the
  other agents where they are seen) plus what the controllers compute per row;
- the optimiser's own state (``Optimizer.memory_needs``: an ES's samples and, for CMA-ES, its
  d x d covariance terms; NEAT's first speciation, which grows as the square of the population);
- with ``--record``, one traced episode: about ``8000 + 250 x (agents + boxes)`` bytes a step.

The coefficients were measured as the peak resident memory (``ru_maxrss``) of real runs on
CPU, eager and compiled (docs/usage.md, Memory, has the figures), and rounded up: the estimate
is meant to be above the real peak, so that a run it lets through does not run out of memory;
the paper's run needs about 1.1 GiB. On a CUDA device the environments and the optimiser's
tensors live in its memory, which is checked against what the device has free.

What is available: the smaller of /proc/meminfo's MemAvailable (else ``os.sysconf``'s available
pages) and what the process's cgroup still allows. ``--no-memory-check`` skips the check: it is a
flag of ``run`` and ``sweep``, not a run setting, and never changes a run's numbers.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

from .config import RunConfig
from .errors import UserError

GiB = 2 ** 30
MiB = 2 ** 20
PROCESS = 900 * MiB
"""Python, torch, the optimisers' libraries and Rerun, imported: it varies with the machine's CPU and
libraries (430 to 690 MiB measured), so the margin is wide."""
COMPILING = 400 * MiB
"""What torch.compile adds while it compiles the step."""


@dataclass(frozen=True)
class MemoryNeeds:
    """A run's estimated peak memory, in bytes, in parts (``shared`` by runs played in one process)."""

    shared: int
    """The process itself (one per process, whatever the number of runs it plays)."""
    environments: int
    """The arenas played at once and what the controllers compute over them."""
    optimizer: int
    """The optimiser's own state at its peak."""
    recording: int
    """One traced episode for the recording."""
    on_device: bool
    """Whether environments and optimiser live on a CUDA device, not in the machine's memory."""

    @property
    def own(self) -> int:
        """What the run adds to a process that plays it."""
        return self.environments + self.optimizer + self.recording

    @property
    def total(self) -> int:
        return self.shared + self.own

    def host(self) -> int:
        """Of ``total``, what the machine's memory holds."""
        return self.shared + self.recording + (0 if self.on_device else self.environments + self.optimizer)

    def largest(self) -> str:
        """What most of the memory goes to, in words."""
        parts = {"the environments played at once": self.environments, "the optimiser's state": self.optimizer,
                 "the recorded episodes": self.recording}
        return max(parts, key=parts.get)


def estimate(config: RunConfig) -> MemoryNeeds:
    """The peak memory ``config`` needs (see the module docstring)."""
    from algorithms import REGISTRY

    env = config.env_config()
    tasks = len({phase.name for phase in config.phases()})  # every task is scored at generation 0
    # an ES also scores its centre; NEAT's population drifts by a few genomes (0.92's genetics)
    controllers = config.population + 1 + config.population // 20
    optimizer = REGISTRY[config.algo]
    options = optimizer.Options(**config.algo_options)
    state, policy_per_row = optimizer.memory_needs(controllers, env.obs_dim, options)
    candidates = 4 + env.n_boxes + (env.n_agents if env.see_other_agents else 0)
    per_row = 400 + 16 * candidates + 56 * env.obs_dim + policy_per_row
    arenas = max(controllers * config.evals * tasks, tasks * config.held_out_episodes)
    recording = (60 * MiB + env.duration * (8000 + 250 * (env.n_agents + env.n_boxes))) if config.record else 0
    return MemoryNeeds(shared=PROCESS + (COMPILING if config.compile else 0),
                       environments=arenas * env.n_agents * per_row, optimizer=state, recording=recording,
                       on_device=config.device.startswith("cuda"))


def available() -> int | None:
    """Bytes of memory this process can still take (None where it cannot be told)."""
    free = None
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                free = int(line.split()[1]) * 1024
    except OSError:
        pass
    if free is None:
        try:
            free = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        except (ValueError, OSError, AttributeError):
            return None
    limit = _cgroup_room()
    return free if limit is None else min(free, limit)


def _cgroup_room() -> int | None:
    """What this process's cgroup (v2, else v1) still allows, where it sets a limit."""
    for limit_file, usage_file in (("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory.current"),
                                   ("/sys/fs/cgroup/memory/memory.limit_in_bytes",
                                    "/sys/fs/cgroup/memory/memory.usage_in_bytes")):
        try:
            limit = Path(limit_file).read_text().strip()
            usage = int(Path(usage_file).read_text().strip())
        except (OSError, ValueError):
            continue
        if limit.isdigit() and int(limit) < 2 ** 60:  # "max", or v1's huge number: no limit
            return max(int(limit) - usage, 0)
    return None


def device_free(device: str) -> int | None:
    """Bytes free on CUDA device ``device`` (None for another device)."""
    if not device.startswith("cuda"):
        return None
    import torch

    return torch.cuda.mem_get_info(torch.device(device))[0]


def _size(n: int) -> str:
    if n >= 1024 * GiB:
        return f"{n / (1024 * GiB):.1f} TiB"
    return f"{n / GiB:.1f} GiB" if n >= GiB else f"{n / MiB:.0f} MiB"


FIX = ("lower --population, --evals or the sizes of the arena or the controller, or pass --no-memory-check "
       "to run anyway")


def check(configs: Sequence[RunConfig], together: bool = False, what: str = "this run", fix: str = FIX) -> None:
    """Raise UserError, saying how much is needed, how much there is and ``fix``, where ``configs``
    (run at once: as separate processes, or ``together`` in one) cannot fit in this machine's memory."""
    needs = [estimate(config) for config in configs]
    if not needs:
        return
    shared = max(n.shared for n in needs)
    host = (shared + sum(n.host() - n.shared for n in needs)) if together else sum(n.host() for n in needs)
    room = available()
    if room is not None and host > room:
        biggest = max(needs, key=lambda n: n.total)
        raise UserError(f"{what} needs about {_size(host)} of memory (most of it for {biggest.largest()}) and "
                        f"this machine has {_size(room)} available: {fix}")
    on_device = sum(n.environments + n.optimizer for n in needs if n.on_device)
    if on_device:
        free = device_free(configs[0].device)
        if free is not None and on_device > free:
            raise UserError(f"{what} needs about {_size(on_device)} of memory on {configs[0].device} and it has "
                            f"{_size(free)} free: {fix}")
