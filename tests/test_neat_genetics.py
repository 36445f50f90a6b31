"""neat-python 0.92's genetics (``algorithms.neat.genetics``): gene for gene what neat-python
0.92 itself evolves (0.92 is installed with pip into a directory of the test session's own and
run in a subprocess), and each difference from neat-python 2.0 on its own."""
from __future__ import annotations

import configparser
import functools
import json
import random
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from neat.graphs import creates_cycle
from neat.innovation import InnovationTracker

from algorithms.neat import NeatOptimizer
from algorithms.neat.config import build_neat_config, neat_config_path
from algorithms.neat.genetics import GENETICS, Neat092ConnectionGene, check_genetics, spawn_counts

try:
    from neat092_reference import fitness, snapshot
except ImportError:  # tests/ imported as a package
    from tests.neat092_reference import fitness, snapshot

REFERENCE_SCRIPT = Path(__file__).with_name("neat092_reference.py")
UNREACHABLE = ("(from versions: none)", "NewConnectionError", "Failed to establish a new connection",
               "Temporary failure in name resolution", "Name or service not known", "Network is unreachable",
               "ConnectTimeoutError", "ReadTimeoutError", "Max retries exceeded", "ProxyError")
"""What pip says when it cannot reach the package index (the only reason to skip the parity)."""

PARITY_RUNS = [(8, 100, 40), (2, 60, 80)]
"""(seed, population, generations): between them, several species, species dropped as stagnant,
population sizes off ``pop_size``, outputs feeding hidden nodes and many fitness ties."""


@pytest.fixture(autouse=True)
def _keep_global_random():
    state = random.getstate()
    yield
    random.setstate(state)


# ------------------------------------------------------------------------------------------
# neat-python 0.92 itself


@pytest.fixture(scope="session")
def neat092(pytestconfig, tmp_path_factory) -> Path:
    """A directory holding neat-python 0.92, installed there by pip once (kept in pytest's
    cache between sessions), never into the project's environment."""
    cache = getattr(pytestconfig, "cache", None)
    target = cache.mkdir("neat-python-0.92") if cache is not None else tmp_path_factory.mktemp("neat-python-0.92")
    if (target / "neat_python-0.92.dist-info").is_dir():
        return target
    result = subprocess.run(
        [sys.executable, "-m", "pip", "install", "--no-deps", "--upgrade", "--no-input",
         "--disable-pip-version-check", "--retries", "1", "--timeout", "20", "--target", str(target),
         "neat-python==0.92"], capture_output=True, text=True)
    if result.returncode != 0:
        output = result.stdout + result.stderr
        if any(sign in output for sign in UNREACHABLE):
            pytest.skip("pip cannot reach the package index to install neat-python 0.92 "
                        f"({output.strip().splitlines()[-1]})")
        pytest.fail(f"pip could not install neat-python 0.92:\n{output}")
    return target


@pytest.fixture(scope="session")
def reference_run(neat092, tmp_path_factory):
    """``(seed, population, generations) -> neat-python 0.92's run`` (``neat092_reference``),
    with the paper's configuration file as the project reads it."""
    folder = tmp_path_factory.mktemp("neat092-runs")

    @functools.cache
    def run(seed: int, population: int, generations: int) -> dict:
        parser = configparser.ConfigParser()
        parser.read(neat_config_path())
        parser["NEAT"]["pop_size"] = str(population)
        parser["DefaultGenome"]["num_inputs"] = "41"
        config = folder / f"config-{population}.ini"
        with open(config, "w") as handle:
            parser.write(handle)
        out = folder / f"run-{seed}-{population}-{generations}.json"
        # -I: neither PYTHONPATH nor the working directory can put 2.0 (or the project) first
        subprocess.run([sys.executable, "-I", str(REFERENCE_SCRIPT), str(neat092), str(config), str(seed),
                        str(generations), str(out)], check=True)
        data = json.loads(out.read_text())
        assert Path(data["neat_file"]).is_relative_to(neat092)
        return data

    return run


def _our_run(seed: int, population: int, generations: int, genetics: str = "0.92"):
    """The optimiser, treated as ``neat092_reference`` treats neat-python 0.92: snapshots of
    every evaluated generation (as JSON reads them back), and the optimiser."""
    opt = NeatOptimizer(obs_dim=41, population_size=population, seed=seed, genetics=genetics)
    snapshots = []
    for _ in range(generations):
        opt.ask()
        snapshots.append(json.loads(json.dumps(snapshot(opt.population, opt.species))))
        scores = torch.tensor([fitness(g) for g in opt.asked_genomes], dtype=torch.float64)
        opt.tell(scores, scores)
    return snapshots, opt


def _first_difference(ours: list, theirs: list) -> int | None:
    return next((g for g, (a, b) in enumerate(zip(ours, theirs)) if a != b), None)


@pytest.mark.parametrize("seed,population,generations", PARITY_RUNS)
def test_evolves_what_neat_python_092_evolves(reference_run, seed, population, generations):
    """Same seed, same fitness: every gene of every genome (keys, weights, biases, enabled
    flags, in their dicts' order), every species (representative and members, in order) and,
    at the end, the state of ``random``: equal to neat-python 0.92's, in every generation."""
    reference = reference_run(seed, population, generations)
    theirs = reference["snapshots"]
    ours, opt = _our_run(seed, population, generations)
    assert len(ours) == len(theirs) == generations
    assert _first_difference(ours, theirs) is None, f"first difference at generation {_first_difference(ours, theirs)}"
    assert json.loads(json.dumps(opt._random_state)) == reference["random_state"]

    # the run went through what tells the versions apart
    sizes = [len(s["genomes"]) for s in theirs]
    assert any(size != population for size in sizes), "the population size never drifted"
    assert max(len(s["species"]) for s in theirs) >= 3
    alive = [{sid for sid, _rep, _members in s["species"]} for s in theirs]
    assert any(before - after for before, after in zip(alive, alive[1:])), "no species was dropped"
    connections = [c for s in theirs for _key, _nodes, conns in s["genomes"] for c in conns]
    assert any(0 <= source < 3 for source, _target, _w, _on in connections), "no output fed a node"
    assert any(not on for _s, _t, _w, on in connections)


def test_parity_sees_the_75_percent_rule_and_2_0(reference_run, monkeypatch):
    """The parity test fails for neat-python 2.0's genetics, and for 0.92's with 2.0's rule that
    disables a crossed-over connection with p = 0.75 when either parent's is disabled."""
    seed, population, generations = PARITY_RUNS[0]
    theirs = reference_run(seed, population, generations)["snapshots"]
    assert _first_difference(_our_run(seed, population, 3, genetics="2.0")[0], theirs) == 0

    crossover = Neat092ConnectionGene.crossover

    def with_the_75_percent_rule(self, gene2):
        child = crossover(self, gene2)
        if not (self.enabled and gene2.enabled) and random.random() < 0.75:
            child.enabled = False
        return child

    monkeypatch.setattr(Neat092ConnectionGene, "crossover", with_the_75_percent_rule)
    ours, _opt = _our_run(seed, population, 15)
    assert _first_difference(ours, theirs) is not None


# ------------------------------------------------------------------------------------------
# each difference on its own


def _genome_config(genetics: str, num_inputs: int = 41):
    gc = build_neat_config(num_inputs, 10, genetics=genetics).genome_config
    gc.innovation_tracker = InnovationTracker()
    return gc


def _fresh_genome(genetics: str, key: int = 1):
    config = build_neat_config(41, 10, genetics=genetics)
    gc = config.genome_config
    gc.innovation_tracker = InnovationTracker()
    genome = config.genome_type(key)
    genome.configure_new(gc)
    return genome, gc


def test_spawn_counts_follow_neat_pythons_rule():
    """``spawn_counts`` is neat-python's ``compute_spawn`` (the same counts on Python 3.11, where
    both add the fitnesses left to right), over species that grow, shrink, stay and sit at the
    minimum, and a population with no adjusted fitness at all."""
    import neat

    draw = random.Random(3)
    cases = [([0.0, 0.0], [10, 20], 30, 2)]
    for _ in range(300):
        n = draw.randint(1, 8)
        cases.append(([draw.choice([0.0, draw.random(), draw.random() / 7]) for _ in range(n)],
                      [draw.randint(1, 60) for _ in range(n)], draw.randint(20, 300), draw.randint(1, 5)))
    for case in cases:
        assert spawn_counts(*case) == neat.DefaultReproduction.compute_spawn(*case), case
    assert len({tuple(spawn_counts(*case)) for case in cases}) > 250  # the cases are not all alike


def test_genetics_values():
    assert GENETICS == ("0.92", "2.0")
    assert check_genetics("0.92") == "0.92" and check_genetics("2.0") == "2.0"
    for bad in ("2", "0.9", 1, 2.0, 0.92, "neat"):
        with pytest.raises(ValueError, match="genetics must be one of '0.92', '2.0'"):
            check_genetics(bad)
    with pytest.raises(ValueError, match="genetics must be one of"):
        NeatOptimizer(obs_dim=41, population_size=10, seed=0, genetics="1.0")
    assert NeatOptimizer(obs_dim=41, population_size=10, seed=0).genetics == "0.92"


@pytest.mark.parametrize("genetics,disabled_share", [("0.92", 0.5), ("2.0", 0.875)])
def test_crossover_of_a_connection_disabled_in_one_parent(genetics, disabled_share):
    """0.92 takes ``enabled`` from either parent (two draws per connection: weight, enabled);
    2.0 then disables the child's with p = 0.75 (a third draw)."""
    gene_type = _genome_config(genetics).connection_gene_type
    on, off = gene_type((-1, 0), innovation=1), gene_type((-1, 0), innovation=1)
    on.weight, on.enabled, off.weight, off.enabled = 0.5, True, -0.5, False
    random.seed(0)
    children = [on.crossover(off) for _ in range(4000)]
    assert sum(not c.enabled for c in children) / len(children) == pytest.approx(disabled_share, abs=0.03)
    assert {c.weight for c in children} == {0.5, -0.5}
    random.seed(1)
    on.crossover(off)
    after = random.getstate()
    random.seed(1)
    for _ in range(2 if genetics == "0.92" else 3):
        random.random()
    assert random.getstate() == after


@pytest.mark.parametrize("genetics", GENETICS)
def test_crossover_aligns_connections(genetics):
    """0.92 lines connections up by key (in the fitter parent's order), 2.0 by innovation number:
    the same connection added twice (two innovation numbers) is homologous in 0.92 only. Genes
    of the less fit parent alone are never inherited."""
    gc = _genome_config(genetics)
    genome_type = build_neat_config(41, 10, genetics=genetics).genome_type

    def parent(key, fitness, genes):
        genome = genome_type(key)
        genome.nodes[0] = genome.create_node(gc, 0)
        for source, innovation, weight in genes:
            genome.add_connection(gc, source, 0, weight, True, innovation=innovation)
        genome.fitness = fitness
        return genome

    fitter = parent(1, 2.0, [(-2, 2, 0.25), (-1, 1, 1.0)])
    weaker = parent(2, 1.0, [(-1, 7, -1.0), (-3, 3, 3.0)])
    weights = set()
    for seed in range(40):
        random.seed(seed)
        child = genome_type(3)
        child.configure_crossover(weaker, fitter, gc)
        assert sorted(child.connections) == [(-2, 0), (-1, 0)]
        if genetics == "0.92":
            assert list(child.connections) == [(-2, 0), (-1, 0)]
        weights.add(child.connections[(-1, 0)].weight)
    assert weights == ({1.0, -1.0} if genetics == "0.92" else {1.0})


@pytest.mark.parametrize("genetics", GENETICS)
def test_add_node_bias(genetics):
    """2.0 gives the node that splits a connection bias 0; 0.92 draws it like any new node's."""
    for seed in range(20):
        genome, gc = _fresh_genome(genetics)
        random.seed(seed)
        genome.mutate_add_node(gc)
        (node,) = set(genome.nodes) - {0, 1, 2, 3}
        random.seed(seed)
        random.choice(range(len(genome.connections) - 2))  # the connection to split
        drawn = max(-5.0, min(5.0, random.gauss(0.0, 1.0)))
        assert genome.nodes[node].bias == (drawn if genetics == "0.92" else 0.0)


@pytest.mark.parametrize("genetics", GENETICS)
def test_add_connection_sources(genetics):
    """0.92 lets an output feed a hidden node (never another output, never closing a cycle);
    2.0 never starts a connection at an output."""
    from_outputs = 0
    for seed in range(30):
        genome, gc = _fresh_genome(genetics)
        random.seed(seed)
        for _ in range(100):
            if random.random() < 0.2:
                genome.mutate_add_node(gc)
            else:
                genome.mutate_add_connection(gc)
        keys = list(genome.connections)
        for i, (source, target) in enumerate(keys):
            assert not (source in gc.output_keys and target in gc.output_keys)
            assert not creates_cycle(keys[:i] + keys[i + 1:], (source, target))
        from_outputs += sum(source in gc.output_keys for source, _target in keys)
    assert (from_outputs > 10) if genetics == "0.92" else from_outputs == 0


def test_node_genes_have_no_time_constant():
    """0.92's node genes: bias, response, activation, aggregation; no draws for a time constant,
    and the distance of 0.92 (2.0's, whose time constant never changes, gives the same)."""
    old, new = _fresh_genome("0.92")[1], _fresh_genome("2.0")[1]
    assert [a.name for a in old.node_gene_type._gene_attributes] == ["bias", "response", "activation",
                                                                     "aggregation"]
    assert not hasattr(old, "time_constant_init_mean") and hasattr(new, "time_constant_init_mean")
    random.seed(5)
    a, b = old.node_gene_type(4), old.node_gene_type(4)
    a.init_attributes(old)
    b.init_attributes(old)
    b.activation = "sigmoid"
    twin_a, twin_b = new.node_gene_type(4), new.node_gene_type(4)
    twin_a.init_attributes(new)
    twin_b.init_attributes(new)
    for twin, gene in ((twin_a, a), (twin_b, b)):
        for name in ("bias", "response", "activation", "aggregation"):
            setattr(twin, name, getattr(gene, name))
    assert a.distance(b, old) == twin_a.distance(twin_b, new) == pytest.approx(0.6 * (abs(a.bias - b.bias) + 1))


@pytest.mark.parametrize("genetics", GENETICS)
def test_population_size(genetics):
    """2.0 keeps exactly ``pop_size`` genomes; 0.92's spawn counts let it drift by a few."""
    _snapshots, opt = _our_run(6, 40, 1, genetics)
    sizes = []
    for _ in range(25):
        opt.ask()
        sizes.append(opt.population_size)
        assert opt.ask().population_size == len(opt.population) == sizes[-1]
        scores = torch.tensor([fitness(g) for g in opt.asked_genomes], dtype=torch.float64)
        opt.tell(scores, scores)
    if genetics == "2.0":
        assert set(sizes) == {40}
    else:
        assert set(sizes) != {40} and all(abs(s - 40) <= 5 for s in sizes)
