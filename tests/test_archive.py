"""The skill archive (``--archive``): each task's top controller kept at its end and put back
(``Optimizer.adopt``) when the task returns: NEAT in place of its newest offspring (never evaluated),
under 2.0's genetics with the population's innovation numbers; an ES as its centre;
the right task's controller, the population's size kept, resumed bit for bit, scored held out."""
from __future__ import annotations

import copy
import json
import shutil
import warnings
from collections import defaultdict

import pytest
import torch

from algorithms import REGISTRY, make_optimizer
from algorithms.base import Optimizer
from algorithms.neat import NeatOptimizer
from algorithms.neat.genetics import GENETICS
from lifelong_evo.commands.cli import main

OBS_DIM = 31
COMMON = ["--preset", "smoke", "--env", "duration=60", "--no-record", "--quiet"]


def _evolved(algo: str, generations: int = 3, seed: int = 1, **options):
    """An optimiser (with ``options``) told ``generations`` generations of random fitness, and its
    best controller of the first."""
    optimizer = make_optimizer(algo, obs_dim=OBS_DIM, population_size=20, seed=seed, **options)
    draws = torch.Generator().manual_seed(seed)
    best = None
    for _ in range(generations):
        optimizer.ask()
        fitness = torch.rand(optimizer.population_size, generator=draws)
        best = best or optimizer.export(int(fitness.argmax()))
        optimizer.tell(fitness, fitness)
    return optimizer, best


def _without_innovation(genome: dict) -> dict:
    """An exported genome's genes without their innovation numbers (2.0's adopt renumbers them)."""
    return {"nodes": genome["nodes"],
            "connections": [{k: v for k, v in c.items() if k != "innovation"} for c in genome["connections"]]}


@pytest.mark.parametrize("genetics", GENETICS)
def test_neat_adopt_replaces_the_newest_offspring_and_keeps_the_size(genetics):
    """The adopted genome takes the place of the newest offspring (never evaluated, so the lowest
    fitness; the elites keep theirs), under a new key, in a species; the next ask plays it, every
    gene as exported (under 0.92 its innovation numbers too; 2.0's are the population's) and, under
    2.0, with the time constant every node of the population has."""
    optimizer, best = _evolved("neat", genetics=genetics)
    before = dict(optimizer.population)
    unevaluated = [key for key, genome in before.items() if genome.fitness is None]
    assert unevaluated and len(unevaluated) < len(before)  # offspring and elites
    optimizer.adopt(best)
    assert optimizer.population_size == len(before)
    (added,) = set(optimizer.population) - set(before)
    assert set(before) - set(optimizer.population) == {max(unevaluated)}
    assert added > max(before) and optimizer.reproduction.ancestors[added] == ()
    assert set(optimizer.species.genome_to_species) == set(optimizer.population)
    assert {k for s in optimizer.species.species.values() for k in s.members} == set(optimizer.population)
    if genetics == "2.0":
        assert {n.time_constant for g in optimizer.population.values() for n in g.nodes.values()} == {1.0}
    optimizer.ask()
    played = optimizer.export([g.key for g in optimizer.asked_genomes].index(added))["genome"]
    assert _without_innovation(played) == _without_innovation(best["genome"])
    if genetics == "0.92":
        assert played == best["genome"]


def test_neat_adopt_keeps_the_innovation_bookkeeping_valid():
    """Under 0.92 (innovation numbers are labels, kept), a genome whose node keys and innovation
    numbers lie beyond a population's counters (a from-scratch population's) moves them on, so
    that evolution never reuses them."""
    optimizer, best = _evolved("neat", generations=1, seed=2)
    genome = best["genome"]
    link = genome["connections"][0]
    hidden = {**genome["nodes"][0], "key": 1000}
    grown = {**best, "genome": {"nodes": [*genome["nodes"], hidden], "connections": [
        *genome["connections"], {**link, "out": 1000, "innovation": 5000},
        {**link, "in": 1000, "innovation": 5001}]}}
    optimizer.adopt(grown)
    assert optimizer.config.genome_config.get_new_node_key({}) > 1000
    assert optimizer.reproduction.innovation_tracker.get_innovation_number(-1, 999) > 5001
    draws = torch.Generator().manual_seed(0)
    for _ in range(3):  # evolution goes on
        optimizer.ask()
        fitness = torch.rand(optimizer.population_size, generator=draws)
        optimizer.tell(fitness, fitness)


def _named(population, by: str) -> dict:
    """Over ``population``'s connection genes: each key with the innovation numbers it carries
    (``by="key"``), or each number with the keys that carry it (``by="innovation"``)."""
    named = defaultdict(set)
    for genome in population.values():
        for key, gene in genome.connections.items():
            if by == "key":
                named[key].add(gene.innovation)
            else:
                named[gene.innovation].add(key)
    return named


def test_neat_adopt_into_a_fresh_population_takes_its_innovation_numbers():
    """--archive with --from-scratch under 2.0: the archived genome's innovation numbers are its old
    population's tracker's, which in a fresh population (a new tracker, numbering in first-seen
    order) name other keys. Adopted, each connection carries the number the fresh population gives
    its key, a key it lacks a new number from its tracker, so that every number names one key and
    crossover pairs homologous genes only."""
    _, best = _evolved("neat", seed=1, genetics="2.0")
    fresh = make_optimizer("neat", obs_dim=OBS_DIM, population_size=20, seed=2, genetics="2.0")
    numbers = _named(fresh.population, by="key")
    assert all(len(carried) == 1 for carried in numbers.values())  # a fresh population numbers each key once
    exported = {(c["in"], c["out"]): c["innovation"] for c in best["genome"]["connections"]}
    assert any(numbers[key] != {number} for key, number in exported.items() if key in numbers)
    assert any(key not in numbers for key in exported)
    counter = fresh.reproduction.innovation_tracker.global_counter
    fresh.adopt(best)
    adopted = fresh.population[max(fresh.population)]
    assert set(adopted.connections) == set(exported)
    for key, gene in adopted.connections.items():
        if key in numbers:
            assert {gene.innovation} == numbers[key], key
    new = sorted(gene.innovation for key, gene in adopted.connections.items() if key not in numbers)
    assert new == list(range(counter + 1, counter + 1 + len(new)))
    draws = torch.Generator().manual_seed(0)
    with warnings.catch_warnings():
        # neat-python's crossover warns where two parents' genes share a number but not a key
        warnings.filterwarnings("error", "Innovation number collision", RuntimeWarning)
        for generation in range(3):  # evolution goes on, the adopted genome the fittest parent at first
            assert all(len(keys) == 1 for keys in _named(fresh.population, by="innovation").values())
            fresh.ask()
            fitness = torch.rand(fresh.population_size, generator=draws)
            if generation == 0:
                fitness[fresh.asked_genomes.index(adopted)] = 2.0
            fresh.tell(fitness, fitness)


def test_neat_adopt_takes_the_number_most_genomes_carry():
    """Under 2.0 a key that the population's genomes carry under several numbers (2.0 numbers a key
    again when a later generation adds it again) takes the number most of them carry, the oldest
    (lowest) among equally many."""
    optimizer, best = _evolved("neat", genetics="2.0")
    victim = max(k for k, g in optimizer.population.items() if g.fitness is None)  # adopt replaces it
    carriers = defaultdict(list)
    for genome_key, genome in sorted(optimizer.population.items()):
        if genome_key != victim:
            for key, gene in genome.connections.items():
                carriers[key].append(gene)
    exported = [(c["in"], c["out"]) for c in best["genome"]["connections"]]
    majority, tie = [key for key in exported if len(carriers[key]) >= 3][:2]
    fresh = optimizer.reproduction.innovation_tracker.global_counter + 1
    for gene in carriers[majority][1:]:  # a newer number on all but one: it is the most common
        gene.innovation = fresh
    half = len(carriers[tie]) // 2
    oldest = carriers[tie][0].innovation
    for i, gene in enumerate(carriers[tie]):  # as many carry the oldest number as a newer one
        gene.innovation = oldest if i < half else fresh + 1 if i < 2 * half else fresh + 2
    optimizer.adopt(best)
    adopted = optimizer.population[max(optimizer.population)]
    assert adopted.connections[majority].innovation == fresh
    assert adopted.connections[tie].innovation == oldest


def _assert_identical(state, expected, where: str = "state") -> None:
    """``state`` holds exactly ``expected``: the same keys and items, every tensor element for
    element with its dtype (a ``repr`` abbreviates a tensor of over 1000 elements with "...")."""
    if isinstance(expected, torch.Tensor):
        assert isinstance(state, torch.Tensor) and state.dtype == expected.dtype and torch.equal(state, expected), where
    elif isinstance(expected, dict):
        assert isinstance(state, dict) and state.keys() == expected.keys(), where
        for key in expected:
            _assert_identical(state[key], expected[key], f"{where}[{key!r}]")
    elif isinstance(expected, (list, tuple)):
        assert type(state) is type(expected) and len(state) == len(expected), where
        for i, (item, expected_item) in enumerate(zip(state, expected)):
            _assert_identical(item, expected_item, f"{where}[{i}]")
    else:
        assert state == expected, where


@pytest.mark.parametrize("algo", ["sep-cmaes", "cmaes", "openai-es", "pgpe", "snes"])
def test_es_adopt_moves_the_centre_and_keeps_the_spread(algo):
    optimizer, best = _evolved(algo)
    size = optimizer.population_size
    # a copy: the centre optimiser's state holds the live tensors, which adopt could change in place
    spread = copy.deepcopy({k: v for k, v in optimizer._searcher_state().items() if k not in ("m", "mu")})
    optimizer.adopt(best)
    assert optimizer.centre.tolist() == best["parameters"]
    after = {k: v for k, v in optimizer._searcher_state().items() if k not in ("m", "mu")}
    _assert_identical(after, spread, "spread")
    optimizer.ask()
    assert optimizer.population_size == size
    assert optimizer.export(optimizer.centre_index)["parameters"] == best["parameters"]


def test_adopt_goes_between_tell_and_ask():
    for algo in ("neat", "sep-cmaes"):
        optimizer, best = _evolved(algo)
        optimizer.ask()
        with pytest.raises(RuntimeError, match="between tell"):
            optimizer.adopt(best)


@pytest.fixture(scope="module")
def adopted(tmp_path_factory):
    """Per algorithm, a run with --archive on red, green, red, red, green, red (one generation each)
    and every adopt the loop made: the controller, and the population's size before and after."""
    out = tmp_path_factory.mktemp("archive")
    calls: dict[str, list] = {}
    with pytest.MonkeyPatch.context() as patch:
        for algo in ("neat", "sep-cmaes"):
            cls = REGISTRY[algo]
            original = cls.adopt

            def spy(self, exported, original=original, algo=algo):
                size = self.population_size
                original(self, exported)
                self.ask()
                played = [self.export(i) for i in range(self.population_size)]
                calls.setdefault(algo, []).append((self.generation, exported, size, self.population_size, played))

            patch.setattr(cls, "adopt", spy)
            assert main(["--algo", algo, *COMMON, "--schedule", "red:1,green:1,red:1,red:1,green:1,red:1", "--archive",
                         "--out", str(out), "--name", algo]) == 0
    return out, calls


@pytest.mark.parametrize("algo", ["neat", "sep-cmaes"])
def test_a_returning_task_gets_its_own_archived_controller(adopted, algo):
    """At the start of each phase whose task returns after another, the loop puts back that task's
    top controller of its latest end (not another task's, not an older one; nothing where a task
    goes on), the population keeps its size, and the population played holds the controller."""
    out, calls = adopted
    stored = {name: json.loads((out / algo / "controllers" / f"{name}.json").read_text())
              for name in ("task0-red-top", "task1-green-top", "task3-red-top")}
    assert [(generation, exported) for generation, exported, *_ in calls[algo]] == \
        [(2, stored["task0-red-top"]), (4, stored["task1-green-top"]), (5, stored["task3-red-top"])]
    for _, exported, before, after, played in calls[algo]:
        assert before == after
        if algo == "neat":
            assert any(e["genome"] == exported["genome"] for e in played)
        else:
            assert played[-1]["parameters"] == exported["parameters"]  # the centre


def test_a_blend_into_a_returning_task_is_its_returning_phase(tmp_path, monkeypatch):
    """green>red after green: red counts from the blend's first generation, so its archived
    controller goes back there (where the fitness is still mostly green's), and the red phase the
    blend goes on into gets nothing."""
    adopted = []
    original = NeatOptimizer.adopt

    def spy(self, exported):
        adopted.append((self.generation, exported))
        original(self, exported)

    monkeypatch.setattr(NeatOptimizer, "adopt", spy)
    assert main(["--algo", "neat", *COMMON, "--schedule", "red:1,green:1,green>red:2,red:1", "--archive",
                 "--out", str(tmp_path), "--name", "blend"]) == 0
    red = json.loads((tmp_path / "blend/controllers/task0-red-top.json").read_text())
    assert adopted == [(2, red)]


def test_the_held_out_block_scores_the_archive(adopted):
    """summary.json's held-out block: each task's archived controller (its top one at its latest
    end) with its held-out score on that task, and their mean."""
    out, _ = adopted
    held_out = json.loads((out / "neat/summary.json").read_text())["held_out"]
    assert held_out["archive"] == {
        "red": {"controller": "task5-red-top", "score": held_out["scores"]["task5-red-top"]["red"]},
        "green": {"controller": "task4-green-top", "score": held_out["scores"]["task4-green-top"]["green"]}}
    assert held_out["archive_mean"] == (held_out["archive"]["red"]["score"] + held_out["archive"]["green"]["score"]) / 2


def test_without_archive_nothing_is_adopted_nor_scored(tmp_path, monkeypatch):
    def refuse(self, exported):
        raise AssertionError("adopted without --archive")

    monkeypatch.setattr(NeatOptimizer, "adopt", refuse)
    assert main(["--algo", "neat", *COMMON, "--schedule", "red:1,green:1,red:1", "--out", str(tmp_path),
                 "--name", "off"]) == 0
    held_out = json.loads((tmp_path / "off/summary.json").read_text())["held_out"]
    assert "archive" not in held_out and "archive_mean" not in held_out


@pytest.mark.parametrize("algo", ["neat", "sep-cmaes"])
def test_resume_keeps_the_archive(tmp_path, algo):
    """Resumed from the checkpoint at green's end, before red returns, a run puts back the archived
    red controller the checkpoint holds, and repeats the uninterrupted run byte for byte."""
    flags = ["--algo", algo, *COMMON, "--schedule", "red:2,green:2,red:2", "--archive", "--checkpoint-every", "2",
             "--out", str(tmp_path)]
    assert main([*flags, "--name", "whole"]) == 0
    shutil.copytree(tmp_path / "whole", tmp_path / "resumed")
    (tmp_path / "resumed/checkpoints/generation-000006.pt").unlink()
    assert main([*flags, "--name", "resumed", "--resume"]) == 0
    for name in ("metrics.csv", "controllers/task2-red-top.json", *(["species.csv"] if algo == "neat" else [])):
        assert (tmp_path / "resumed" / name).read_bytes() == (tmp_path / "whole" / name).read_bytes(), name
    held_out = [json.loads((tmp_path / run / "summary.json").read_text())["held_out"] for run in ("whole", "resumed")]
    assert held_out[0] == held_out[1]


def test_archive_needs_an_optimizer_that_can_adopt(tmp_path, monkeypatch, capsys):
    class NoAdopt(NeatOptimizer):
        name = "no-adopt"
        adopt = Optimizer.adopt

    monkeypatch.setitem(REGISTRY, "no-adopt", NoAdopt)
    assert main(["--algo", "no-adopt", *COMMON, "--archive", "--out", str(tmp_path)]) == 2
    assert capsys.readouterr().err == ("error: --archive: algorithm 'no-adopt' cannot take a controller back (it has "
                                       "no Optimizer.adopt): drop --archive\n")
    assert not list(tmp_path.iterdir())
