"""A NEAT controller as a drawing shows it (``algorithms.network_from_export``): its nodes and
enabled connections, each marked new where a reference genome has no enabled connection between
the same nodes, and how far it lies from that reference by the measure of the NEAT regulariser a
run applies: neat-python's genetic distance (``gd``, the paper's, computed with the genetics the
controller evolved with, as the regulariser computes it), or weight protection's two sums (``wp``,
``optimizer.weight_protection``, before lambda_1 and lambda_2 weigh them). Under any other
regulariser (``functional`` compares outputs, which no file holds) the genetic distance is given,
named as what it is.

Everything is computed from exported controllers (``NeatOptimizer.export``), so a controller read
back from its file gives the same drawing and the same numbers."""
from __future__ import annotations

from typing import Any

from ..base import Connection, ControllerNetwork
from .config import build_neat_config
from .export import genome_from_export
from .optimizer import NeatOptimizer, weight_protection


def genome_network(exported: dict[str, Any], reference: dict[str, Any] | None = None,
                   regulariser: str | None = None) -> ControllerNetwork:
    """The exported genome's inputs that an enabled connection reads, its hidden and output nodes,
    its enabled connections, and (with a ``reference`` genome) its distance to it as
    ``regulariser`` (a name of ``NeatOptimizer.regularisers``) measures it."""
    links = [c for c in exported["genome"]["connections"] if c["enabled"]]
    kept = {(c["in"], c["out"]) for c in reference["genome"]["connections"] if c["enabled"]} if reference else set()
    nodes = tuple((key, "input") for key in sorted({c["in"] for c in links if c["in"] < 0})) + tuple(
        (n["key"], "output" if n["key"] < exported["num_outputs"] else "hidden") for n in exported["genome"]["nodes"])
    connections = tuple(Connection(c["in"], c["out"], c["weight"],
                                   reference is not None and (c["in"], c["out"]) not in kept) for c in links)
    measures = () if reference is None else _measures(exported, reference, regulariser)
    return ControllerNetwork(nodes=nodes, connections=connections, measures=measures)


def _measures(exported: dict[str, Any], reference: dict[str, Any], regulariser: str | None
              ) -> tuple[tuple[str, float], ...]:
    config = build_neat_config(exported["num_inputs"], genetics=exported["genetics"])
    genome, anchor = (genome_from_export(e, config) for e in (exported, reference))
    if NeatOptimizer.regularisers.get(regulariser, {}).get("penalty") == "wp":
        shared, other = weight_protection(genome, anchor)
        return ("sum of squared weight changes", shared), ("sum of squared new weights", other)
    return (("genetic distance", anchor.distance(genome, config.genome_config)),)  # as the regulariser measures it
