"""The batched NEAT forward pass against neat-python's own networks.

"bias" mode must equal neat-python 2.0's ``FeedForwardNetwork`` exactly (up to float32);
"zero" mode must equal neat-python 0.92's ``FeedForwardNetwork`` (the version the paper ran),
re-implemented below from 0.92's source, and also 2.0's network with the outputs 0.92 leaves
unevaluated set to 0.0.
"""
from __future__ import annotations

import copy
import math
import random

import neat
import pytest
import torch
from neat.innovation import InnovationTracker

from envs import numerics

from algorithms.neat.config import build_neat_config
from algorithms.neat.genetics import GENETICS
from algorithms.neat.network import (
    CompiledPopulation,
    _add_weighted,
    compile_genomes,
    fill_tensors,
    genome_layers,
    layout_genomes,
    neat_sigmoid,
)

HEAVY = {"DefaultGenome": {"node_add_prob": 0.5, "conn_add_prob": 0.5,
                           "node_delete_prob": 0.15, "conn_delete_prob": 0.2,
                           "enabled_mutate_rate": 0.05}}
"""Many hidden nodes, deletions and disabled connections (so dangling hidden nodes)."""
SPARSE = {"DefaultGenome": {"initial_connection": "partial_direct 0.03", "node_add_prob": 0.5,
                            "conn_add_prob": 0.3, "enabled_mutate_rate": 0.1}}
"""Few initial connections: outputs without any incoming connection."""


@pytest.fixture(autouse=True)
def _keep_global_random():
    state = random.getstate()
    yield
    random.setstate(state)


# ------------------------------------------------------------------------------------------
# neat-python 0.92's FeedForwardNetwork (neat/graphs.py and neat/nn/feed_forward.py of
# neat-python 0.92, as released on PyPI), kept literal on purpose.


def _required_for_output_v092(inputs, outputs, connections):
    required = set(outputs)
    s = set(outputs)
    while 1:
        t = set(a for (a, b) in connections if b in s and a not in s)
        if not t:
            break
        layer_nodes = set(x for x in t if x not in inputs)
        if not layer_nodes:
            break
        required = required.union(layer_nodes)
        s = s.union(t)
    return required


def _feed_forward_layers_v092(inputs, outputs, connections):
    required = _required_for_output_v092(inputs, outputs, connections)
    layers = []
    s = set(inputs)
    while 1:
        c = set(b for (a, b) in connections if a in s and b not in s)
        t = set()
        for n in c:
            if n in required and all(a in s for (a, b) in connections if b == n):
                t.add(n)
        if not t:
            break
        layers.append(t)
        s = s.union(t)
    return layers


class _FeedForwardNetworkV092:
    def __init__(self, genome, config):
        gc = config.genome_config
        connections = [cg.key for cg in genome.connections.values() if cg.enabled]
        layers = _feed_forward_layers_v092(gc.input_keys, gc.output_keys, connections)
        self.node_evals = []
        for layer in layers:
            for node in layer:
                inputs = []
                for conn_key in connections:
                    inode, onode = conn_key
                    if onode == node:
                        inputs.append((inode, genome.connections[conn_key].weight))
                ng = genome.nodes[node]
                self.node_evals.append((node, gc.activation_defs.get(ng.activation),
                                        gc.aggregation_function_defs.get(ng.aggregation),
                                        ng.bias, ng.response, inputs))
        self.input_nodes, self.output_nodes = gc.input_keys, gc.output_keys
        self.values = dict((key, 0.0) for key in self.input_nodes + self.output_nodes)

    def activate(self, inputs):
        for k, v in zip(self.input_nodes, inputs):
            self.values[k] = v
        for node, act_func, agg_func, bias, response, links in self.node_evals:
            s = agg_func([self.values[i] * w for i, w in links])
            self.values[node] = act_func(bias + response * s)
        return [self.values[i] for i in self.output_nodes]


# ------------------------------------------------------------------------------------------
# genomes and observations


def _fresh_config(num_inputs=41, overrides=None, pop_size=300, genetics="0.92"):
    config = build_neat_config(num_inputs, pop_size, overrides, genetics=genetics)
    config.genome_config.innovation_tracker = InnovationTracker()
    return config


def _fresh_genomes(config, n, first_key=1):
    out = []
    for key in range(first_key, first_key + n):
        g = config.genome_type(key)
        g.configure_new(config.genome_config)
        out.append(g)
    return out


def _mutated_genomes(config, n, low=50, high=200):
    out = _fresh_genomes(config, n)
    for g in out:
        for _ in range(random.randint(low, high)):
            g.mutate(config.genome_config)
    return out


def _evolved_genomes(config, generations=4):
    """Genomes of every generation of a short real neat-python run, and each generation's size."""
    seen, sizes = [], []
    # a private generator: the probe must not depend on which tests ran before this one
    draw = random.Random(11)
    probe = [draw.choice((0.0, 1.0)) if i % 2 else draw.uniform(-1, 1)
             for i in range(config.genome_config.num_inputs)]

    def evaluate(genomes, cfg):
        sizes.append(len(genomes))
        for _key, g in genomes:
            out = neat.nn.FeedForwardNetwork.create(g, cfg).activate(probe)
            g.fitness = out[0] - out[1] + 0.1 * len(g.connections)
            seen.append(copy.deepcopy(g))

    population = neat.Population(config, seed=7)
    population.run(evaluate, generations)
    return seen, sizes


def _observations(P, E, A, n, generator):
    """Like real observations: a mix of 0/1 one-hot entries and floats in [-1, 1]."""
    onehot = (torch.rand(P, E, A, n, generator=generator) < 0.3).float()
    floats = torch.rand(P, E, A, n, generator=generator) * 2 - 1
    pick = torch.rand(1, 1, 1, n, generator=generator) < 0.6
    return torch.where(pick, onehot, floats)


def _reference(genomes, config, obs, mode):
    """(P, E, A, 3) float64 outputs of neat-python networks, one genome at a time."""
    P, E, A, n = obs.shape
    out = torch.zeros(P, E, A, 3, dtype=torch.float64)
    for i, g in enumerate(genomes):
        net = (neat.nn.FeedForwardNetwork.create(g, config) if mode == "bias"
               else _FeedForwardNetworkV092(g, config))
        for e in range(E):
            for a in range(A):
                out[i, e, a] = torch.tensor(net.activate(obs[i, e, a].double().tolist()))
    return out


def _check_parity(genomes, config, mode, seed=0, E=2, A=3, device="cpu"):
    gen = torch.Generator().manual_seed(seed)
    obs = _observations(len(genomes), E, A, config.genome_config.num_inputs, gen)
    policy = compile_genomes(genomes, config, device, unconnected_outputs=mode)
    got = policy(obs.to(device))
    assert got.shape == (len(genomes), E, A, 3) and got.dtype == torch.float32
    assert got.device.type == torch.device(device).type
    got = got.cpu()
    want = _reference(genomes, config, obs, mode)
    err = (got.double() - want).abs().max().item()
    assert err < 1e-5, f"{mode}: max error {err}"
    return policy, obs, got


def _stats(genomes, config):
    """How many genomes show each structure the pass has to get right."""
    gc = config.genome_config
    stats = dict(bias_neuron=0, dead_output=0, disabled=0, deep=0, no_input_output=0, output_source=0)
    for g in genomes:
        enabled = [k for k, c in g.connections.items() if c.enabled]
        targets = {b for _a, b in enabled}
        stats["output_source"] += any(a in gc.output_keys for a, _b in enabled)
        required = neat.graphs.required_for_output(gc.input_keys, gc.output_keys, enabled)
        stats["bias_neuron"] += any(n not in targets for n in required if n not in gc.output_keys)
        stats["no_input_output"] += any(o not in targets for o in gc.output_keys)
        layers, _ = genome_layers(g, gc, "zero")
        computed = set().union(*layers) if layers else set()
        stats["dead_output"] += any(o not in computed for o in gc.output_keys)
        stats["disabled"] += any(not c.enabled for c in g.connections.values())
        stats["deep"] += len(layers) >= 4
    return stats


# ------------------------------------------------------------------------------------------


def test_neat_sigmoid_is_the_papers_activation():
    for x in (-1.0, -0.2, 0.0, 0.3, 2.0):
        assert neat_sigmoid(x) == pytest.approx(1.0 / (1.0 + math.exp(-4.9 * x)), rel=1e-12)
    assert neat_sigmoid(-1e6) == pytest.approx(1.0 / (1.0 + math.exp(60.0)))  # no OverflowError
    assert neat_sigmoid(1e6) == 1.0


def test_config_registers_the_activation_and_sizes():
    for n in (41, 61):
        config = build_neat_config(n, 50)
        assert config.genome_config.num_inputs == n and config.pop_size == 50
        assert config.genome_config.activation_defs.get("neat_sigmoid") is neat_sigmoid
    with pytest.raises(KeyError):
        build_neat_config(41, 50, {"DefaultGenome": {"no_such_option": 1}})


def _hand_genome(config):
    """Output 0 = sig(b0 - 1 * sig(b5 + 0.5 x1) + 2 x2); output 1 fed only by hidden 7, which
    has no enabled input (its input -3 -> 7 is disabled) and by a disabled -4 -> 1; output 2
    has no connection at all."""
    gc = config.genome_config
    g = config.genome_type(1)
    for key, bias in ((0, 0.1), (1, -0.3), (2, 0.7), (5, -0.2), (7, 0.4)):
        g.nodes[key] = g.create_node(gc, key)
        g.nodes[key].bias = bias
    for (a, b, w, on) in ((-1, 5, 0.5, True), (5, 0, -1.0, True), (-2, 0, 2.0, True),
                          (7, 1, 1.5, True), (-3, 7, 0.8, False), (-4, 1, 3.0, False)):
        g.add_connection(gc, a, b, w, on)
    return g


def test_hand_built_genome_in_both_modes():
    config = _fresh_config(num_inputs=4)
    g = _hand_genome(config)
    x = [0.3, -0.6, 1.0, 1.0]

    def sig(v):
        return 1.0 / (1.0 + math.exp(-4.9 * v))

    out0 = sig(0.1 - 1.0 * sig(-0.2 + 0.5 * x[0]) + 2.0 * x[1])
    expected = {"zero": [out0, 0.0, 0.0], "bias": [out0, sig(-0.3 + 1.5 * sig(0.4)), sig(0.7)]}
    obs = torch.tensor(x).view(1, 1, 1, 4)
    for mode, want in expected.items():
        got = compile_genomes([g], config, unconnected_outputs=mode)(obs).view(3).tolist()
        assert got == pytest.approx(want, abs=1e-6), mode
    # neat-python 2.0 itself: bias neurons, not zeros
    assert neat.nn.FeedForwardNetwork.create(g, config).activate(x) == pytest.approx(
        expected["bias"], abs=1e-12)
    assert _FeedForwardNetworkV092(g, config).activate(x) == pytest.approx(
        expected["zero"], abs=1e-12)


def test_output_feeding_a_hidden_node():
    """neat-python 0.92's genomes may start a connection at an output: output 0 feeds hidden 5,
    which feeds output 1. With output 0's only input disabled, 0.92 computes neither output 0
    nor what it feeds; 2.0 makes it a bias neuron."""
    config = _fresh_config(num_inputs=2)
    gc = config.genome_config
    g = config.genome_type(1)
    for key, bias in ((0, 0.1), (1, 0.3), (2, 0.0), (5, -0.2)):
        g.nodes[key] = g.create_node(gc, key)
        g.nodes[key].bias = bias
    for a, b, w in ((-1, 0, 1.5), (0, 5, -2.0), (-2, 5, 0.5), (5, 1, 1.0), (-2, 2, 0.7)):
        g.add_connection(gc, a, b, w, True)
    x = [0.4, -0.9]

    def sig(v):
        return 1.0 / (1.0 + math.exp(-4.9 * v))

    def expected(out0):
        return [out0, sig(0.3 + sig(-0.2 - 2.0 * out0 + 0.5 * x[1])), sig(0.7 * x[1])]

    obs = torch.tensor(x).view(1, 1, 1, 2)
    for mode in ("zero", "bias"):
        policy = compile_genomes([g], config, unconnected_outputs=mode)
        assert policy(obs).view(3).tolist() == pytest.approx(expected(sig(0.1 + 1.5 * x[0])), abs=1e-6)
        assert policy.max_depth == 2
    g.connections[(-1, 0)].enabled = False
    want = {"zero": [0.0, 0.0, sig(0.7 * x[1])], "bias": expected(sig(0.1))}
    for mode, values in want.items():
        got = compile_genomes([g], config, unconnected_outputs=mode)(obs).view(3).tolist()
        assert got == pytest.approx(values, abs=1e-6), mode
    assert neat.nn.FeedForwardNetwork.create(g, config).activate(x) == pytest.approx(want["bias"], abs=1e-12)
    assert _FeedForwardNetworkV092(g, config).activate(x) == pytest.approx(want["zero"], abs=1e-12)


@pytest.mark.parametrize("genetics", GENETICS)
def test_fresh_genomes_match_neat_python(genetics):
    config = _fresh_config(genetics=genetics)
    genomes = _fresh_genomes(config, 120)
    for mode in ("zero", "bias"):
        _check_parity(genomes, config, mode)


@pytest.mark.parametrize("genetics", GENETICS)
def test_heavily_mutated_genomes_match_neat_python(genetics):
    random.seed(3)
    config = _fresh_config(overrides=HEAVY, genetics=genetics)
    sparse = _fresh_config(overrides=SPARSE, genetics=genetics)
    sparse.genome_config.innovation_tracker = config.genome_config.innovation_tracker
    genomes = _mutated_genomes(config, 40, 20, 120) + _mutated_genomes(sparse, 40, 0, 60)
    for key, g in enumerate(genomes):
        g.key = key
    stats = _stats(genomes, config)
    # the population exercises every special case (2.0's genomes never start a connection at an output)
    assert (stats.pop("output_source") >= 3) == (genetics == "0.92")
    for what, count in stats.items():
        assert count >= 3, (what, stats)
    for mode in ("zero", "bias"):
        policy, obs, got = _check_parity(genomes, config, mode, seed=1, E=4, A=5)
        assert policy.max_depth >= 4
        assert int((policy.depths >= 3).sum()) >= 5
    assert int((~policy.zero_outputs).sum()) == 3 * len(genomes)  # bias mode: none left at 0
    # zero mode = neat-python 2.0 with the outputs 0.92 never computes set to 0.0
    zero = compile_genomes(genomes, config, unconnected_outputs="zero")
    live = ~zero.zero_outputs
    assert 30 <= int(live.sum()) < 3 * len(genomes)
    assert int((zero.depths[live.all(dim=1)] >= 2).sum()) >= 3
    want = _reference(genomes, config, obs, "bias")
    want[zero.zero_outputs[:, None, None, :].expand_as(want)] = 0.0
    assert (zero(obs).double() - want).abs().max().item() < 1e-5


@pytest.mark.parametrize("genetics", GENETICS)
def test_evolved_genomes_match_neat_python(genetics):
    config = _fresh_config(pop_size=40, genetics=genetics)
    genomes, sizes = _evolved_genomes(config)
    assert len(sizes) == 4 and sizes[0] == 40
    if genetics == "2.0":
        assert sizes == [40] * 4
    else:  # 0.92's spawn counts let the population drift by a few genomes
        assert all(abs(size - 40) <= 5 for size in sizes), sizes
    for mode in ("zero", "bias"):
        _check_parity(genomes, config, mode, seed=2, E=1, A=2)


def test_population_without_hidden_nodes():
    config = _fresh_config(overrides={"DefaultGenome": {"num_hidden": 0}})
    genomes = _fresh_genomes(config, 5)
    genomes[0].connections = {k: c for k, c in genomes[0].connections.items() if k[1] != 2}
    for mode in ("zero", "bias"):
        policy, _obs, got = _check_parity(genomes, config, mode, E=1, A=2)
        assert policy.n_hidden == 0 and policy.max_depth == 0
        assert bool((got[0, ..., 2] == 0).all()) == (mode == "zero")


def test_padding_does_not_change_a_genome():
    random.seed(4)
    config = _fresh_config(overrides=HEAVY)
    genomes = _mutated_genomes(config, 12, 0, 150)
    gen = torch.Generator().manual_seed(5)
    obs = _observations(len(genomes), 3, 5, 41, gen)
    together = compile_genomes(genomes, config)(obs)
    for i, g in enumerate(genomes):
        alone = compile_genomes([g], config)(obs[i:i + 1])
        assert torch.equal(alone, together[i:i + 1])  # exact products: padding adds exact zeros


def test_the_layout_reads_the_structure_only():
    """``layout_genomes`` places nodes by which nodes and enabled connections a genome has: other
    weights (zero among them), biases and responses leave it as it was, and ``fill_tensors`` on
    it is ``compile_genomes``."""
    random.seed(9)
    config = _fresh_config(overrides=HEAVY)
    genomes = _mutated_genomes(config, 10, 0, 150)
    gc = config.genome_config
    layout = layout_genomes(genomes, gc, "zero")
    assert layout.n_hidden > 0 and len(layout.blocks) >= 3
    for g in genomes:
        for c in g.connections.values():
            c.weight = 0.0
        for n in g.nodes.values():
            n.bias, n.response = random.uniform(-5, 5), random.uniform(0.5, 2)
    assert layout_genomes(genomes, gc, "zero") == layout
    obs = _observations(len(genomes), 2, 3, 41, torch.Generator().manual_seed(10))
    assert torch.equal(fill_tensors(genomes, layout, gc)(obs), compile_genomes(genomes, config)(obs))


def test_shard_gives_the_populations_outputs():
    random.seed(7)
    config = _fresh_config(overrides=HEAVY)
    genomes = _mutated_genomes(config, 12, 0, 150)
    policy = compile_genomes(genomes, config)
    obs = _observations(len(genomes), 3, 5, 41, torch.Generator().manual_seed(8))
    together = policy(obs)
    for start, stop in ((0, 5), (5, 12), (11, 12)):
        shard = policy.shard(start, stop)
        assert shard.population_size == stop - start and shard.genome_keys == policy.genome_keys[start:stop]
        assert torch.equal(shard(obs[start:stop]), together[start:stop])


@pytest.mark.parametrize("start,K,rows", [(1, 3, 50), (3, 2, 50), (11, 3, 50), (70, 2, 6), (8, 1, 6)])
def test_add_weighted_is_exact_on_the_grid(start, K, rows):
    """Hidden sources times weights, on envs.numerics' grid: the sum is the exact one (whatever
    order the BLAS adds in, and across chunks of 64 sources), then rounded once with the base."""
    gen = torch.Generator().manual_seed(start * 100 + K)
    z = torch.rand(7, start + K + 2, rows, generator=gen)  # hidden values lie in [0, 1]
    w = torch.randn(7, K, start, generator=gen)
    base = z[:, start:start + K]
    w_grid, sources = numerics.grid_weights(w), numerics.input_grid(z[:, :start])
    exact = sum(w_grid[:, :, j:j + 1] * sources[:, j:j + 1] for j in range(start))  # integers: exact
    want = (base.double() + exact * numerics.GRID_UNIT).float()  # (here below 2**53 beyond a chunk too)
    got = _add_weighted(base, w_grid, z, start)
    assert got.shape == (7, K, rows)
    assert torch.equal(got, want)
    real = base.double() + torch.bmm(w.double(), z[:, :start].double())
    assert torch.allclose(got.double(), real, atol=1e-4)


def test_policy_protocol_and_errors():
    config = _fresh_config(num_inputs=61)
    genomes = _fresh_genomes(config, 7)
    policy = compile_genomes(genomes, config)
    assert isinstance(policy, CompiledPopulation)
    assert policy.population_size == 7 and policy.genome_keys == tuple(range(1, 8))
    obs = torch.rand(7, 4, 5, 61, dtype=torch.float64)  # any float dtype is accepted
    out = policy(obs)
    assert out.shape == (7, 4, 5, 3) and out.is_contiguous() and out.dtype == torch.float32
    assert bool(((out >= 0) & (out <= 1)).all())
    with pytest.raises(ValueError):
        policy(torch.rand(6, 4, 5, 61))
    with pytest.raises(ValueError):
        policy(torch.rand(7, 4, 5, 41))
    with pytest.raises(ValueError):
        compile_genomes(genomes, config, unconnected_outputs="nan")
    genomes[0].nodes[0].activation = "tanh"
    with pytest.raises(NotImplementedError):
        compile_genomes(genomes, config)
