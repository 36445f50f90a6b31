"""NEAT controllers back from their JSON export (``NeatOptimizer.export``), as policies."""
from __future__ import annotations

import torch

from .config import build_neat_config
from .network import CompiledPopulation, compile_genomes


def genome_from_export(exported: dict, config):
    """A neat-python genome with every gene of the export (disabled connections included)."""
    genome = config.genome_type(exported["genome_key"])
    genome_config = config.genome_config
    for node in exported["genome"]["nodes"]:
        gene = genome_config.node_gene_type(node["key"])
        gene.bias, gene.response = node["bias"], node["response"]
        gene.activation, gene.aggregation = node["activation"], node["aggregation"]
        genome.nodes[gene.key] = gene
    for link in exported["genome"]["connections"]:
        gene = genome_config.connection_gene_type((link["in"], link["out"]), link["innovation"])
        gene.weight, gene.enabled = link["weight"], link["enabled"]
        genome.connections[gene.key] = gene
    return genome


def policy_from_export(exported: dict, device: str | torch.device = "cpu") -> CompiledPopulation:
    """A one-controller batched policy that computes exactly what the exported genome did."""
    config = build_neat_config(exported["num_inputs"], pop_size=2)
    genome = genome_from_export(exported, config)
    return compile_genomes([genome], config, device, unconnected_outputs=exported["unconnected_outputs"])
