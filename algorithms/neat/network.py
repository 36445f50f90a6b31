"""neat-python genomes as one batched torch policy.

``compile_genomes`` turns a generation's genomes into padded weight tensors once, in two steps:
``layout_genomes`` decides from the genomes' structure which slot computes each node, and
``fill_tensors`` writes the genes' weights and biases into those slots. The resulting
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

import functools
import itertools
import math
from collections import defaultdict
from dataclasses import dataclass
from typing import Literal, Sequence

import torch
from neat.graphs import feed_forward_layers, required_for_output

from envs import numerics

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
                  ) -> tuple[list[set[int]], list[tuple[int, int]]]:
    """The layers of computed nodes and the enabled connections ``(src, dst)`` that feed them
    (in the genome's gene order), for one genome, under ``unconnected_outputs`` (see the module
    docstring)."""
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
    links = [(a, b) for a, b in enabled if b in computed]
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

    @functools.cached_property
    def _grids(self) -> tuple[torch.Tensor, list[torch.Tensor | None]]:
        """The input weights and each block's on ``numerics.exact_bmm``'s grid, made at the first
        portable call (once per generation)."""
        return numerics.grid_weights(self.w_in), [None if w is None else numerics.grid_weights(w)
                                                  for _, _, w in self.blocks]

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
            if numerics.native():
                return self._native_call(x).view(P, E, A, self.n_outputs)
            # input part of every slot plus the bias, (P, E*A, N), moved to (P, N, E*A)
            w_in_grid, block_grids = self._grids
            z = numerics.exact_bmm(x, w_in_grid, self.bias.mT).mT.contiguous()
            for (start, stop, _), w_grid in zip(self.blocks[:-1], block_grids):  # hidden depths
                block = z[:, start:stop]
                block.copy_(numerics.sigmoid(block if w_grid is None else _add_weighted(block, w_grid, z, start)))
            start, _stop, _ = self.blocks[-1]  # outputs
            w_grid = block_grids[-1]
            pre = z[:, start:] if w_grid is None else _add_weighted(z[:, start:], w_grid, z, start)
            return numerics.sigmoid(pre).mT.contiguous().view(P, E, A, self.n_outputs)

    def _native_call(self, x: torch.Tensor) -> torch.Tensor:
        """The pass in torch's own arithmetic (``numerics.use("native")``): ``(P, E*A, outputs)``."""
        P, rows, _ = x.shape
        # (x @ w is much faster than w^T @ x^T, which falls off a cliff for 56+ inputs)
        z = torch.empty(P, self.w_in.shape[2], rows, dtype=self.dtype, device=self.device)
        torch.add(torch.bmm(x, self.w_in).mT, self.bias, out=z)
        for start, stop, w in self.blocks[:-1]:  # hidden depths
            if w is None:  # depth 1: inputs and bias only
                z[:, start:stop].sigmoid_()
            else:
                block = z[:, start:stop]
                torch.sigmoid(_native_add_weighted(block, w, z, start), out=block)
        start, _stop, w = self.blocks[-1]  # outputs
        pre = z[:, start:] if w is None else _native_add_weighted(z[:, start:], w, z, start)
        out = torch.empty(P, rows, self.n_outputs, dtype=z.dtype, device=z.device)
        out.mT.copy_(pre.sigmoid_())  # (faster than a sigmoid that writes transposed)
        return out


def _add_weighted(base: torch.Tensor, w_grid: torch.Tensor, z: torch.Tensor, start: int) -> torch.Tensor:
    """``base + w @ z[:, :start]`` as a new tensor, with ``w @ z`` exact (``numerics.exact_bmm``,
    here with the weights on the left)."""
    total = numerics.grid_bmm(w_grid, numerics.input_grid(z[:, :start])) + base.to(torch.float64)
    return total.to(base.dtype)


def _native_add_weighted(base: torch.Tensor, w: torch.Tensor, z: torch.Tensor, start: int) -> torch.Tensor:
    """``base + w @ z[:, :start]`` in torch's arithmetic. aten's CPU bmm switches to a slow scalar
    kernel for matrices with fewer than 400 multiply-adds, which very few sources (an early
    generation, a thin depth) easily give; a few broadcast multiply-adds are faster there."""
    if start <= 3 and start * w.shape[1] * z.shape[2] < 400:
        out = torch.addcmul(base, w[:, :, 0:1], z[:, 0:1])
        for j in range(1, start):
            out.addcmul_(w[:, :, j:j + 1], z[:, j:j + 1])
        return out
    return torch.baddbmm(base, w, z[:, :start])


# --------------------------------------------------------------------------------------------
# compiling: the layout, then the tensors


@dataclass(frozen=True)
class GenomeSlots:
    """Where one genome's computed nodes go among the population's node slots."""

    links: list[tuple[int, int]]
    """The enabled connections ``(source, target)`` into computed nodes (``genome_layers``)."""
    slots: dict[int, list[int]]
    """Each computed node's slots: its hidden slot if other nodes read it, then its output slot
    if it is an output. Both are computed from the same weights and bias."""
    hidden_slot: dict[int, int]
    """The slot a node's targets read: its hidden slot."""
    zero_outputs: tuple[bool, ...]
    """Per output, in ``output_keys`` order: left at 0.0 (not computed)."""
    depth: int
    """The genome's deepest hidden depth (0: no hidden slots)."""


@dataclass(frozen=True)
class Layout:
    """The node slots of a population: hidden slots ``0 .. n_hidden - 1``, one contiguous block
    per depth as wide as the widest genome's, then one slot per output."""

    genomes: list[GenomeSlots]
    """Each genome's slots, in the population's order."""
    n_hidden: int
    n_slots: int
    """``n_hidden`` plus the outputs."""
    blocks: list[tuple[int, int]]
    """``(start, stop)`` of each hidden depth's slots, shallowest first, then of the outputs."""
    unconnected_outputs: UnconnectedOutputs


def _hidden_depths(genome, genome_config, unconnected_outputs: UnconnectedOutputs
                   ) -> tuple[dict[int, list[int]], set[int], list[tuple[int, int]]]:
    """One genome's nodes that need a hidden slot, by depth (each depth's nodes in ascending
    key order), its computed outputs, and the enabled connections into computed nodes. An
    output needs a hidden slot only when it feeds another node (possible under 0.92's
    genetics)."""
    layers, links = genome_layers(genome, genome_config, unconnected_outputs)
    input_keys, output_keys = set(genome_config.input_keys), set(genome_config.output_keys)
    incoming: dict[int, list[int]] = defaultdict(list)
    for a, b in links:
        incoming[b].append(a)
    sources = {a for a, _b in links}
    depth: dict[int, int] = {}
    by_depth: dict[int, list[int]] = defaultdict(list)
    outputs = set()
    for layer in layers:  # topological order: a node's hidden sources already have their depth
        for node in layer:
            if node in output_keys:
                outputs.add(node)
                if node not in sources:
                    continue
            depth[node] = 1 + max((depth[a] for a in incoming[node] if a not in input_keys), default=0)
            by_depth[depth[node]].append(node)
    return {d: sorted(nodes) for d, nodes in by_depth.items()}, outputs, links


def layout_genomes(genomes: Sequence, genome_config, unconnected_outputs: UnconnectedOutputs) -> Layout:
    """The slot of every computed node of ``genomes`` (at least one), from their structure alone
    (which nodes and enabled connections they have, never a weight or bias): hidden depth ``d`` gets as many
    slots as the genome with the most nodes at that depth has, a genome's nodes take that
    depth's first slots in ascending key order, and the outputs come last (module docstring,
    Layout)."""
    placed = [_hidden_depths(genome, genome_config, unconnected_outputs) for genome in genomes]
    deepest = max(max(by_depth, default=0) for by_depth, _outputs, _links in placed)
    width = [max(len(by_depth.get(d, ())) for by_depth, _outputs, _links in placed) for d in range(1, deepest + 1)]
    offsets = [0, *itertools.accumulate(width)]  # offsets[d - 1]: the first slot of depth d
    n_hidden = offsets[-1]
    output_slot = {key: n_hidden + i for i, key in enumerate(genome_config.output_keys)}

    layouts = []
    for by_depth, outputs, links in placed:
        hidden_slot = {node: offsets[d - 1] + r for d, nodes in by_depth.items() for r, node in enumerate(nodes)}
        slots = {node: [slot] for node, slot in hidden_slot.items()}
        for node in outputs:
            slots.setdefault(node, []).append(output_slot[node])
        layouts.append(GenomeSlots(
            links=links, slots=slots, hidden_slot=hidden_slot,
            zero_outputs=tuple(key not in outputs for key in genome_config.output_keys),
            depth=max(by_depth, default=0)))
    # no depth is empty: a node at depth d reads one at depth d - 1
    blocks = [(offsets[d], offsets[d + 1]) for d in range(deepest)]
    blocks.append((n_hidden, n_hidden + len(output_slot)))
    return Layout(genomes=layouts, n_hidden=n_hidden, n_slots=n_hidden + len(output_slot), blocks=blocks,
                  unconnected_outputs=unconnected_outputs)


def _activation_slope(genome, node: int) -> float:
    """The slope of node ``node``'s activation; NotImplementedError for a node the batched
    pass cannot compute."""
    gene = genome.nodes[node]
    if gene.aggregation != "sum" or gene.activation not in _ACTIVATION_SLOPES:
        raise NotImplementedError(
            f"genome {genome.key} node {node}: the batched pass supports aggregation "
            f"'sum' with activations {sorted(_ACTIVATION_SLOPES)}, got "
            f"{gene.aggregation!r}/{gene.activation!r}")
    return _ACTIVATION_SLOPES[gene.activation]


def _dense(shape: tuple[int, ...], entries: dict[tuple[int, ...], float], dtype: torch.dtype) -> torch.Tensor:
    """A float64 tensor of zeros with ``entries`` (index: value) set, then cast to ``dtype``."""
    t = torch.zeros(shape, dtype=torch.float64)
    if entries:
        t[tuple(torch.tensor(list(entries), dtype=torch.long).T)] = torch.tensor(list(entries.values()),
                                                                               dtype=torch.float64)
    return t.to(dtype)


def fill_tensors(genomes: Sequence, layout: Layout, genome_config, device: str | torch.device = "cpu",
                 dtype: torch.dtype = torch.float32) -> CompiledPopulation:
    """The batched policy of ``genomes`` on ``layout`` (``layout_genomes`` of the same genomes
    in the same order): each computed node's slots get ``slope * bias`` and, per enabled incoming
    connection, ``slope * response * weight`` (computed in float64, then cast to ``dtype``); an
    output left at 0.0 gets bias ``-inf`` and no weights; everything else is 0."""
    input_index = {k: i for i, k in enumerate(genome_config.input_keys)}
    P, n_in, N, n_hidden = len(genomes), len(input_index), layout.n_slots, layout.n_hidden
    bias: dict[tuple[int, int], float] = {}  # (genome, slot)
    w_in: dict[tuple[int, int, int], float] = {}  # (genome, input, slot)
    w_hh: dict[tuple[int, int, int], float] = {}  # (genome, slot, the hidden slot it reads)
    for g, (genome, placed) in enumerate(zip(genomes, layout.genomes)):
        for i, zero in enumerate(placed.zero_outputs):
            if zero:  # sigmoid(-inf) is exactly 0.0
                bias[g, n_hidden + i] = -math.inf
        slope = {node: _activation_slope(genome, node) for node in placed.slots}
        for node, slots in placed.slots.items():
            for s in slots:
                bias[g, s] = slope[node] * genome.nodes[node].bias
        for a, b in placed.links:
            value = slope[b] * genome.nodes[b].response * genome.connections[a, b].weight
            for s in placed.slots[b]:
                if a in input_index:
                    w_in[g, input_index[a], s] = value
                else:
                    w_hh[g, s, placed.hidden_slot[a]] = value

    device = torch.device(device)
    weights_between = _dense((P, N, max(n_hidden, 1)), w_hh, dtype)  # [genome, destination, source]
    blocks = [(start, stop, None if start == 0 else weights_between[:, start:stop, :start].contiguous().to(device))
              for start, stop in layout.blocks]
    return CompiledPopulation(
        w_in=_dense((P, n_in, N), w_in, dtype).to(device), bias=_dense((P, N), bias, dtype).unsqueeze(2).to(device),
        blocks=blocks, n_hidden=n_hidden, genome_keys=tuple(genome.key for genome in genomes),
        unconnected_outputs=layout.unconnected_outputs,
        depths=torch.tensor([placed.depth for placed in layout.genomes], dtype=torch.long),
        zero_outputs=torch.tensor([placed.zero_outputs for placed in layout.genomes], dtype=torch.bool))


def compile_genomes(genomes: Sequence, config, device: str | torch.device = "cpu", *,
                    unconnected_outputs: UnconnectedOutputs = "zero",
                    dtype: torch.dtype = torch.float32) -> CompiledPopulation:
    """Compile neat-python genomes (in the given order) into one batched policy: the layout
    of their nodes (``layout_genomes``), then the tensors (``fill_tensors``).

    ``config`` is the ``neat.Config`` (or its ``genome_config``) the genomes were made with.
    """
    genome_config = getattr(config, "genome_config", config)
    if unconnected_outputs not in UNCONNECTED_OUTPUTS_MODES:
        raise ValueError(f"unconnected_outputs must be one of {UNCONNECTED_OUTPUTS_MODES}, "
                         f"got {unconnected_outputs!r}")
    genomes = list(genomes)
    if not genomes:
        raise ValueError("compile_genomes needs at least one genome")
    layout = layout_genomes(genomes, genome_config, unconnected_outputs)
    return fill_tensors(genomes, layout, genome_config, device, dtype)


__all__ = ["CompiledPopulation", "GenomeSlots", "Layout", "compile_genomes", "fill_tensors", "genome_layers",
           "layout_genomes", "neat_sigmoid", "NEAT_SIGMOID_SLOPE", "UNCONNECTED_OUTPUTS_MODES"]
