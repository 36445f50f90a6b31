"""Optimisers behind one ask/tell interface (see ``algorithms.base``), by registry name.

Each optimiser is one module; this package imports them and builds ``REGISTRY``, so an optimiser
module never imports the registry and no module imports the package that imports it.
"""
from __future__ import annotations

from typing import Any

from .base import BatchedPolicy, ControllerNetwork, ExportError, GenerationReport, Optimizer, OptimizerOptions
from .cmaes import CMAES, SepCMAES
from .es import ESOptimizer
from .neat import NeatOptimizer
from .openai_es import OpenAIES
from .pgpe import PGPE
from .snes import SNES

REGISTRY: dict[str, type[Optimizer]] = {cls.name: cls for cls in (NeatOptimizer, CMAES, SepCMAES, OpenAIES, PGPE, SNES)}
"""Every optimiser by the name the command line uses (``--algo``); add your own with
``REGISTRY["my-algo"] = MyOptimizer``."""


class UnknownAlgorithmError(ValueError):
    pass


def make_optimizer(name: str, *, obs_dim: int, population_size: int, seed: int,
                   reg: float = 0.0, device: str = "cpu", **options) -> Optimizer:
    """Build the optimiser ``name`` for controllers with ``obs_dim`` inputs and 3 outputs;
    ``options`` are fields of its ``Options`` (ValueError for a value out of range)."""
    try:
        cls = REGISTRY[name]
    except KeyError:
        raise UnknownAlgorithmError(
            f"unknown algorithm {name!r}: choose one of {', '.join(REGISTRY)}") from None
    if reg and not cls.has_regularizer:
        raise ValueError(f"algorithm {name!r} has no regulariser: set reg to 0 or use another algorithm")
    return cls(obs_dim=obs_dim, population_size=population_size, seed=seed,
               reg=reg, device=device, **options)


def controller_size(exported: dict) -> dict[str, int]:
    """What an exported controller is made of, to set families side by side: an MLP's
    ``parameters`` (weights and biases); a NEAT genome's ``nodes`` (hidden and output) and its
    enabled ``connections``."""
    if exported.get("format") == "neat-python-genome":
        genome = exported["genome"]
        return {"nodes": len(genome["nodes"]),
                "connections": sum(bool(c["enabled"]) for c in genome["connections"])}
    if "layer_sizes" in exported:
        sizes = exported["layer_sizes"]
        return {"parameters": sum((a + 1) * b for a, b in zip(sizes[:-1], sizes[1:]))}
    raise ValueError("not an exported controller: expected a NEAT genome or an MLP (layer_sizes, parameters)")


def check_export(exported: Any, obs_dim: int | None = None) -> None:
    """ExportError unless ``exported`` is what ``Optimizer.export`` writes, a NEAT genome or an MLP,
    whole and of consistent sizes, taking ``obs_dim`` inputs where given: the check
    ``policy_from_export`` makes first, so that a damaged controller is refused by its field."""
    if not isinstance(exported, dict):
        raise ExportError(f"a controller is a JSON object, not {type(exported).__name__}")
    if exported.get("format") == "neat-python-genome":
        from .neat.export import check_export as check_neat

        check_neat(exported, obs_dim)
    elif "layer_sizes" in exported:
        from .mlp import check_export as check_mlp

        check_mlp(exported, obs_dim)
    else:
        raise ExportError("not an exported controller: expected a NEAT genome (format neat-python-genome) or an MLP "
                          "(layer_sizes, parameters)")


def policy_from_export(exported: dict, device: str = "cpu") -> BatchedPolicy:
    """A one-controller policy from what ``Optimizer.export`` wrote (NEAT genome or MLP);
    ExportError where it is neither (``check_export``)."""
    check_export(exported)
    if exported.get("format") == "neat-python-genome":
        from .neat.export import policy_from_export as neat_policy

        return neat_policy(exported, device)
    from .mlp import MLPPolicy

    return MLPPolicy.from_export(exported, device)


def network_from_export(exported: dict, reference: dict | None = None, regulariser: str | None = None
                        ) -> ControllerNetwork:
    """What a drawing shows of what ``Optimizer.export`` wrote (``ControllerNetwork``): a NEAT
    genome's nodes and connections (``neat.graph.genome_network``), an MLP's layers
    (``mlp.mlp_network``), against ``reference`` (an export of the same family, such as
    ``reference_export``'s; None: none), measured as the run's ``regulariser`` (a name of the
    optimiser's ``regularisers``) measures it where the files allow. ExportError where either is
    not an export (``check_export``) or they are not of one family and size."""
    check_export(exported)
    if reference is not None:
        check_export(reference)
        if reference.get("format") != exported.get("format"):
            raise ExportError(f"the reference is a {reference.get('format') or 'MLP'} controller, "
                              f"the controller a {exported.get('format') or 'MLP'} one")
    if exported.get("format") == "neat-python-genome":
        from .neat.graph import genome_network

        return genome_network(exported, reference, regulariser)
    from .mlp import mlp_network

    return mlp_network(exported, reference)


__all__ = ["CMAES", "PGPE", "REGISTRY", "SNES", "BatchedPolicy", "ControllerNetwork", "ESOptimizer", "ExportError",
           "GenerationReport", "NeatOptimizer", "OpenAIES", "Optimizer", "OptimizerOptions", "SepCMAES",
           "UnknownAlgorithmError", "check_export", "controller_size", "make_optimizer", "network_from_export",
           "policy_from_export"]
