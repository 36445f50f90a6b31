"""Where does an ES update first differ between two machines? Prints one line per quantity of
sep-CMA-ES's search state (EvoTorch's constants, weights, centre, step size, paths, variances),
after construction and after each of three updates on a fixed fitness, each as a digest of its
bytes; with ``--against FILE`` (a trace made elsewhere), also the first line that differs.

    python -m benchmarks.trace_es_update > here.txt
    python -m benchmarks.trace_es_update --against tests/data/same-numbers/sep-cmaes-update-trace.txt

The update runs on one torch thread under the default (portable) arithmetic, as in a run. The
versions of Python, torch and numpy and the CPU are printed first: a difference there can
explain one below. Exit status 1 when ``--against`` finds a difference."""
from __future__ import annotations

import argparse
import hashlib
import platform
import sys
from pathlib import Path

import numpy as np
import torch

from algorithms import make_optimizer
from lifelong_evo.provenance import machine

OBS_DIM, POPULATION, SEED, UPDATES = 18, 300, 42, 3


def _digest(value) -> str | None:
    """A short digest of a tensor's, array's or number's bytes; ``None`` for anything else."""
    if isinstance(value, torch.Tensor):
        data = value.detach().cpu().contiguous().numpy().tobytes()
    elif isinstance(value, np.ndarray | np.generic):
        data = np.ascontiguousarray(value).tobytes()
    elif isinstance(value, bool | int):
        data = repr(value).encode()
    elif isinstance(value, float):
        data = value.hex().encode()
    else:
        return None
    return hashlib.sha256(data).hexdigest()[:16]


def trace() -> list[str]:
    """The trace's lines (without the version header)."""
    torch.set_num_threads(1)
    optimizer = make_optimizer("sep-cmaes", obs_dim=OBS_DIM, population_size=POPULATION, seed=SEED)
    lines = []
    for update in range(UPDATES + 1):
        if update:
            optimizer.ask()
            # a fixed fitness with distinct values in a scrambled order, so that ranking matters
            fitness = (torch.arange(optimizer.population_size) * 7919 % 307).float() / 10
            optimizer.tell(fitness, fitness)
        state = vars(optimizer.searcher)
        for name in sorted(state):
            digest = _digest(state[name])
            if digest is not None:
                lines.append(f"update {update} {name} {digest}")
        lines.append(f"update {update} centre {_digest(optimizer.centre)}")
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--against", type=Path, help="a trace made on another machine")
    args = parser.parse_args(argv)
    print(f"# python {platform.python_version()}, torch {torch.__version__}, numpy {np.__version__}; "
          f"{machine('cpu')}")
    lines = trace()
    print("\n".join(lines))
    if args.against is None:
        return 0
    theirs = [line for line in args.against.read_text().splitlines() if not line.startswith("#")]
    for mine, other in zip(lines, theirs):
        if mine != other:
            print(f"first difference: here {mine!r}, there {other!r}")
            return 1
    if len(lines) != len(theirs):
        print(f"the traces have {len(lines)} and {len(theirs)} lines")
        return 1
    print("the same trace")
    return 0


if __name__ == "__main__":
    sys.exit(main())
