"""neat-python genomes as one batched torch policy, and the paper's NEAT configuration.

``compile_genomes`` turns a generation's genomes into padded weight tensors once; the resulting
``CompiledPopulation`` maps observations ``(P, E, A, n_inputs)`` to outputs ``(P, E, A, 3)`` for
every genome at once, with one batched matmul for the input block and one small batched matmul
per hidden depth (no Python loop over genomes or agents).

Semantics
---------
A node's value is ``act(bias + response * sum(w * x))`` over its *enabled* incoming connections
(aggregation ``sum``), as in ``neat.nn.FeedForwardNetwork``; nodes that no output needs are never
computed. The activation is ``neat_sigmoid(x) = 1 / (1 + exp(-4.9 x))`` (neat-python's own
``sigmoid`` with its slope 5 is also accepted). neat-python clamps ``4.9 x`` to ``[-60, 60]``;
the torch pass does not, which changes nothing in float32 (``sigmoid(-60) = 8.7e-27``).

The two versions of neat-python disagree about nodes without enabled incoming connections, so
``compile_genomes`` takes ``unconnected_outputs``:

``"zero"`` (default; neat-python 0.92, which produced the paper's numbers, and the project's
    foraging spec): a node is computed only when it has at least one enabled incoming connection
    and every one of its sources is an input or a computed node (0.92's ``feed_forward_layers``).
    An output that is not computed stays at 0.0 (its wheel turns at ``-max_wheel_velocity``).
    Note that this is broader than "an output without incoming connections": a hidden node
    without enabled inputs is *dead* in 0.92, and so is every node it feeds, so an output fed
    by such a node stays at 0.0 as well, even if it also has live inputs.
``"bias"`` (exactly neat-python 2.0's ``FeedForwardNetwork``): a required node without enabled
    incoming connections is a *bias neuron* with value ``act(bias)``, and everything it feeds is
    computed normally; no output is ever left at 0.0.

The two modes agree on every genome in which each required hidden node and each output has an
enabled incoming connection.

Layout
------
Hidden nodes are grouped by depth (1 + the deepest hidden source; 1 for nodes fed by inputs
only, or by nothing) and padded per depth to the generation's largest count, so that each
depth is a contiguous block of slots; outputs are computed last, in slots of their own. Under
neat-python 2.0's genetics outputs are sinks; under 0.92's an output may feed hidden nodes (never
another output): such an output also gets a hidden slot at its depth, computed from the same
weights and bias, which its targets read. ``slope * response`` is folded into
the weights and ``slope * bias`` into the bias. Padding slots have zero weights in and out.
Nothing is capped: the padding follows the largest genome of the generation. One call costs
one batched matmul for the inputs plus one small batched matmul per hidden depth beyond the
first (see ``CompiledPopulation``).
"""
from __future__ import annotations

import configparser
import math
import os
import tempfile
from collections import defaultdict
from importlib import resources
from typing import Literal, Mapping, Sequence

import neat
import torch
from neat.graphs import feed_forward_layers, required_for_output

from .neat_genetics import (
    DEFAULT_GENETICS,
    Neat092Genome,
    Neat092Reproduction,
    Neat092SpeciesSet,
    Neat092Stagnation,
    check_genetics,
)
from .neat_speciation import SpeciesSet

UnconnectedOutputs = Literal["zero", "bias"]
UNCONNECTED_OUTPUTS_MODES: tuple[str, ...] = ("zero", "bias")

NEAT_SIGMOID_SLOPE = 4.9
"""Slope of the paper's activation: ``neat_sigmoid(x) = 1 / (1 + exp(-4.9 x))``."""

_ACTIVATION_SLOPES: dict[str, float] = {"neat_sigmoid": NEAT_SIGMOID_SLOPE, "sigmoid": 5.0}
"""Activations the batched pass knows: all are ``sigmoid(slope * x)``."""


def neat_sigmoid(x):
    """The paper's activation ``1 / (1 + exp(-4.9 x))``, registered with neat-python as
    ``neat_sigmoid``; the argument is clamped to ``[-60, 60]`` as neat-python's own sigmoid does,
    so ``exp`` never overflows. Module-level, so configs and genomes pickle by reference."""
    z = max(-60.0, min(60.0, NEAT_SIGMOID_SLOPE * x))
    return 1.0 / (1.0 + math.exp(-z))


# --------------------------------------------------------------------------------------------
# configuration


def neat_config_path() -> str:
    """Path of the packaged ``neat_config.ini`` (the paper's table)."""
    return str(resources.files("algorithms").joinpath("neat_config.ini"))


def minimum_population(genetics: str = DEFAULT_GENETICS) -> int:
    """The smallest population NEAT evolves at the size asked, with the paper's configuration
    (``neat_config.ini``): each species keeps its ``elitism`` best genomes, so 0.92's genetics
    grows a smaller population to that many; 2.0's gives every species at least
    max(``elitism``, ``min_species_size``) genomes and stops with an error ("Configuration
    conflict") where two species do not fit."""
    parser = configparser.ConfigParser()
    with open(neat_config_path()) as f:
        parser.read_file(f)
    elitism = parser.getint("DefaultReproduction", "elitism")
    if check_genetics(genetics) == "0.92":
        return elitism
    return 2 * max(elitism, parser.getint("DefaultReproduction", "min_species_size"))


class Reproduction(neat.DefaultReproduction):
    """neat-python 2.0.0's ``DefaultReproduction`` with one bug fixed: ``_adjust_spawn_exact``,
    when the species' spawn counts add up to more than the population, takes one genome off each
    species above the minimum size in one pass and then gives up. One large species next to one
    at the minimum is enough for it to raise "Internal error adjusting spawn counts" in the
    middle of a run (docs/algorithms.md, pitfalls). Here the passes go
    on until the counts fit; wherever neat-python's own succeeds, the counts are the same."""

    def _adjust_spawn_exact(self, spawn_amounts, pop_size, min_species_size):
        excess = sum(spawn_amounts) - pop_size
        if excess <= 0 or len(spawn_amounts) * min_species_size > pop_size:
            return super()._adjust_spawn_exact(spawn_amounts, pop_size, min_species_size)
        spawn_amounts = list(spawn_amounts)
        # neat-python's order: larger species first, ties by species order (a stable sort)
        order = sorted(range(len(spawn_amounts)), key=lambda i: spawn_amounts[i], reverse=True)
        while excess > 0:
            for i in order:
                if excess > 0 and spawn_amounts[i] > min_species_size:
                    spawn_amounts[i] -= 1
                    excess -= 1
        return spawn_amounts


_SECTIONS = ("DefaultGenome", "DefaultReproduction", "DefaultSpeciesSet", "DefaultStagnation")
"""The sections of ``neat_config.ini``, in the order of ``neat_components``."""


def neat_components(genetics: str = DEFAULT_GENETICS) -> tuple[type, type, type, type]:
    """The genome, reproduction, species-set and stagnation classes of ``genetics`` (see
    ``algorithms.neat_genetics``): neat-python 0.92's, or 2.0's own with the spawn-count fix and
    batched speciation distances (``algorithms.neat_speciation``)."""
    if check_genetics(genetics) == "0.92":
        return Neat092Genome, Neat092Reproduction, Neat092SpeciesSet, Neat092Stagnation
    return neat.DefaultGenome, Reproduction, SpeciesSet, neat.DefaultStagnation


def build_neat_config(num_inputs: int, pop_size: int = 300,
                      overrides: Mapping[str, Mapping[str, object]] | None = None,
                      genetics: str = DEFAULT_GENETICS) -> neat.Config:
    """A fresh ``neat.Config`` with the paper's values, ``num_inputs`` inputs and ``pop_size``,
    and the components of ``genetics`` (``neat_components``).

    ``overrides`` maps section name (as in ``neat_config.ini``) to ``{option: value}`` and
    replaces further values (tests use it for high mutation rates). Build one per optimiser: the
    config carries mutable counters (the node indexer, and the innovation tracker once
    reproduction sets it).
    """
    if int(num_inputs) < 1:
        raise ValueError(f"num_inputs must be >= 1, got {num_inputs}")
    if int(pop_size) < 2:
        raise ValueError(f"pop_size must be >= 2, got {pop_size}")
    parser = configparser.ConfigParser()
    with open(neat_config_path()) as f:
        parser.read_file(f)
    parser["NEAT"]["pop_size"] = str(int(pop_size))
    parser["DefaultGenome"]["num_inputs"] = str(int(num_inputs))
    for section, values in (overrides or {}).items():
        for key, value in values.items():
            if not parser.has_option(section, key):
                raise KeyError(f"unknown NEAT option [{section}] {key}")
            parser[section][key] = str(value)
    components = neat_components(genetics)
    # neat-python reads each component's options from the section named after its class
    for section, component in zip(_SECTIONS, components):
        if section != component.__name__:
            parser[component.__name__] = dict(parser[section])
            parser.remove_section(section)
    fd, path = tempfile.mkstemp(prefix="neat-config-", suffix=".ini")
    try:
        with os.fdopen(fd, "w") as f:
            parser.write(f)
        config = neat.Config(*components, path)
    finally:
        os.unlink(path)
    config.genome_config.add_activation("neat_sigmoid", neat_sigmoid)
    return config


# --------------------------------------------------------------------------------------------
# graph analysis


def _layers_v092(inputs: Sequence[int], connections: Sequence[tuple[int, int]],
                 required: set[int]) -> list[set[int]]:
    """neat-python 0.92's ``feed_forward_layers``: a required node joins a layer once it has at
    least one enabled incoming connection and all its sources are inputs or earlier layers.
    (Same result as 0.92's code, without its quadratic scans.)"""
    incoming: dict[int, list[int]] = defaultdict(list)
    for a, b in connections:
        incoming[b].append(a)
    ready = set(inputs)
    pending = {n for n in required if incoming.get(n)}
    layers = []
    while True:
        layer = {n for n in pending if all(a in ready for a in incoming[n])}
        if not layer:
            return layers
        layers.append(layer)
        ready |= layer
        pending -= layer


def genome_layers(genome, genome_config, unconnected_outputs: UnconnectedOutputs = "zero"
                  ) -> tuple[list[set[int]], list[tuple[int, int, float]]]:
    """The layers of computed nodes and the enabled connections ``(src, dst, weight)`` that feed
    them, for one genome, under ``unconnected_outputs`` (see the module docstring)."""
    inputs, outputs = genome_config.input_keys, genome_config.output_keys
    enabled = [cg.key for cg in genome.connections.values() if cg.enabled]
    if unconnected_outputs == "bias":
        layers, _required = feed_forward_layers(inputs, outputs, enabled)
    elif unconnected_outputs == "zero":
        layers = _layers_v092(inputs, enabled, required_for_output(inputs, outputs, enabled))
    else:
        raise ValueError(f"unconnected_outputs must be one of {UNCONNECTED_OUTPUTS_MODES}, "
                         f"got {unconnected_outputs!r}")
    computed = set().union(*layers) if layers else set()
    links = [(a, b, genome.connections[(a, b)].weight) for a, b in enabled if b in computed]
    return layers, links


# --------------------------------------------------------------------------------------------
# the batched policy


class CompiledPopulation:
    """A generation of NEAT genomes as one batched policy (``algorithms.base.BatchedPolicy``).

    Call with observations ``(P, E, A, n_inputs)``; returns outputs ``(P, E, A, 3)`` in ``[0, 1]``
    (a new contiguous tensor). Build it with ``compile_genomes``.

    Internally node values are kept as ``(P, N, E*A)`` (node slot, then the rows of all envs and
    agents), so that every elementwise step runs over long contiguous rows: one batched matmul
    ``x @ w_in`` computes the input part of every slot (moved to that layout as the bias is
    added), then each hidden depth adds the part from shallower hidden slots (one small batched
    matmul) and applies the sigmoid, and the outputs come last. Outputs that stay at 0.0
    (``unconnected_outputs="zero"``) have bias ``-inf`` and no incoming weights, so their
    sigmoid is exactly 0.0.
    """

    def __init__(self, *, w_in: torch.Tensor, bias: torch.Tensor,
                 blocks: list[tuple[int, int, torch.Tensor | None]], n_hidden: int,
                 genome_keys: tuple, unconnected_outputs: str, depths: torch.Tensor,
                 zero_outputs: torch.Tensor):
        self.w_in = w_in              # (P, n_inputs, N): slope * response * weight
        self.bias = bias              # (P, N, 1): slope * bias (-inf: output left at 0.0)
        self.blocks = blocks          # hidden depths, then outputs: (start, stop, W (P, K, start))
        self.n_hidden = n_hidden      # hidden slots; outputs are slots n_hidden..N-1
        self.genome_keys = genome_keys
        self.unconnected_outputs = unconnected_outputs
        self.depths = depths          # (P,) hidden depth of each genome (CPU)
        self.zero_outputs = zero_outputs  # (P, n_outputs) bool: outputs left at 0.0 (CPU)
        self.population_size = int(w_in.shape[0])
        self.n_inputs = int(w_in.shape[1])
        self.n_outputs = int(w_in.shape[2]) - n_hidden

    @property
    def device(self) -> torch.device:
        return self.w_in.device

    @property
    def dtype(self) -> torch.dtype:
        return self.w_in.dtype

    @property
    def max_depth(self) -> int:
        """Hidden depths evaluated per call (each after the first costs one small matmul)."""
        return len(self.blocks) - 1

    def shard(self, start: int, stop: int) -> "CompiledPopulation":
        """Genomes ``start .. stop - 1`` (it keeps the population's depths, which only adds
        exact no-op steps for shallower shards)."""
        return CompiledPopulation(
            w_in=self.w_in[start:stop], bias=self.bias[start:stop],
            blocks=[(first, last, None if w is None else w[start:stop]) for first, last, w in self.blocks],
            n_hidden=self.n_hidden, genome_keys=self.genome_keys[start:stop],
            unconnected_outputs=self.unconnected_outputs, depths=self.depths[start:stop],
            zero_outputs=self.zero_outputs[start:stop])

    def __call__(self, observations: torch.Tensor) -> torch.Tensor:
        P, E, A, n = observations.shape
        if P != self.population_size or n != self.n_inputs:
            raise ValueError(f"expected observations (population={self.population_size}, envs, "
                             f"agents, {self.n_inputs}), got {tuple(observations.shape)}")
        with torch.no_grad():
            x = observations.reshape(P, E * A, n)
            if x.dtype != self.dtype:
                x = x.to(self.dtype)
            # input part of every slot, (P, E*A, N), then + bias, moved to (P, N, E*A)
            # (x @ w is much faster than w^T @ x^T, which falls off a cliff for 56+ inputs)
            z = torch.empty(P, self.w_in.shape[2], E * A, dtype=self.dtype, device=self.device)
            torch.add(torch.bmm(x, self.w_in).mT, self.bias, out=z)
            for start, stop, w in self.blocks[:-1]:  # hidden depths
                if w is None:  # depth 1: inputs and bias only
                    z[:, start:stop].sigmoid_()
                else:
                    block = z[:, start:stop]
                    torch.sigmoid(_add_weighted(block, w, z, start), out=block)
            start, _stop, w = self.blocks[-1]  # outputs
            pre = z[:, start:] if w is None else _add_weighted(z[:, start:], w, z, start)
            out = torch.empty(P, E * A, self.n_outputs, dtype=z.dtype, device=z.device)
            out.mT.copy_(pre.sigmoid_())  # (faster than a sigmoid that writes transposed)
            return out.view(P, E, A, self.n_outputs)


def _add_weighted(base: torch.Tensor, w: torch.Tensor, z: torch.Tensor, start: int) -> torch.Tensor:
    """``base + w @ z[:, :start]`` as a new tensor. aten's CPU bmm switches to a slow scalar
    kernel for matrices with fewer than 400 multiply-adds, which very few sources (an early
    generation, a thin depth) easily give; a few broadcast multiply-adds are faster there."""
    if start <= 3 and start * w.shape[1] * z.shape[2] < 400:
        out = torch.addcmul(base, w[:, :, 0:1], z[:, 0:1])
        for j in range(1, start):
            out.addcmul_(w[:, :, j:j + 1], z[:, j:j + 1])
        return out
    return torch.baddbmm(base, w, z[:, :start])


def compile_genomes(genomes: Sequence, config, device: str | torch.device = "cpu", *,
                    unconnected_outputs: UnconnectedOutputs = "zero",
                    dtype: torch.dtype = torch.float32) -> CompiledPopulation:
    """Compile neat-python genomes (in the given order) into one batched policy.

    ``config`` is the ``neat.Config`` (or its ``genome_config``) the genomes were made with.
    """
    genome_config = getattr(config, "genome_config", config)
    if unconnected_outputs not in UNCONNECTED_OUTPUTS_MODES:
        raise ValueError(f"unconnected_outputs must be one of {UNCONNECTED_OUTPUTS_MODES}, "
                         f"got {unconnected_outputs!r}")
    genomes = list(genomes)
    if not genomes:
        raise ValueError("compile_genomes needs at least one genome")
    input_index = {k: i for i, k in enumerate(genome_config.input_keys)}
    output_index = {k: i for i, k in enumerate(genome_config.output_keys)}
    n_in, n_out, P = len(input_index), len(output_index), len(genomes)

    per_genome = []      # (hidden slots' nodes by depth, links, computed outputs)
    width: list[int] = []  # max hidden slots per depth (depth 1 at index 0)
    for genome in genomes:
        layers, links = genome_layers(genome, genome_config, unconnected_outputs)
        incoming: dict[int, list[int]] = defaultdict(list)
        for a, b, _w in links:
            incoming[b].append(a)
        sources = {a for a, _b, _w in links}
        depth: dict[int, int] = {}
        by_depth: dict[int, list[int]] = defaultdict(list)
        outputs = set()
        for layer in layers:  # topological order
            for node in layer:
                gene = genome.nodes[node]
                if gene.aggregation != "sum" or gene.activation not in _ACTIVATION_SLOPES:
                    raise NotImplementedError(
                        f"genome {genome.key} node {node}: the batched pass supports aggregation "
                        f"'sum' with activations {sorted(_ACTIVATION_SLOPES)}, got "
                        f"{gene.aggregation!r}/{gene.activation!r}")
                if node in output_index:
                    outputs.add(node)
                    if node not in sources:
                        continue
                d = 1 + max((depth[a] for a in incoming[node] if a not in input_index), default=0)
                depth[node] = d
                by_depth[d].append(node)
        for d, nodes in by_depth.items():
            nodes.sort()
            while len(width) < d:
                width.append(0)
            width[d - 1] = max(width[d - 1], len(nodes))
        per_genome.append((by_depth, links, outputs))

    offsets = [0]
    for w in width:
        offsets.append(offsets[-1] + w)
    n_hidden = offsets[-1]
    N = n_hidden + n_out

    bias_idx: list[tuple[int, int]] = []
    bias_val: list[float] = []
    in_idx: list[tuple[int, int, int]] = []
    in_val: list[float] = []
    hh_idx: list[tuple[int, int, int]] = []
    hh_val: list[float] = []
    zero_outputs = torch.zeros(P, n_out, dtype=torch.bool)
    depths = torch.zeros(P, dtype=torch.long)
    for g, (genome, (by_depth, links, outputs)) in enumerate(zip(genomes, per_genome)):
        hidden_slot: dict[int, int] = {}  # the slot a node's targets read
        for d, nodes in by_depth.items():
            for r, node in enumerate(nodes):
                hidden_slot[node] = offsets[d - 1] + r
        slots: dict[int, list[int]] = defaultdict(list)  # the slots computing each node
        for node, s in hidden_slot.items():
            slots[node].append(s)
        for node in outputs:
            slots[node].append(n_hidden + output_index[node])
        depths[g] = max(by_depth, default=0)
        for key, i in output_index.items():
            if key not in outputs:  # left at 0.0: sigmoid(-inf) with no incoming weights
                zero_outputs[g, i] = True
                bias_idx.append((g, n_hidden + i))
                bias_val.append(-math.inf)
        for node, node_slots in slots.items():
            gene = genome.nodes[node]
            for s in node_slots:
                bias_idx.append((g, s))
                bias_val.append(_ACTIVATION_SLOPES[gene.activation] * gene.bias)
        for a, b, weight in links:
            gene = genome.nodes[b]
            v = _ACTIVATION_SLOPES[gene.activation] * gene.response * weight
            for s in slots[b]:
                if a in input_index:
                    in_idx.append((g, input_index[a], s))
                    in_val.append(v)
                else:
                    hh_idx.append((g, s, hidden_slot[a]))
                    hh_val.append(v)

    def dense(shape, idx, val):
        t = torch.zeros(shape, dtype=torch.float64)
        if idx:
            t[tuple(torch.tensor(idx, dtype=torch.long).T)] = torch.tensor(val, dtype=torch.float64)
        return t.to(dtype)

    device = torch.device(device)
    bias = dense((P, N), bias_idx, bias_val).unsqueeze(2)
    w_in = dense((P, n_in, N), in_idx, in_val)
    w_hh = dense((P, N, max(n_hidden, 1)), hh_idx, hh_val)  # [g, destination, source]
    blocks: list[tuple[int, int, torch.Tensor | None]] = []
    bounds = [(offsets[d], offsets[d + 1]) for d in range(len(width)) if width[d] > 0]
    bounds.append((n_hidden, N))
    for start, stop in bounds:
        w = None if start == 0 else w_hh[:, start:stop, :start].contiguous().to(device)
        blocks.append((start, stop, w))
    return CompiledPopulation(
        w_in=w_in.to(device), bias=bias.to(device), blocks=blocks, n_hidden=n_hidden,
        genome_keys=tuple(g.key for g in genomes), unconnected_outputs=unconnected_outputs,
        depths=depths, zero_outputs=zero_outputs)


__all__ = ["CompiledPopulation", "compile_genomes", "build_neat_config", "neat_components", "neat_config_path",
           "neat_sigmoid", "genome_layers", "NEAT_SIGMOID_SLOPE", "UNCONNECTED_OUTPUTS_MODES"]
