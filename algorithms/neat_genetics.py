"""neat-python 0.92's genetics, built on neat-python 2.0's extension points.

The paper ran neat-python 0.92; this project runs neat-python 2.0, whose genetic operators,
selection and speciation differ from 0.92's. The classes here are the genome, the genes, the
reproduction, the species set and the stagnation that a ``neat.Config`` takes
(``build_neat_config(..., genetics="0.92")`` puts them together) and behave as 0.92's do, down to
the order of every draw from ``random``: from the same seed and the same fitness they evolve the
populations neat-python 0.92 evolves, gene for gene (``tests/test_neat_genetics.py`` runs 0.92
itself next to them).

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
    in ascending key order. (Both compute their distances in batches: ``neat_speciation``.)

Shared by both versions and inherited unchanged: attribute initialisation and mutation (including
the draws a zero rate still makes), the order of mutations, node and connection deletion,
initial connections (``partial_direct``), the genome distance (0.92's node distance has no
time-constant term, which is exactly 0 in 2.0, where the time constant never changes), the spawn
formula, elitism, the survival threshold, complete-extinction handling, and the configuration
file (every option is given, so neither version's defaults matter).

Innovation numbers: 0.92 has none. These genomes still carry the numbers 2.0's tracker assigns
(a child's connection takes the fitter parent's), which label genes in exports and checkpoints;
nothing here reads them, and assigning them draws no random number.
"""
from __future__ import annotations

import math
import random
import sys
from typing import Literal, get_args

import neat
from neat.genes import DefaultConnectionGene, DefaultNodeGene
from neat.genome import DefaultGenomeConfig
from neat.graphs import creates_cycle
from neat.math_util import mean

from .neat_speciation import SpeciesSet

Genetics = Literal["0.92", "2.0"]
GENETICS: tuple[str, ...] = get_args(Genetics)
"""The genetics a NEAT run can use: neat-python 0.92's (the paper's) or 2.0's."""
DEFAULT_GENETICS = "0.92"


def check_genetics(value) -> str:
    """``value`` if it is one of ``GENETICS`` (version names, as strings), else ValueError."""
    if value not in GENETICS:
        raise ValueError(f"genetics must be one of {', '.join(repr(g) for g in GENETICS)}, got {value!r}")
    return value


class Neat092NodeGene(DefaultNodeGene):
    """A node gene without 2.0's ``time_constant``."""

    _gene_attributes = [a for a in DefaultNodeGene._gene_attributes if a.name != "time_constant"]
    distance_terms = ("bias", "response")
    """The attributes whose absolute differences ``distance`` adds, in order (``neat_speciation``)."""

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
            s.adjusted_fitness = (mean(m.fitness for m in s.members.values()) - lowest) / fitness_range

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


__all__ = ["Genetics", "GENETICS", "DEFAULT_GENETICS", "check_genetics", "Neat092NodeGene", "Neat092ConnectionGene",
           "Neat092Genome", "Neat092Stagnation", "Neat092Reproduction", "Neat092SpeciesSet"]
