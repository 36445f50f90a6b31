"""Plug your own optimiser into the ask/tell interface and run the paper's protocol with it.

    python examples/custom_optimizer.py --preset smoke

A (1, lambda) hill climber on the project's MLP controller: each generation samples
``population_size`` perturbations of the incumbent (the incumbent itself is controller 0) and
keeps the best. Registering it makes every verb (run, sweep, compare) accept ``--algo hill-climber``;
its ``Options`` declare ``--option sigma=0.05`` and ``--option hidden=[32,16]``: parsed, checked, and
listed by ``python examples/custom_optimizer.py --help``. Its one regulariser is the functional one,
which needs only its reference, the incumbent at each task end (``reference_export``):
``python examples/custom_optimizer.py --preset smoke --reg 1``.
"""
from __future__ import annotations

import sys
from dataclasses import dataclass
from typing import Any

import torch

from algorithms import REGISTRY, GenerationReport, Optimizer, OptimizerOptions
from algorithms.base import FUNCTIONAL
from algorithms.mlp import MLPPolicy, layer_sizes_for, n_parameters
from lifelong_evo.commands.cli import main


@dataclass(frozen=True)
class HillClimberOptions(OptimizerOptions):
    sigma: float = 0.1
    """Standard deviation of the perturbations."""
    hidden: tuple[int, ...] = (16,)
    """Hidden layer sizes of the MLP controller."""

    def __post_init__(self):
        super().__post_init__()
        if not self.sigma > 0:
            raise ValueError(f"sigma must be > 0, got {self.sigma}")


class HillClimber(Optimizer):
    name = "hill-climber"
    Options = HillClimberOptions
    regularisers = {FUNCTIONAL: {}}

    def __init__(self, *, obs_dim: int, population_size: int, seed: int, reg: float = 0.0,
                 device: str = "cpu", **options):
        options = self.Options(**options)
        self.layer_sizes = layer_sizes_for(obs_dim, options.hidden)
        self.sigma = options.sigma
        self.device = device
        self.generator = torch.Generator().manual_seed(seed)
        self.incumbent = torch.zeros(n_parameters(self.layer_sizes))
        self.size = population_size
        self.samples: torch.Tensor | None = None
        self.reference: torch.Tensor | None = None

    @property
    def population_size(self) -> int:
        return self.size

    def ask(self) -> MLPPolicy:
        if self.samples is None:
            noise = torch.randn(self.size, self.incumbent.numel(), generator=self.generator) * self.sigma
            noise[0] = 0.0
            self.samples = self.incumbent + noise
        return MLPPolicy(self.samples.to(self.device), self.layer_sizes)

    def regularise(self, fitness: torch.Tensor) -> torch.Tensor:
        return fitness

    def tell(self, fitness: torch.Tensor, selection_fitness: torch.Tensor) -> GenerationReport:
        self.incumbent = self.samples[int(selection_fitness.argmax())].clone()
        self.samples = None
        return GenerationReport(extra={"sigma": self.sigma})

    def end_task(self) -> None:
        self.reference = self.incumbent.clone()

    def reference_export(self) -> dict[str, Any] | None:
        return None if self.reference is None else {"layer_sizes": list(self.layer_sizes),
                                                    "parameters": self.reference.tolist()}

    def state_dict(self) -> dict[str, Any]:
        return {"incumbent": self.incumbent, "generator": self.generator.get_state(), "samples": self.samples,
                "reference": self.reference}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.incumbent = state["incumbent"]
        self.generator.set_state(state["generator"])
        self.samples = state["samples"]
        self.reference = state["reference"]

    def export(self, index: int) -> dict[str, Any]:
        return {"layer_sizes": list(self.layer_sizes), "parameters": self.samples[index].tolist()}


REGISTRY[HillClimber.name] = HillClimber

if __name__ == "__main__":
    sys.exit(main(["--algo", HillClimber.name, *sys.argv[1:]]))
