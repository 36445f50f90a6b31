"""What a regulariser keeps: a task end's top controller as a network, set against its reference.

At every task end the recording (``Recorder.log_network``) and ``plot`` show the top controller
(``task<i>-<task>-top``) next to the reference the regulariser anchors to, which is the previous
task end's exported controller of the kind ``reference_kind`` names (the first task end has none):

- a NEAT genome: its nodes (the inputs it reads, hidden nodes, the outputs) and its enabled
  connections with their weights, each marked ``new`` where the reference has no enabled
  connection between the same nodes, and neat-python's genetic distance to the reference (the
  regulariser's own measure);
- an MLP (an ES): its layer sizes and the Euclidean distance of each layer's weights and biases
  to the reference's, and of all of them.

Everything here is computed from exported controllers (``Optimizer.export``), so the loop and
``plot``, which reads them from controllers/, show the same numbers.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import torch

from algorithms.mlp import unflatten
from algorithms.neat.config import build_neat_config
from algorithms.neat.export import genome_from_export

from .metrics import controller_key


@dataclass(frozen=True)
class Node:
    key: int
    """neat-python's node key: negative for an input, 0 to 2 for the outputs."""
    role: str
    """``input``, ``hidden`` or ``output``."""
    depth: int
    """Its column in a drawing: 0 for the inputs, else one more than the deepest node feeding it."""


@dataclass(frozen=True)
class Edge:
    source: int
    target: int
    weight: float
    new: bool
    """The reference has no enabled connection from ``source`` to ``target``."""


@dataclass(frozen=True)
class NetworkView:
    """A controller as a network, and how far it lies from its reference."""

    controller: str
    """Its name in controllers/ (``task1-green-top``)."""
    reference: str | None
    """The reference's name (None: no reference, or it was not found)."""
    distance: float | None
    """NEAT: the genetic distance to the reference; an MLP: the Euclidean distance of all its parameters."""
    nodes: tuple[Node, ...] = ()
    """NEAT: the inputs with an enabled connection, the hidden nodes and the outputs."""
    edges: tuple[Edge, ...] = ()
    """NEAT: the enabled connections."""
    layer_sizes: tuple[int, ...] = ()
    """An MLP: ``(inputs, *hidden, outputs)``."""
    layer_distances: tuple[float, ...] = ()
    """An MLP: per layer, the Euclidean distance of its weights and biases to the reference's."""

    @property
    def is_neat(self) -> bool:
        return bool(self.nodes)


def reference_kind(config: dict[str, Any]) -> str:
    """The kind of exported controller (``metrics.HELD_OUT_LEVELS``) the run's regulariser anchors
    to, from config.json's values: NEAT's top genome (its reference is the task's best genome by
    selection fitness); an ES's centre, or its top controller with ``reference = "best"``."""
    options = config.get("algo_options_resolved") or config.get("algo_options") or {}
    return "centre" if config.get("algo") != "neat" and options.get("reference", "centre") == "centre" else "top"


def reference_name(config: dict[str, Any], phase_names: list[str], phase_index: int) -> str | None:
    """The name of the reference of phase ``phase_index``'s top controller: the previous task end's
    controller of ``reference_kind``; None at the first task end."""
    if phase_index == 0:
        return None
    return controller_key(phase_index - 1, phase_names[phase_index - 1], reference_kind(config))


def network_view(name: str, exported: dict[str, Any], reference_of: str | None = None,
                 reference: dict[str, Any] | None = None) -> NetworkView:
    """The exported controller ``name`` as a network, against ``reference`` (named ``reference_of``;
    None: no reference)."""
    if reference is None:
        reference_of = None
    if exported.get("format") == "neat-python-genome":
        return _neat_view(name, exported, reference_of, reference)
    return _mlp_view(name, exported, reference_of, reference)


def _neat_view(name: str, exported: dict[str, Any], reference_of: str | None,
               reference: dict[str, Any] | None) -> NetworkView:
    links = [c for c in exported["genome"]["connections"] if c["enabled"]]
    kept = {(c["in"], c["out"]) for c in reference["genome"]["connections"] if c["enabled"]} if reference else set()
    outputs = range(exported["num_outputs"])
    keys = sorted({c["in"] for c in links if c["in"] < 0}) + [n["key"] for n in exported["genome"]["nodes"]]
    depth = {key: 0 if key < 0 else 1 for key in keys}
    for _ in keys:  # longest path from the inputs (the network is feed-forward)
        for link in links:
            depth[link["out"]] = max(depth[link["out"]], depth[link["in"]] + 1)
    nodes = tuple(Node(key, "input" if key < 0 else "output" if key in outputs else "hidden", depth[key])
                  for key in keys)
    edges = tuple(Edge(c["in"], c["out"], c["weight"], reference is not None and (c["in"], c["out"]) not in kept)
                  for c in links)
    distance = None
    if reference is not None:
        config = build_neat_config(exported["num_inputs"], genetics=exported["genetics"])
        genome, anchor = (genome_from_export(e, config) for e in (exported, reference))
        distance = anchor.distance(genome, config.genome_config)  # as the regulariser measures it
    return NetworkView(name, reference_of, distance, nodes=nodes, edges=edges)


def _mlp_view(name: str, exported: dict[str, Any], reference_of: str | None,
              reference: dict[str, Any] | None) -> NetworkView:
    sizes = tuple(exported["layer_sizes"])
    distances: tuple[float, ...] = ()
    if reference is not None and tuple(reference["layer_sizes"]) == sizes:
        mine, theirs = (unflatten(torch.tensor(e["parameters"], dtype=torch.float64), sizes)
                        for e in (exported, reference))
        distances = tuple(math.sqrt(((w - v) ** 2).sum().item() + ((b - c) ** 2).sum().item())
                          for (w, b), (v, c) in zip(mine, theirs))
    else:
        reference_of = None
    distance = math.sqrt(sum(d * d for d in distances)) if distances else None
    return NetworkView(name, reference_of, distance, layer_sizes=sizes, layer_distances=distances)


def task_end_views(config: dict[str, Any], phase_names: list[str],
                   controllers: dict[str, dict[str, Any]]) -> list[tuple[int, NetworkView]]:
    """``(phase index, view)`` of every task end whose top controller ``controllers`` (by name, as
    controllers/ holds them) has, against its reference where that is there too."""
    views = []
    for i, name in enumerate(phase_names):
        top = controller_key(i, name, "top")
        if top in controllers:
            reference = reference_name(config, phase_names, i)
            views.append((i, network_view(top, controllers[top], reference, controllers.get(reference))))
    return views


def describe(view: NetworkView) -> str:
    """One line: what the network is and how far it lies from its reference."""
    if view.is_neat:
        hidden = sum(node.role == "hidden" for node in view.nodes)
        new = sum(edge.new for edge in view.edges)
        shape = f"{hidden} hidden nodes, {len(view.edges)} enabled connections"
        moved = (f"; genetic distance {view.distance:.3g} to {view.reference}, which lacks {new} of them"
                 if view.reference else "")
    else:
        shape = "layers " + " -> ".join(map(str, view.layer_sizes))
        moved = f"; distance {view.distance:.3g} to {view.reference}" if view.reference else ""
    return f"{view.controller}: {shape}{moved}"
