"""NEAT controllers back from their JSON export (``NeatOptimizer.export``), as policies;
``check_export`` refuses an export that is not one (ExportError naming the field) before any of
it is built."""
from __future__ import annotations

from collections.abc import Callable
from typing import Any

import torch

from ..base import ExportError, is_integer, is_number, shown_value
from .config import build_neat_config
from .network import _ACTIVATION_SLOPES, UNCONNECTED_OUTPUTS_MODES, CompiledPopulation, compile_genomes

N_OUTPUTS = 3
"""The outputs of every NEAT controller (one per wheel), as ``build_neat_config`` builds them."""
INTEGER, NUMBER = (is_integer, "an integer"), (is_number, "a finite number")
TEXT, BOOLEAN = (lambda value: isinstance(value, str), "text"), (lambda value: isinstance(value, bool), "true or false")
NODE_FIELDS = {"key": INTEGER, "bias": NUMBER, "response": NUMBER, "activation": TEXT, "aggregation": TEXT}
CONNECTION_FIELDS = {"in": INTEGER, "out": INTEGER, "weight": NUMBER, "enabled": BOOLEAN, "innovation": INTEGER}
"""Each gene's fields, with the test its value must pass and the words for what that is."""


def genome_from_export(exported: dict, config):
    """A neat-python genome with every gene of the export (disabled connections included); the
    node attributes an export does not carry have the value the configuration fixes
    (``fixed_node_attributes``). Draws nothing from ``random``."""
    genome = config.genome_type(exported["genome_key"])
    genome_config = config.genome_config
    fixed = fixed_node_attributes(genome_config)
    for node in exported["genome"]["nodes"]:
        gene = genome_config.node_gene_type(node["key"])
        gene.bias, gene.response = node["bias"], node["response"]
        gene.activation, gene.aggregation = node["activation"], node["aggregation"]
        for name, value in fixed.items():
            setattr(gene, name, value)
        genome.nodes[gene.key] = gene
    for link in exported["genome"]["connections"]:
        gene = genome_config.connection_gene_type((link["in"], link["out"]), link["innovation"])
        gene.weight, gene.enabled = link["weight"], link["enabled"]
        genome.connections[gene.key] = gene
    return genome


def fixed_node_attributes(genome_config) -> dict[str, float]:
    """The node gene attributes an export does not carry (neat-python 2.0's ``time_constant``; 0.92's
    genes have none), each with the one value every node has: its initial mean, clamped, since the
    configuration draws it with standard deviation 0 and never mutates or replaces it. Set directly
    rather than by ``init_attributes``, which would draw from ``random`` and so change the run's
    numbers. ValueError for an attribute the configuration lets vary: the export would lose it."""
    fixed = {}
    for attribute in genome_config.node_gene_type._gene_attributes:
        if attribute.name in NODE_FIELDS:
            continue
        varying = {name: value for name in (attribute.init_stdev_name, attribute.mutate_rate_name,
                                            attribute.replace_rate_name)
                   if (value := getattr(genome_config, name)) != 0}
        if varying:
            raise ValueError(f"node attribute {attribute.name} varies ({varying}): an export does not "
                             "carry it, so cannot rebuild the genome")
        fixed[attribute.name] = attribute.clamp(getattr(genome_config, attribute.init_mean_name), genome_config)
    return fixed


def policy_from_export(exported: dict, device: str | torch.device = "cpu") -> CompiledPopulation:
    """A one-controller batched policy that computes exactly what the exported genome did;
    ExportError where ``exported`` is not a NEAT export (``check_export``)."""
    check_export(exported)
    config = build_neat_config(exported["num_inputs"], pop_size=2)
    genome = genome_from_export(exported, config)
    return compile_genomes([genome], config, device, unconnected_outputs=exported["unconnected_outputs"])


def check_export(exported: dict, obs_dim: int | None = None) -> None:
    """ExportError unless ``exported`` is a NEAT export that ``policy_from_export`` can build:
    ``num_inputs`` a positive integer (``obs_dim``, where given), ``num_outputs`` 3, a known
    ``unconnected_outputs`` mode, an integer ``genome_key``, and a ``genome`` whose ``nodes`` and
    ``connections`` are lists of genes with every field of the right type, the output nodes among
    the nodes, sum aggregation and an activation the batched pass knows, and each connection
    between an input or a node and a node."""
    inputs = exported.get("num_inputs")
    if not is_integer(inputs) or inputs < 1:
        raise ExportError(f"num_inputs is {shown_value(inputs)}, not a positive integer")
    if obs_dim is not None and inputs != obs_dim:
        raise ExportError(f"num_inputs is {inputs}, not the arena's {obs_dim} observations")
    if exported.get("num_outputs") != N_OUTPUTS:
        raise ExportError(f"num_outputs is {shown_value(exported.get('num_outputs'))}, not {N_OUTPUTS}")
    if exported.get("unconnected_outputs") not in UNCONNECTED_OUTPUTS_MODES:
        raise ExportError(f"unconnected_outputs is {shown_value(exported.get('unconnected_outputs'))}, "
                          f"not one of {', '.join(UNCONNECTED_OUTPUTS_MODES)}")
    if not is_integer(exported.get("genome_key")):
        raise ExportError(f"genome_key is {shown_value(exported.get('genome_key'))}, not an integer")
    genome = exported.get("genome")
    if not isinstance(genome, dict):
        raise ExportError(f"genome is {shown_value(genome)}, not an object of nodes and connections")
    nodes = _genes(genome, "nodes", NODE_FIELDS)
    links = _genes(genome, "connections", CONNECTION_FIELDS)
    keys = {node["key"] for node in nodes}
    if any(key < 0 for key in keys):  # negative keys are the inputs'
        raise ExportError(f"genome.nodes has the negative key(s) {sorted(k for k in keys if k < 0)}, which name inputs")
    missing = [k for k in range(N_OUTPUTS) if k not in keys]
    if missing:
        raise ExportError(f"genome.nodes lacks the output node(s) {missing}")
    for i, node in enumerate(nodes):
        if node["aggregation"] != "sum" or node["activation"] not in _ACTIVATION_SLOPES:
            raise ExportError(f"genome.nodes[{i}] has aggregation {node['aggregation']!r} and activation "
                              f"{node['activation']!r}: the batched pass takes sum with {sorted(_ACTIVATION_SLOPES)}")
    for i, link in enumerate(links):
        if not (-inputs <= link["in"] < 0 or link["in"] in keys) or link["out"] not in keys:
            raise ExportError(f"genome.connections[{i}] joins {link['in']} to {link['out']}: a connection runs "
                              f"from an input (-{inputs} to -1) or a node to a node of genome.nodes")


def _genes(genome: dict, part: str, expected: dict[str, tuple[Callable[[Any], bool], str]]) -> list[dict]:
    """``genome[part]``, checked to be a list of objects whose fields pass ``expected``."""
    genes = genome.get(part)
    if not isinstance(genes, list):
        raise ExportError(f"genome.{part} is {shown_value(genes)}, not a list of genes")
    for i, gene in enumerate(genes):
        if not isinstance(gene, dict):
            raise ExportError(f"genome.{part}[{i}] is {shown_value(gene)}, not a gene (an object)")
        for name, (test, words) in expected.items():
            if not test(gene.get(name)):
                raise ExportError(f"genome.{part}[{i}].{name} is {shown_value(gene.get(name))}, not {words}")
    return genes
