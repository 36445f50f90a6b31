"""The two genetics a NEAT run can use, and the one place that chooses between them.

``genetics_version(genetics)`` answers everything that depends on the choice: the genome,
reproduction, species-set and stagnation classes a ``neat.Config`` takes (``config.py`` builds it
with them) and the smallest population each evolves (``GeneticsVersion.minimum_population``).
Every other module asks it, and none compares the genetics' name itself.

``"2.0"`` is neat-python 2.0's own genetics, with its spawn-count adjustment fixed
(``Reproduction``) and speciation distances computed in batches (``speciation.SpeciesSet``).

``"0.92"`` (the default) is neat-python 0.92's, which the paper ran: the ``Neat092*`` classes here
are built on neat-python 2.0's extension points and behave as 0.92's do, down to the order of
every draw from ``random``: from the same seed and the same fitness they evolve the populations
neat-python 0.92 evolves, gene for gene (``tests/test_neat_genetics.py`` runs 0.92 itself next
to them).

Where neat-python 0.92 differs from 2.0, reproduced here:

Genes
    Node genes have bias, response, activation and aggregation only: 2.0's ``time_constant`` (a
    CTRNN parameter) draws one more random number whenever a node is created, crossed over or
    mutated. Connection crossover takes each attribute, ``enabled`` included, from either parent
    with probability 1/2; 2.0 then disables the child's connection with probability 0.75 when
    either parent's is disabled (one more draw).
Genome
    Crossover aligns connection genes by key (input node, output node), in the fitter parent's
    gene order, and the child inherits the fitter parent's genes only; 2.0 aligns them by
    innovation number, visits them in set order and drops a gene that would close a cycle. A node
    added by splitting a connection draws its bias like any new node; 2.0 sets it to 0. A new
    connection's source is drawn from the genome's nodes, outputs included, then the inputs, in
    that order; 2.0 draws it from the hidden nodes and inputs (in set order), so under 0.92 an
    output can feed a hidden node (never another output, and never closing a cycle).
Reproduction
    The species' spawn counts are not adjusted to add up to the population size, so the
    population drifts by a few genomes around ``pop_size``; 2.0 forces the exact size. A
    species' members are ranked by fitness alone, ties keeping the species' member order (a
    stable sort); 2.0 ranks ties by genome key, highest first.
Stagnation
    Species are visited in the species set's order, which survives the stable sort by fitness
    among equal fitnesses and so decides the order in which species reproduce; 2.0 visits them
    by id.
Speciation
    The genomes to place are a Python ``set`` of their keys, built from an iterator and visited
    (and ``pop``-ed) in the order the interpreter gives it; species are visited in the species
    set's order; among equal distances the first candidate in that order wins. 2.0 visits both
    in ascending key order. (Both compute their distances in batches: ``speciation``.)

Shared by both versions and inherited unchanged: attribute initialisation and mutation (including
the draws a zero rate still makes), the order of mutations, node and connection deletion,
initial connections (``partial_direct``), the genome distance (0.92's node distance has no
time-constant term, which is exactly 0 in 2.0, where the time constant never changes), the spawn
formula (``spawn_counts``), elitism, the survival threshold, complete-extinction handling, and
the configuration file (every option is given, so neither version's defaults matter).

Innovation numbers: 0.92 has none. These genomes still carry the numbers 2.0's tracker assigns
(a child's connection takes the fitter parent's), which label genes in exports and checkpoints;
nothing here reads them, and assigning them draws no random number.
"""
from __future__ import annotations

import math
import random
import sys
from dataclasses import dataclass
from typing import Literal, get_args

import neat
from neat.genes import DefaultConnectionGene, DefaultNodeGene
from neat.genome import DefaultGenomeConfig
from neat.graphs import creates_cycle
from envs import numerics

from .speciation import SpeciesSet

Genetics = Literal["0.92", "2.0"]
GENETICS: tuple[str, ...] = get_args(Genetics)
"""The genetics a NEAT run can use: neat-python 0.92's (the paper's) or 2.0's."""
DEFAULT_GENETICS = "0.92"


def check_genetics(value) -> str:
    """``value`` if it is one of ``GENETICS`` (version names, as strings), else ValueError."""
    if value not in GENETICS:
        raise ValueError(f"genetics must be one of {', '.join(repr(g) for g in GENETICS)}, got {value!r}")
    return value


@dataclass(frozen=True)
class GeneticsVersion:
    """What a run's genetics decides: its classes, how its reproduction sizes species and how its
    crossover lines genes up."""

    genome: type
    reproduction: type
    species_set: type
    stagnation: type
    exact_population_size: bool
    """Reproduction makes every generation exactly ``pop_size`` (2.0), giving each species at
    least max(``elitism``, ``min_species_size``) genomes, or lets the population drift by a few
    genomes (0.92), each species keeping its ``elitism`` best."""
    crossover_by_innovation: bool
    """Crossover lines connection genes up by innovation number (2.0), so a genome brought in
    from elsewhere must carry the numbers this population gives its connections; or by key (0.92),
    which reads no innovation number."""

    @property
    def components(self) -> tuple[type, type, type, type]:
        """The genome, reproduction, species-set and stagnation classes, in ``neat.Config``'s order."""
        return self.genome, self.reproduction, self.species_set, self.stagnation

    def minimum_population(self, elitism: int, min_species_size: int) -> tuple[int, str]:
        """The smallest population evolved at the size asked, and why, in words. 0.92 grows a
        smaller population to ``elitism`` genomes; 2.0 stops with an error ("Configuration
        conflict") where two species do not fit."""
        if self.exact_population_size:
            per_species = max(elitism, min_species_size)
            return 2 * per_species, f"room for two species of {per_species} genomes"
        return elitism, f"every species keeps its {elitism} best genomes"


def genetics_version(genetics: str) -> GeneticsVersion:
    """The classes and rules of ``genetics`` (one of ``GENETICS``; ValueError for another value)."""
    if check_genetics(genetics) == "0.92":
        return GeneticsVersion(Neat092Genome, Neat092Reproduction, Neat092SpeciesSet, Neat092Stagnation,
                               exact_population_size=False, crossover_by_innovation=False)
    return GeneticsVersion(neat.DefaultGenome, Reproduction, SpeciesSet, neat.DefaultStagnation,
                           exact_population_size=True, crossover_by_innovation=True)


def spawn_counts(adjusted_fitness: list[float], previous_sizes: list[int], pop_size: int,
                 min_species_size: int) -> list[int]:
    """neat-python's ``compute_spawn`` rule (0.92's and 2.0's): each species moves half way from
    its previous size towards its share of ``pop_size`` by adjusted fitness (at least one genome
    when it moves at all, and at least ``min_species_size``), then the counts are scaled to
    ``pop_size`` and rounded. neat-python adds the fitnesses with Python's ``sum``, whose float
    result differs between Python 3.11 and 3.12 (``numerics.ordered_sum``); here they are added
    left to right, as 3.11 does."""
    fitness_total = numerics.ordered_sum(adjusted_fitness)
    counts = []
    for fitness, size in zip(adjusted_fitness, previous_sizes):
        share = max(min_species_size, fitness / fitness_total * pop_size) if fitness_total > 0 \
            else min_species_size
        half_way = (share - size) * 0.5
        step = int(round(half_way))
        if step == 0 and half_way != 0:
            step = 1 if half_way > 0 else -1
        counts.append(size + step)
    scale = pop_size / sum(counts)  # integers: exact on every Python
    return [max(min_species_size, int(round(count * scale))) for count in counts]


# --------------------------------------------------------------------------------------------
# neat-python 2.0's genetics: its own classes, with one fix


class Reproduction(neat.DefaultReproduction):
    """neat-python 2.0.0's ``DefaultReproduction`` with one bug fixed: ``_adjust_spawn_exact``,
    when the species' spawn counts add up to more than the population, takes one genome off each
    species above the minimum size in one pass and then gives up. One large species next to one
    at the minimum is enough for it to raise "Internal error adjusting spawn counts" in the
    middle of a run (docs/algorithms.md, pitfalls). Here the passes go
    on until the counts fit; wherever neat-python's own succeeds, the counts are the same. The
    spawn rule is ``spawn_counts``; the species' mean fitnesses before it are neat-python's own
    (Python's ``sum``), so this genetics can evolve otherwise on Python 3.12 than on 3.11."""

    compute_spawn = staticmethod(spawn_counts)

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


# --------------------------------------------------------------------------------------------
# neat-python 0.92's genetics on 2.0's classes (module docstring)


class Neat092NodeGene(DefaultNodeGene):
    """A node gene without 2.0's ``time_constant``."""

    _gene_attributes = [a for a in DefaultNodeGene._gene_attributes if a.name != "time_constant"]
    distance_terms = ("bias", "response")
    """The attributes whose absolute differences ``distance`` adds, in order (``speciation``)."""

    def distance(self, other, config):
        d = abs(self.bias - other.bias) + abs(self.response - other.response)
        if self.activation != other.activation:
            d += 1.0
        if self.aggregation != other.aggregation:
            d += 1.0
        return d * config.compatibility_weight_coefficient


class Neat092ConnectionGene(DefaultConnectionGene):
    """A connection gene crossed over attribute by attribute, without the 75% disable rule."""

    def crossover(self, gene2):
        child = self.__class__(self.key, innovation=self.innovation)
        for attribute in self._gene_attributes:
            parent = self if random.random() > 0.5 else gene2
            setattr(child, attribute.name, getattr(parent, attribute.name))
        return child


class Neat092Genome(neat.DefaultGenome):
    """neat-python 0.92's crossover, add-node and add-connection; see the module docstring."""

    @classmethod
    def parse_config(cls, param_dict):
        param_dict["node_gene_type"] = Neat092NodeGene
        param_dict["connection_gene_type"] = Neat092ConnectionGene
        return DefaultGenomeConfig(param_dict, cls.__name__)

    def configure_crossover(self, genome1, genome2, config):
        fitter, other = (genome1, genome2) if genome1.fitness > genome2.fitness else (genome2, genome1)
        for genes, fitter_genes, other_genes in ((self.connections, fitter.connections, other.connections),
                                                 (self.nodes, fitter.nodes, other.nodes)):
            for key, gene in fitter_genes.items():
                homologue = other_genes.get(key)
                genes[key] = gene.copy() if homologue is None else gene.crossover(homologue)

    def mutate_add_node(self, config):
        if not self.connections:
            if config.check_structural_mutation_surer():
                self.mutate_add_connection(config)
            return
        split = random.choice(list(self.connections.values()))
        node = config.get_new_node_key(self.nodes)
        self.nodes[node] = self.create_node(config, node)  # its drawn bias is kept (2.0 zeroes it)
        split.enabled = False
        source, target = split.key
        tracker = config.innovation_tracker
        self.add_connection(config, source, node, 1.0, True,
                            innovation=tracker.get_innovation_number(source, node, "add_node_in"))
        self.add_connection(config, node, target, split.weight, True,
                            innovation=tracker.get_innovation_number(node, target, "add_node_out"))

    def mutate_add_connection(self, config):
        nodes = list(self.nodes)
        target = random.choice(nodes)
        source = random.choice(nodes + config.input_keys)  # outputs included, in this order
        key = (source, target)
        if key in self.connections:
            if config.check_structural_mutation_surer():
                self.connections[key].enabled = True
            return
        if source in config.output_keys and target in config.output_keys:
            return
        if config.feed_forward and creates_cycle(list(self.connections), key):
            return
        innovation = config.innovation_tracker.get_innovation_number(source, target, "add_connection")
        self.connections[key] = self.create_connection(config, source, target, innovation)


class Neat092Stagnation(neat.DefaultStagnation):
    """Stagnation visiting species in the species set's order."""

    def update(self, species_set, generation):
        config = self.stagnation_config
        ranked = []
        for sid, species in species_set.species.items():  # in the set's order, not by id
            previous_best = max(species.fitness_history, default=-sys.float_info.max)
            species.fitness = self.species_fitness_func(species.get_fitnesses())
            species.fitness_history.append(species.fitness)
            species.adjusted_fitness = None
            if species.fitness > previous_best:
                species.last_improved = generation
            ranked.append((sid, species))
        ranked.sort(key=lambda item: item[1].fitness)
        result = []
        not_stagnant = len(ranked)
        for index, (sid, species) in enumerate(ranked):
            spared = len(ranked) - index <= config.species_elitism
            stagnant = (not spared and not_stagnant > config.species_elitism
                        and generation - species.last_improved >= config.max_stagnation)
            not_stagnant -= stagnant
            result.append((sid, species, stagnant))
        return result


class Neat092Reproduction(neat.DefaultReproduction):
    """Reproduction without the exact population size and with a stable ranking of members."""

    compute_spawn = staticmethod(spawn_counts)

    def reproduce(self, config, species, pop_size, generation):
        # innovation numbers as 2.0 assigns them (see the module docstring)
        config.genome_config.innovation_tracker = self.innovation_tracker
        self.innovation_tracker.reset_generation()

        remaining = []
        for sid, s, stagnant in self.stagnation.update(species, generation):
            if stagnant:
                self.reporters.species_stagnant(sid, s)
            else:
                remaining.append(s)
        if not remaining:
            species.species = {}
            return {}

        fitnesses = [m.fitness for s in remaining for m in s.members.values()]
        lowest = min(fitnesses)
        fitness_range = max(1.0, max(fitnesses) - lowest)
        for s in remaining:
            mean_fitness = numerics.ordered_mean(m.fitness for m in s.members.values())
            s.adjusted_fitness = (mean_fitness - lowest) / fitness_range

        settings = self.reproduction_config
        spawn_amounts = self.compute_spawn([s.adjusted_fitness for s in remaining],
                                           [len(s.members) for s in remaining], pop_size,
                                           max(settings.min_species_size, settings.elitism))
        population = {}
        species.species = {}
        for spawn, s in zip(spawn_amounts, remaining):
            # stable: ties keep the member order speciation gave (2.0 breaks them by key)
            ranked = sorted(s.members.items(), key=lambda member: member[1].fitness, reverse=True)
            s.members = {}
            species.species[s.key] = s
            elites = ranked[:settings.elitism]
            population.update(elites)
            parents = ranked[:max(2, math.ceil(settings.survival_threshold * len(ranked)))]
            for _ in range(max(spawn, settings.elitism) - len(elites)):
                parent1_id, parent1 = random.choice(parents)
                parent2_id, parent2 = random.choice(parents)
                key = next(self.genome_indexer)
                child = config.genome_type(key)
                child.configure_crossover(parent1, parent2, config.genome_config)
                child.mutate(config.genome_config)
                population[key] = child
                self.ancestors[key] = (parent1_id, parent2_id)
        return population


class Neat092SpeciesSet(SpeciesSet):
    """Speciation visiting genomes in ``set`` order and species in the species set's order."""

    def _unplaced(self, population: dict) -> set:
        # from an iterator, as 0.92 builds it: set(dict) presizes the table, and the table size
        # changes the order in which a set visits its keys
        return set(iter(population))

    @staticmethod
    def _take(unplaced: set) -> int:
        return unplaced.pop()

    def _species_order(self) -> list[int]:
        return list(self.species)


__all__ = ["Genetics", "GENETICS", "DEFAULT_GENETICS", "GeneticsVersion", "check_genetics", "genetics_version",
           "Reproduction", "Neat092NodeGene", "Neat092ConnectionGene", "Neat092Genome", "Neat092Stagnation",
           "Neat092Reproduction", "Neat092SpeciesSet"]
