"""Optimisers behind one ask/tell interface (see ``algorithms.base``), by registry name."""
from __future__ import annotations

from .base import BatchedPolicy, GenerationReport, Optimizer, OptimizerOptions
from .es import ES_ALGORITHMS
from .neat_optimizer import NeatOptimizer

REGISTRY: dict[str, type[Optimizer]] = {"neat": NeatOptimizer, **ES_ALGORITHMS}
"""Every optimiser by the name the command line uses."""


class UnknownAlgorithmError(ValueError):
    pass


def make_optimizer(name: str, *, obs_dim: int, population_size: int, seed: int,
                   regularization: float = 0.0, device: str = "cpu", **options) -> Optimizer:
    """Build the optimiser ``name`` for controllers with ``obs_dim`` inputs and 3 outputs;
    ``options`` are fields of its ``Options`` (ValueError for a value out of range)."""
    try:
        cls = REGISTRY[name]
    except KeyError:
        raise UnknownAlgorithmError(
            f"unknown algorithm {name!r}: choose one of {', '.join(REGISTRY)}") from None
    if regularization and not cls.has_regularizer:
        raise ValueError(f"algorithm {name!r} has no regulariser: drop --reg or use another algorithm")
    return cls(obs_dim=obs_dim, population_size=population_size, seed=seed,
               regularization=regularization, device=device, **options)


def policy_from_export(exported: dict, device: str = "cpu") -> BatchedPolicy:
    """A one-controller policy from what ``Optimizer.export`` wrote (NEAT genome or MLP)."""
    if exported.get("format") == "neat-python-genome":
        from .neat_export import policy_from_export as neat_policy

        return neat_policy(exported, device)
    if "layer_sizes" in exported:
        from .mlp import MLPPolicy

        return MLPPolicy.from_export(exported, device)
    raise ValueError("not an exported controller: expected a NEAT genome or an MLP (layer_sizes, parameters)")


__all__ = ["policy_from_export", "REGISTRY", "BatchedPolicy", "GenerationReport", "Optimizer", "OptimizerOptions",
           "make_optimizer", "UnknownAlgorithmError"]
