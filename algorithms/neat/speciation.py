"""Genetic distances between NEAT genomes computed many pairs at a time, and the speciation
that uses them.

Speciation compares every genome with every species representative: thousands of distances per
generation, each a Python loop over two genomes' genes in neat-python. ``GenomeTable.distances``
computes them with float64 tensor arithmetic instead, and its results are equal, bit for bit, to
neat-python's ``a.distance(b, config)``. (The regulariser measures the population against one or
a few references, where neat-python's own loop is as quick as building a table.) That is what keeps the species (and so the whole run) unchanged: a
distance one bit off can move a genome across the compatibility threshold or break a tie
differently. Exactness rests on three facts:

* every operation is the IEEE double operation neat-python's Python floats perform (subtraction,
  ``abs``, addition, multiplication by the coefficients, one division), in the same order;
* neat-python adds the homologous genes' distances one at a time, in the order of the first
  genome's genes, and floating-point addition is not associative: so the sum here runs over
  gene positions in that order, one tensor addition per position, vectorised over pairs only
  (a non-homologous position adds ``0.0``, which leaves a non-negative sum unchanged);
* ``a.distance(b)`` and ``b.distance(a)`` can differ in the last bit, so the direction is kept:
  row ``i``, column ``j`` is ``selves[i].distance(others[j])``.

Only neat-python's genome distance and its node and connection gene distances are supported
(the node gene's terms are its ``distance_terms``, or neat-python 2.0's bias, response and time
constant); ``GenomeTable`` refuses other classes, and speciation computes their distances pair
by pair, as neat-python does.

``DistanceCache`` is neat-python's ``GenomeDistanceCache`` (whichever of ``a.distance(b)`` and
``b.distance(a)`` is asked for first answers both) whose misses are read from batches computed
by ``prepare``; a pair never prepared is computed by neat-python itself. ``SpeciesSet`` is
neat-python 2.0's ``DefaultSpeciesSet.speciate`` on that cache: the same species, members and
representatives, with the visiting orders as hooks that neat-python 0.92's species set
(``genetics.Neat092SpeciesSet``) overrides. (2.0's ``speciate`` also reports the mean genetic
distance to its reporters; the optimiser has none, so that is left out.)
"""
from __future__ import annotations

from collections.abc import Iterable, Sequence

import neat
import torch
from neat.genes import DefaultConnectionGene, DefaultNodeGene
from neat.species import Species


PAIR_GENES_AT_ONCE = 1 << 21
"""At most about this many (pair, gene) entries per batch: a few tens of MB of temporaries."""


def node_distance_terms(gene_type: type) -> tuple[str, ...] | None:
    """The attributes whose absolute differences a node gene's ``distance`` adds, in its order;
    None for a distance this module does not know."""
    if gene_type.distance is DefaultNodeGene.distance:
        return ("bias", "response", "time_constant")
    terms = getattr(gene_type, "distance_terms", None)
    return None if terms is None else tuple(terms)


def unsupported(genome_config, genomes: Iterable) -> str | None:
    """Why ``GenomeTable`` cannot compute these genomes' distances (a genome or gene class with a
    distance of its own), or None."""
    if node_distance_terms(genome_config.node_gene_type) is None:
        return (f"{genome_config.node_gene_type.__name__}.distance is not neat-python's: "
                "declare its distance_terms to batch its distances")
    if genome_config.connection_gene_type.distance is not DefaultConnectionGene.distance:
        return f"{genome_config.connection_gene_type.__name__}.distance is not neat-python's"
    if any(type(g).distance is not neat.DefaultGenome.distance for g in genomes):
        return "the genomes' distance is not neat-python's DefaultGenome.distance"
    return None


class GenomeTable:
    """The genes of a set of genomes as dense float64 tensors (one row per genome, one column
    per gene key), from which ``distances`` computes neat-python's genetic distances."""

    def __init__(self, genomes: Iterable, genome_config):
        config = genome_config
        unique = {}
        for genome in genomes:  # an elite is both a population member and a representative
            unique.setdefault(genome.key, genome)
        why = unsupported(config, unique.values())
        if why:
            raise TypeError(why)
        self.node_terms = node_distance_terms(config.node_gene_type)
        self.weight_coefficient = float(config.compatibility_weight_coefficient)
        self.disjoint_coefficient = float(config.compatibility_disjoint_coefficient)
        self.row = {key: row for row, key in enumerate(unique)}
        names: dict[str, int] = {}  # activation and aggregation function names, as numbers
        self.nodes = _Genes(unique.values(), "nodes", self.node_terms,
                            (lambda gene: names.setdefault(gene.activation, len(names)),
                             lambda gene: names.setdefault(gene.aggregation, len(names))))
        self.connections = _Genes(unique.values(), "connections", ("weight",), (lambda gene: gene.enabled,))

    def distances(self, selves: Sequence, others: Sequence) -> torch.Tensor:
        """``(len(selves), len(others))`` float64: ``selves[i].distance(others[j], config)``."""
        o = torch.tensor([self.row[g.key] for g in others], dtype=torch.long)
        width = max(self.nodes.order.shape[1], self.connections.order.shape[1], 1)
        step = max(1, PAIR_GENES_AT_ONCE // max(1, len(others) * width))  # bounds the (others, selves, genes) temporaries
        rows = []
        for start in range(0, len(selves), step):
            s = torch.tensor([self.row[g.key] for g in selves[start:start + step]], dtype=torch.long)
            node = self._part(self.nodes, s, o, self._node_gene_distances)
            connection = self._part(self.connections, s, o, self._connection_gene_distances)
            rows.append((node + connection).T)
        return torch.cat(rows) if rows else torch.zeros(0, len(others), dtype=torch.float64)

    def _node_gene_distances(self, mine: dict, theirs: dict) -> torch.Tensor:
        # as DefaultNodeGene.distance: the terms' |differences| in order, +1.0 for a different
        # activation, +1.0 for a different aggregation, times the weight coefficient
        d = None
        for term in self.node_terms:
            diff = (mine[term] - theirs[term]).abs()
            d = diff if d is None else d + diff
        for label in range(2):
            d = d + (mine["labels"][..., label] != theirs["labels"][..., label]).double()
        return d * self.weight_coefficient

    def _connection_gene_distances(self, mine: dict, theirs: dict) -> torch.Tensor:
        # as DefaultConnectionGene.distance: |weight difference|, +1.0 if one is disabled
        d = (mine["weight"] - theirs["weight"]).abs() + (mine["labels"][..., 0] != theirs["labels"][..., 0]).double()
        return d * self.weight_coefficient

    def _part(self, genes: _Genes, s: torch.Tensor, o: torch.Tensor, gene_distances) -> torch.Tensor:
        """One half of ``DefaultGenome.distance`` (nodes or connections), ``(len(o), len(s))``."""
        columns = genes.order[s]  # (S, L): each self's gene columns in its own order, padded
        mine = {name: values[s.unsqueeze(1), columns] for name, values in genes.values.items()}
        theirs = {name: values[o.view(-1, 1, 1), columns] for name, values in genes.values.items()}
        present = genes.present[o.view(-1, 1, 1), columns]  # (O, S, L); padding is never present
        contributions = torch.where(present, gene_distances(mine, theirs), 0.0).permute(2, 0, 1).contiguous()
        total = torch.zeros(contributions.shape[1:], dtype=torch.float64)
        for position in contributions:  # neat-python's order of summation (module docstring)
            total += position
        n_mine, n_theirs = genes.count[s].double(), genes.count[o].double().unsqueeze(1)
        disjoint = n_mine + n_theirs - 2 * present.sum(dim=2).double()
        larger = torch.maximum(n_mine.expand_as(disjoint), n_theirs.expand_as(disjoint))
        part = (total + self.disjoint_coefficient * disjoint) / larger.clamp_min(1)
        return torch.where(larger > 0, part, 0.0)


class _Genes:
    """One kind of gene (nodes or connections) of a ``GenomeTable``'s genomes: per attribute a
    ``(genomes, columns + 1)`` tensor (the last column is padding, present in no genome), which
    columns each genome has, and each genome's columns in its own gene order. ``numbers`` names
    the attributes whose differences count; ``labels`` give, as numbers, those compared for
    equality only."""

    def __init__(self, genomes: Iterable, kind: str, numbers: tuple[str, ...], labels: tuple):
        column: dict = {}
        counts, columns, genes = [], [], []
        for genome in genomes:
            part = getattr(genome, kind)
            counts.append(len(part))
            columns += [column.setdefault(key, len(column)) for key in part]
            genes += part.values()
        shape = (len(counts), len(column) + 1)
        self.count = torch.tensor(counts, dtype=torch.long)
        rows = torch.repeat_interleave(torch.arange(len(counts)), self.count)
        at = (rows, torch.tensor(columns, dtype=torch.long))
        self.present = torch.zeros(shape, dtype=torch.bool)
        self.present[at] = True
        self.values = {}
        for name in numbers:
            self.values[name] = torch.zeros(shape, dtype=torch.float64)
            self.values[name][at] = torch.tensor([float(getattr(g, name)) for g in genes], dtype=torch.float64)
        self.values["labels"] = torch.zeros(shape + (len(labels),), dtype=torch.float64)
        for i, label in enumerate(labels):
            self.values["labels"][at + (i,)] = torch.tensor([label(g) for g in genes], dtype=torch.float64)
        # each genome's columns in its gene order, padded with the padding column
        starts = torch.cumsum(self.count, 0) - self.count
        positions = torch.arange(len(columns)) - torch.repeat_interleave(starts, self.count)
        self.order = torch.full((len(counts), max(counts, default=0)), len(column), dtype=torch.long)
        self.order[rows, positions] = at[1]


class DistanceCache:
    """neat-python's ``GenomeDistanceCache`` answered from batches (module docstring)."""

    def __init__(self, genome_config, genomes: Iterable):
        self.config = genome_config
        genomes = list(genomes)
        # genomes with a distance of their own keep it, computed pair by pair
        self.table = None if unsupported(genome_config, genomes) else GenomeTable(genomes, genome_config)
        self.distances: dict[tuple[int, int], float] = {}
        self._prepared: dict[tuple[int, int], float] = {}

    def prepare(self, selves: Sequence, others: Sequence) -> None:
        """Compute ``self.distance(other)`` for every pair, for later calls to answer."""
        if self.table is None or not selves or not others:
            return
        for a, row in zip(selves, self.table.distances(selves, others).tolist()):
            self._prepared.update(zip(((a.key, b.key) for b in others), row))

    def __call__(self, genome0, genome1) -> float:
        key = (genome0.key, genome1.key)
        d = self.distances.get(key)
        if d is None:
            d = self._prepared.get(key)
            if d is None:
                d = genome0.distance(genome1, self.config)
            self.distances[key] = self.distances[genome1.key, genome0.key] = d
        return d


class SpeciesSet(neat.DefaultSpeciesSet):
    """neat-python 2.0's speciation with batched distances (module docstring). The hooks give
    2.0's orders: genomes placed in ascending key order, species visited by id."""

    def _unplaced(self, population: dict):
        return sorted(population)

    @staticmethod
    def _take(unplaced) -> int:
        return unplaced.pop(0)

    def _species_order(self) -> list[int]:
        return sorted(self.species)

    def speciate(self, config, population, generation):
        threshold = self.species_set_config.compatibility_threshold
        old = [self.species[sid] for sid in self._species_order()]
        distance = DistanceCache(config.genome_config,
                                 [*population.values(), *(s.representative for s in old)])
        unplaced = self._unplaced(population)
        distance.prepare([s.representative for s in old], list(population.values()))
        representatives, members = {}, {}
        for s in old:  # each species' new representative: the genome closest to its old one
            representative = min(unplaced, key=lambda key: distance(s.representative, population[key]))
            representatives[s.key] = representative
            members[s.key] = [representative]
            unplaced.remove(representative)
        distance.prepare([population[rid] for rid in representatives.values()],
                         [population[key] for key in unplaced])
        while unplaced:
            key = self._take(unplaced)
            genome = population[key]
            candidates = [(d, sid) for d, sid in ((distance(population[rid], genome), sid)
                                                  for sid, rid in representatives.items())
                          if d < threshold]
            if candidates:
                members[min(candidates, key=lambda c: c[0])[1]].append(key)
            else:
                sid = next(self.indexer)
                representatives[sid] = key
                members[sid] = [key]
                distance.prepare([genome], [population[k] for k in unplaced])

        self.genome_to_species = {}
        for sid, representative in representatives.items():
            s = self.species.get(sid)
            if s is None:
                s = self.species[sid] = Species(sid, generation)
            for key in members[sid]:
                self.genome_to_species[key] = sid
            s.update(population[representative], {key: population[key] for key in members[sid]})


__all__ = ["GenomeTable", "DistanceCache", "SpeciesSet", "node_distance_terms", "unsupported"]
