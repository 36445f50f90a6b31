"""NEAT (neat-python 2.0) behind the ask/tell interface, with the paper's genetic-distance
regulariser.

One ``tell`` is one generation of neat-python's ``Population.run`` without the reporters:
best-genome tracking on ``genome.fitness`` (the selection fitness), ``reproduce``,
complete-extinction handling, ``speciate``, ``generation += 1``. The components are neat-python's
own (``DefaultReproduction``, with a fix of its spawn-count adjustment: ``neat_network.Reproduction``;
``DefaultSpeciesSet``, ``DefaultStagnation``) with the paper's
configuration (``neat_config.ini``, built per optimiser by ``build_neat_config``).

Randomness: neat-python draws from the global ``random`` module. The optimiser keeps its own
``random`` state, seeded from ``seed``, and swaps it into the global module only while
neat-python runs (construction and ``tell``), restoring the caller's state afterwards. So a
run is determined by ``seed`` whatever else uses ``random``, and other users of ``random`` are
not disturbed. ``state_dict`` holds that state, so a resumed run continues bit-for-bit.
"""
from __future__ import annotations

import itertools
import json
import math
import numbers
import pickle
import random
import warnings
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import neat
import torch
from neat.export import export_network_json
from neat.reporting import ReporterSet

from .base import GenerationReport, Optimizer, OptimizerOptions
from .neat_network import (
    NEAT_SIGMOID_SLOPE,
    CompiledPopulation,
    UnconnectedOutputs,
    build_neat_config,
    compile_genomes,
    genome_layers,
)

STATE_FORMAT = "lifelong-evo/neat/1"


def _take_counter(obj, attr: str) -> int | None:
    """The next value of the ``itertools.count`` at ``obj.attr``, without consuming it."""
    counter = getattr(obj, attr)
    if counter is None:
        return None
    value = next(counter)
    setattr(obj, attr, itertools.count(value))
    return value


@dataclass(frozen=True)
class NeatOptions(OptimizerOptions):
    """NEAT's options (the NEAT parameters themselves are the paper's: ``neat_config.ini``)."""

    references: int = 1
    """The regulariser's penalty is the mean genetic distance to the last this many task references."""
    unconnected_outputs: UnconnectedOutputs = "zero"
    """Nodes without enabled inputs are dead (zero: neat-python 0.92, the paper's) or bias neurons
    (bias: neat-python 2.0); see ``algorithms.neat_network``."""

    def __post_init__(self):
        super().__post_init__()
        if isinstance(self.references, bool) or not isinstance(self.references, numbers.Integral) \
                or self.references < 1:
            raise ValueError(f"references must be an integer >= 1, got {self.references!r}")


class NeatOptimizer(Optimizer):
    """neat-python NEAT with the paper's configuration; see the module docstring and
    ``NeatOptions`` for the options."""

    name = "neat"
    has_regularizer = True
    Options = NeatOptions

    def __init__(self, *, obs_dim: int, population_size: int, seed: int,
                 regularization: float = 0.0, device: str | torch.device = "cpu", **options):
        self.options = self.Options(**options)
        if not (math.isfinite(regularization) and regularization >= 0):
            raise ValueError(f"regularization must be a finite number >= 0, got {regularization}")
        self.obs_dim = int(obs_dim)
        self.seed = int(seed)
        self.regularization = float(regularization)
        self.references = self.options.references
        self.unconnected_outputs = self.options.unconnected_outputs
        self.device = torch.device(device)
        self.config = build_neat_config(self.obs_dim, int(population_size))

        self._random_state = random.Random(self.seed).getstate()
        reporters = ReporterSet()
        stagnation = self.config.stagnation_type(self.config.stagnation_config, reporters)
        self.reproduction = self.config.reproduction_type(
            self.config.reproduction_config, reporters, stagnation)
        self.species = self.config.species_set_type(self.config.species_set_config, reporters)
        with self._neat_random():
            # as neat.Population.__init__
            self.population = self.reproduction.create_new(
                self.config.genome_type, self.config.genome_config, self.config.pop_size)
            self.generation = 0
            self.species.speciate(self.config, self.population, self.generation)
        self.best_genome = None
        """The best genome by selection fitness so far, kept as neat-python keeps it (a
        reference: an elite's ``fitness`` is overwritten when it is evaluated again)."""
        self.task_best = None
        """The best genome by selection fitness of the current task, kept as ``best_genome`` is
        (the paper's code takes its reference from neat-python's ``best_genome``): the genome
        itself, so when it is evaluated again as an elite its new fitness is what later genomes
        must beat. A lucky evaluation therefore does not stay the reference for the rest of the
        task. One pickle holds it with the population (``state_dict``), so resuming keeps that."""
        self.reference_genomes: list = []
        """One reference per finished task (``end_task``), oldest first."""
        self._asked: list | None = None
        self._policy: CompiledPopulation | None = None

    # ---------------------------------------------------------------------------- randomness

    @contextmanager
    def _neat_random(self):
        outer = random.getstate()
        random.setstate(self._random_state)
        try:
            yield
        finally:
            self._random_state = random.getstate()
            random.setstate(outer)

    # ---------------------------------------------------------------------------- ask / tell

    @property
    def population_size(self) -> int:
        return self.config.pop_size

    @property
    def genome_config(self):
        return self.config.genome_config

    def ask(self) -> CompiledPopulation:
        """The current population, sorted by genome key, as one batched policy."""
        if self._policy is None:
            self._asked = [self.population[k] for k in sorted(self.population)]
            self._policy = compile_genomes(self._asked, self.config, self.device,
                                           unconnected_outputs=self.unconnected_outputs)
        return self._policy

    @property
    def asked_genomes(self) -> list:
        """The genomes of the last ``ask``, in the policy's order."""
        if self._asked is None:
            raise RuntimeError("call ask() first")
        return self._asked

    def _per_genome(self, values: torch.Tensor, what: str) -> list[float]:
        values = torch.as_tensor(values).detach().reshape(-1)
        if values.numel() != len(self.asked_genomes):
            raise ValueError(f"{what} has {values.numel()} values for "
                             f"{len(self._asked)} genomes")
        out = values.double().cpu().tolist()
        if not all(math.isfinite(v) for v in out):
            raise ValueError(f"{what} must be finite, got {out}")
        return out

    def distances_to_references(self) -> torch.Tensor | None:
        """Mean neat-python distance of each asked genome to the last ``references`` task
        references (float64, ``(population,)``), or ``None`` before the first ``end_task``."""
        if not self.reference_genomes:
            return None
        refs = self.reference_genomes[-self.references:]
        gc = self.config.genome_config
        return torch.tensor([sum(r.distance(g, gc) for r in refs) / len(refs)
                             for g in self.asked_genomes], dtype=torch.float64)

    def regularise(self, fitness: torch.Tensor) -> torch.Tensor:
        """``fitness - regularization * mean distance to the references``; ``fitness`` itself
        when ``regularization == 0`` or before the first ``end_task``."""
        if self.regularization == 0 or not self.reference_genomes:
            return fitness
        distance = self.distances_to_references().to(fitness.device)
        return (fitness.double() - self.regularization * distance).to(fitness.dtype)

    def tell(self, fitness: torch.Tensor, selection_fitness: torch.Tensor) -> GenerationReport:
        genomes = self.asked_genomes
        raw = self._per_genome(fitness, "fitness")
        selection = self._per_genome(selection_fitness, "selection_fitness")
        for genome, r, s in zip(genomes, raw, selection):
            genome.raw_fitness = r
            genome.fitness = s
        species_sizes = {int(sid): len(s.members)
                         for sid, s in sorted(self.species.species.items())}

        # neat.Population.run, one generation, without the reporters
        best = None
        for g in self.population.values():
            if best is None or g.fitness > best.fitness:
                best = g
        if self.best_genome is None or best.fitness > self.best_genome.fitness:
            self.best_genome = best
        if self.task_best is None or best.fitness > self.task_best.fitness:
            self.task_best = best
        with self._neat_random():
            self.population = self.reproduction.reproduce(
                self.config, self.species, self.config.pop_size, self.generation)
            if not self.species.species:
                if not self.config.reset_on_extinction:
                    raise neat.CompleteExtinctionException()
                self.population = self.reproduction.create_new(
                    self.config.genome_type, self.config.genome_config, self.config.pop_size)
            self.species.speciate(self.config, self.population, self.generation)
        # lineage record only (never read by neat-python): keep it from growing without bound
        ancestors = self.reproduction.ancestors
        self.reproduction.ancestors = {k: ancestors[k] for k in self.population if k in ancestors}
        self.generation += 1
        self._asked = None
        self._policy = None
        return GenerationReport(species_sizes=species_sizes, extra={})

    def end_task(self) -> None:
        """The best genome of the task (by selection fitness) becomes a reference."""
        if self.task_best is not None:
            self.reference_genomes.append(self.task_best)
        self.task_best = None

    # ---------------------------------------------------------------------------- state

    def state_dict(self) -> dict[str, Any]:
        """Plain facts plus every piece of neat-python state as one pickle (``bytes``)."""
        gc = self.config.genome_config
        state = {
            "population": self.population,
            "species": self.species.species,
            "genome_to_species": self.species.genome_to_species,
            "species_next": _take_counter(self.species, "indexer"),
            "genome_next": _take_counter(self.reproduction, "genome_indexer"),
            "node_next": _take_counter(gc, "node_indexer"),
            "innovation_tracker": self.reproduction.innovation_tracker,
            "ancestors": self.reproduction.ancestors,
            "generation": self.generation,
            "best_genome": self.best_genome,
            "task_best": self.task_best,
            "reference_genomes": self.reference_genomes,
            "random_state": self._random_state,
            "asked_keys": None if self._asked is None else [g.key for g in self._asked],
        }
        return {
            "format": STATE_FORMAT,
            "obs_dim": self.obs_dim,
            "population_size": self.population_size,
            "unconnected_outputs": self.unconnected_outputs,
            "generation": self.generation,
            "neat_version": getattr(neat, "__version__", "unknown"),
            "pickle": pickle.dumps(state, protocol=pickle.HIGHEST_PROTOCOL),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        if state.get("format") != STATE_FORMAT:
            raise ValueError(f"not a NEAT optimiser state (format {state.get('format')!r})")
        for key in ("obs_dim", "population_size"):
            if state[key] != getattr(self, key):
                raise ValueError(f"state has {key}={state[key]}, this optimiser {getattr(self, key)}")
        data = pickle.loads(state["pickle"])
        self.population = data["population"]
        self.species.species = data["species"]
        self.species.genome_to_species = data["genome_to_species"]
        self.species.indexer = itertools.count(data["species_next"])
        self.reproduction.genome_indexer = itertools.count(data["genome_next"])
        gc = self.config.genome_config
        gc.node_indexer = None if data["node_next"] is None else itertools.count(data["node_next"])
        self.reproduction.innovation_tracker = data["innovation_tracker"]
        gc.innovation_tracker = data["innovation_tracker"]
        self.reproduction.ancestors = data["ancestors"]
        self.generation = data["generation"]
        self.best_genome = data["best_genome"]
        self.task_best = data["task_best"]
        self.reference_genomes = data["reference_genomes"]
        self._random_state = data["random_state"]
        keys = data["asked_keys"]
        self._asked = None if keys is None else [self.population[k] for k in keys]
        self._policy = None
        if self._asked is not None:  # ask() again gives the same genomes in the same order
            self._policy = compile_genomes(self._asked, self.config, self.device,
                                           unconnected_outputs=self.unconnected_outputs)

    # ---------------------------------------------------------------------------- export

    def export(self, index: int) -> dict[str, Any]:
        """Genome ``index`` of the last asked population, JSON-serialisable.

        ``genome``: every gene (disabled connections included), enough to rebuild it.
        ``network``: neat-python 2.0's ``neat.export`` JSON of its ``FeedForwardNetwork``
        (``created_timestamp`` dropped). Under ``unconnected_outputs == "zero"`` the outputs
        listed in ``zero_outputs`` are 0.0 whatever ``network`` says.
        """
        genome = self.asked_genomes[index]
        gc = self.config.genome_config
        layers, _links = genome_layers(genome, gc, self.unconnected_outputs)
        computed = set().union(*layers) if layers else set()
        with warnings.catch_warnings():  # neat.export calls datetime.utcnow()
            warnings.simplefilter("ignore", DeprecationWarning)
            network = json.loads(export_network_json(
                neat.nn.FeedForwardNetwork.create(genome, self.config),
                metadata={"genome_id": genome.key, "generation": self.generation}))
        network["metadata"].pop("created_timestamp", None)
        return {
            "format": "neat-python-genome",
            "genome_key": int(genome.key),
            "num_inputs": gc.num_inputs,
            "num_outputs": gc.num_outputs,
            "activation": {"name": "neat_sigmoid", "slope": NEAT_SIGMOID_SLOPE},
            "unconnected_outputs": self.unconnected_outputs,
            "zero_outputs": [k for k in gc.output_keys if k not in computed],
            "fitness": getattr(genome, "raw_fitness", None),
            "selection_fitness": genome.fitness,
            "genome": {
                "nodes": [{"key": int(k), "bias": n.bias, "response": n.response,
                           "activation": n.activation, "aggregation": n.aggregation}
                          for k, n in sorted(genome.nodes.items())],
                "connections": [{"in": int(a), "out": int(b), "weight": c.weight,
                                 "enabled": bool(c.enabled), "innovation": int(c.innovation)}
                                for (a, b), c in sorted(genome.connections.items())],
            },
            "network": network,
        }


__all__ = ["NeatOptimizer", "STATE_FORMAT"]
