"""Batched genetic distances and the speciation on them (``algorithms.neat.speciation``): equal
bit for bit to neat-python's own distances, species and runs."""
from __future__ import annotations

import json
import random

import neat
import pytest
import torch

from algorithms.neat import NeatOptimizer
from algorithms.neat import genetics as neat_genetics
from algorithms.neat import speciation as neat_speciation
from algorithms.neat.genetics import GENETICS
from algorithms.neat.speciation import DistanceCache, GenomeTable

try:
    from neat092_reference import fitness, snapshot
except ImportError:  # tests/ imported as a package
    from tests.neat092_reference import fitness, snapshot


@pytest.fixture(autouse=True)
def _keep_global_random():
    state = random.getstate()
    yield
    random.setstate(state)


def _run(genetics: str, seed: int = 3, population: int = 120, generations: int = 30):
    """Snapshots (``neat092_reference.snapshot``) of every evaluated generation of a run with a
    deterministic fitness, a few genomes of every generation, and the optimiser."""
    opt = NeatOptimizer(obs_dim=41, population_size=population, seed=seed, genetics=genetics)
    snapshots, earlier = [], []
    for _ in range(generations):
        opt.ask()
        snapshots.append(json.loads(json.dumps(snapshot(opt.population, opt.species))))
        earlier += opt.asked_genomes[:6]
        scores = torch.tensor([fitness(g) for g in opt.asked_genomes], dtype=torch.float64)
        opt.tell(scores, scores)
    return snapshots, earlier, opt


@pytest.fixture(scope="module", params=GENETICS)
def evolved(request):
    return request.param, _run(request.param)


@pytest.mark.parametrize("batched", ["all selves at once", "one self at a time"])
def test_distances_are_neat_pythons_bit_for_bit(evolved, batched, monkeypatch):
    """Every pair, in both directions (which differ in the last bit for many pairs): equal to
    ``a.distance(b)``, not merely close. Summing the genes' distances in any other order than
    neat-python's breaks this on thousands of these pairs."""
    genetics, (_snapshots, earlier, opt) = evolved
    config = opt.config.genome_config
    population = list(opt.population.values())
    # the rarer terms: no connections at all, another activation, another aggregation
    bare, relabelled = (opt.config.genome_type(key) for key in (10**6, 10**6 + 1))
    for genome in (bare, relabelled):
        genome.configure_new(config)
    bare.connections.clear()
    some_node = next(iter(relabelled.nodes.values()))
    some_node.activation, some_node.aggregation = "sigmoid", "product"
    others = population + [bare, relabelled]
    selves = earlier + [bare, relabelled]

    if batched == "one self at a time":
        monkeypatch.setattr(neat_speciation, "PAIR_GENES_AT_ONCE", 1)
    got = GenomeTable(selves + others, config).distances(selves, others).tolist()
    expected = [[a.distance(b, config) for b in others] for a in selves]
    mismatches = [(i, j) for i, row in enumerate(expected) for j, d in enumerate(row) if got[i][j] != d]
    assert not mismatches, f"{len(mismatches)} pairs differ, e.g. {mismatches[:3]}"
    asymmetric = sum(a.distance(b, config) != b.distance(a, config) for a in earlier for b in population)
    assert asymmetric > 0, "no pair whose two directions differ: the test cannot see a swapped direction"


def test_cache_keeps_the_first_direction_asked():
    """As neat-python's ``GenomeDistanceCache``: once ``a.distance(b)`` is asked, ``(b, a)``
    answers with it, even where ``b.distance(a)`` would differ in the last bit."""
    _snapshots, earlier, opt = _run("2.0", generations=10)
    config = opt.config.genome_config
    population = list(opt.population.values())
    a, b = next((a, b) for a in earlier for b in population if a.distance(b, config) != b.distance(a, config))
    for prepared in (False, True):
        cache = DistanceCache(config, [a, b])
        if prepared:
            cache.prepare([a, b], [a, b])
        assert cache(a, b) == a.distance(b, config)
        assert cache(b, a) == a.distance(b, config) != b.distance(a, config)


@pytest.mark.parametrize("genetics", GENETICS)
def test_runs_are_unchanged_by_batching(genetics, monkeypatch):
    """Thirty generations, every gene of every genome and every species in every generation:
    the same with batched distances as with neat-python computing each distance itself (and,
    under 2.0, as with neat-python's own ``DefaultSpeciesSet``)."""
    batched, _earlier, opt = _run(genetics)
    first = {sid for sid, _rep, _members in batched[0]["species"]}
    later = {sid for s in batched[1:] for sid, _rep, _members in s["species"]} - first
    assert max(len(s["species"]) for s in batched) >= 4 and len(later) >= 3, "too little speciation to test"
    monkeypatch.setattr(DistanceCache, "prepare", lambda self, selves, others: None)
    assert _run(genetics)[0] == batched
    if genetics == "2.0":
        monkeypatch.setattr(neat_genetics, "SpeciesSet", neat.DefaultSpeciesSet)
        unbatched, _earlier, opt = _run(genetics)
        assert type(opt.species) is neat.DefaultSpeciesSet
        assert unbatched == batched


def test_a_genome_with_a_distance_of_its_own_keeps_it():
    """Batching knows neat-python's distance only: another one is computed pair by pair."""

    class Custom(neat.DefaultGenome):
        def distance(self, other, config):
            return 1.5

    opt = NeatOptimizer(obs_dim=41, population_size=20, seed=1, genetics="2.0")
    config = opt.config.genome_config
    a, b = Custom(1), Custom(2)
    for genome in (a, b):
        genome.configure_new(config)
    with pytest.raises(TypeError, match="not neat-python's"):
        GenomeTable([a, b], config)
    cache = DistanceCache(config, [a, b])
    cache.prepare([a], [b])
    assert cache(a, b) == 1.5
