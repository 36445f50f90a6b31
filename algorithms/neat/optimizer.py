"""NEAT on neat-python 2.0 behind the ask/tell interface, with the paper's genetic-distance
regulariser (``penalty="gd"``) or weight protection (``penalty="wp"``, ``weight_protection``), the
reference code's other one (docs/algorithms.md gives both formulas); its task references exported
for the functional regulariser (``reference_export``).

One ``tell`` is one generation of neat-python's ``Population.run`` without the reporters:
best-genome tracking on ``genome.fitness`` (the selection fitness), ``reproduce``,
complete-extinction handling, ``speciate``, ``generation += 1``. ``genetics`` picks the genome,
reproduction, species set and stagnation (``genetics.genetics_version``): ``"0.92"`` (the
default, the paper's) reproduces neat-python 0.92's (the population size then drifts by a few
genomes around ``population_size``), ``"2.0"`` uses neat-python 2.0's own (with a fix of its
spawn-count adjustment). Both run the paper's configuration (``config.ini``, built per optimiser
by ``config.build_neat_config``); the batched network is ``network.compile_genomes``.

Per generation ``tell`` reports the ``diagnostics`` in ``GenerationReport.extra``: the mean and
standard deviation over the evaluated genomes of the regulariser's distance to the references
(NaN before the first ``end_task``; computed once per generation, shared with ``regularise``),
and the mean fraction of disabled connections per genome.

Randomness: neat-python draws from the global ``random`` module. The optimiser keeps its own
``random`` state, seeded from ``seed``, and swaps it into the global module only while
neat-python runs (construction and ``tell``), restoring the caller's state afterwards. So a
run is determined by ``seed`` whatever else uses ``random``, and other users of ``random`` are
not disturbed. ``state_dict`` holds that state, so a resumed run continues bit-for-bit.
"""
from __future__ import annotations

import collections
import itertools
import json
import math
import numbers
import random
import warnings
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, Literal

import neat
import torch
from neat.export import export_network_json
from neat.reporting import ReporterSet

from envs import numerics

from ..base import FUNCTIONAL, GenerationReport, Optimizer, OptimizerOptions
from . import state as neat_state
from .config import CONFIG_FILE, build_neat_config, minimum_population
from .export import check_export, genome_from_export
from .genetics import DEFAULT_GENETICS, Genetics, genetics_version
from .network import NEAT_SIGMOID_SLOPE, CompiledPopulation, UnconnectedOutputs, compile_genomes, genome_layers

STATE_FORMAT = "lifelong-evo/neat/2"
Penalty = Literal["gd", "wp"]
"""The regulariser's distance to a reference: the genome distance (gd) or weight protection (wp)."""


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
    """NEAT's options (the NEAT parameters themselves are the paper's: ``config.ini``)."""

    references: int = field(default=1, metadata={"min": 1, "max": 1000})
    """The regulariser's penalty is the mean distance to the last this many task references."""
    penalty: Penalty = "gd"
    """The regulariser's distance: gd (the genome distance, the paper's) or wp (weight protection);
    chosen with --regulariser."""
    lambda_2: float = field(default=0.3, metadata={"min": 0, "max": 1e9})
    """Weight protection's lambda_2, on the squared weights of connections the reference lacks
    (lambda_1 is --reg)."""
    unconnected_outputs: UnconnectedOutputs = "zero"
    """Nodes without enabled inputs are dead (zero: neat-python 0.92, the paper's) or bias neurons
    (bias: neat-python 2.0); see ``algorithms.neat.network``."""
    genetics: Genetics = DEFAULT_GENETICS
    """The genetics the population evolves with: neat-python 0.92's (the paper's) or 2.0's; see
    ``algorithms.neat.genetics``."""

    def __post_init__(self):
        super().__post_init__()
        if isinstance(self.references, bool) or not isinstance(self.references, numbers.Integral) \
                or self.references < 1:
            raise ValueError(f"references must be an integer >= 1, got {self.references!r}")
        if not (isinstance(self.lambda_2, numbers.Real) and math.isfinite(self.lambda_2) and self.lambda_2 >= 0):
            raise ValueError(f"lambda_2 must be a finite number >= 0, got {self.lambda_2!r}")


def weight_protection(genome, reference) -> tuple[float, float]:
    """Weight protection's two sums for ``genome`` against one ``reference`` genome: over the
    genome's connection genes (enabled or not) whose key, ``(input, output)``, the reference also
    has, the squared difference of the two weights; over its other connection genes, the squared
    weight. Membership and weight both come from ``reference``."""
    shared = other = 0.0
    for key, gene in genome.connections.items():
        theirs = reference.connections.get(key)
        if theirs is None:
            other += gene.weight * gene.weight
        else:
            shared += (gene.weight - theirs.weight) ** 2
    return shared, other


class NeatOptimizer(Optimizer):
    """neat-python NEAT with the paper's configuration; see the module docstring and
    ``NeatOptions`` for the options."""

    name = "neat"
    has_regularizer = True
    Options = NeatOptions
    diagnostics = ("distance_mean", "distance_std", "disabled_fraction")
    regularizer_options = ("references", "penalty", "lambda_2")
    regularisers = {"gd": {"penalty": "gd"}, "wp": {"penalty": "wp"}, FUNCTIONAL: {}}
    # the functional regulariser reads only the latest reference (reference_export)
    options_used_by = {"lambda_2": ("wp",), "references": ("gd", "wp")}
    lambda_options = ("lambda_2",)
    # the penalty needs a reference: none of them acts before the first end_task, which appends the
    # task's best genome to reference_genomes whatever they say, and state_dict holds none of them
    after_first_task_options = ("references", "penalty", "lambda_2")

    @classmethod
    def check_population(cls, population_size: int, options: NeatOptions | None = None) -> None:
        genetics = (options or cls.Options()).genetics
        smallest, why = minimum_population(genetics)
        if population_size < smallest:
            raise ValueError(f"NEAT with genetics {genetics} needs a population of at least {smallest} ({why}: "
                             f"elitism in {CONFIG_FILE}), got {population_size}")

    @classmethod
    def memory_needs(cls, population_size: int, obs_dim: int, options: NeatOptions) -> tuple[int, int]:
        # measured: the genomes, as neat-python's objects, about 2.5 kB a gene (a fresh genome has
        # about 2 * obs_dim + 10 genes: half of the input-to-node connections), and speciating the
        # first population, about 5 bytes per gene for every pair of genomes; the batched
        # network's node values, for up to 64 node slots
        genes = 2 * obs_dim + 10
        return population_size * genes * 2500 + population_size ** 2 * (5 * genes + 30), 16 * 64

    def __init__(self, *, obs_dim: int, population_size: int, seed: int,
                 reg: float = 0.0, device: str | torch.device = "cpu", **options):
        self.options = self.Options(**options)
        self.check_population(int(population_size), self.options)
        if not (math.isfinite(reg) and reg >= 0):
            raise ValueError(f"reg (lambda) must be a finite number >= 0, got {reg}")
        self.obs_dim = int(obs_dim)
        self.seed = int(seed)
        self.reg = float(reg)
        self.references = self.options.references
        self.penalty = self.options.penalty
        self.unconnected_outputs = self.options.unconnected_outputs
        self.genetics = self.options.genetics
        self.device = torch.device(device)
        self.config = build_neat_config(self.obs_dim, int(population_size), genetics=self.genetics)

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
        task. ``state_dict`` stores it as a reference into the population, so resuming keeps that."""
        self.reference_genomes: list = []
        """One reference per finished task (``end_task``), oldest first."""
        self._asked: list | None = None
        self._policy: CompiledPopulation | None = None
        self._distances: torch.Tensor | None = None

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
        """Genomes in the current population: ``pop_size`` under genetics 2.0, within a few of
        it under 0.92."""
        return len(self.population)

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

    def distance(self, genome, reference) -> float:
        """The regulariser's distance of ``genome`` to one ``reference``: neat-python's genome
        distance (``gd``), or weight protection's ``shared + (lambda_2 / lambda_1) * other``
        (``wp``, ``weight_protection``; lambda_1 is ``reg``, 1 at ``reg == 0``), so that the penalty
        is ``reg`` times it either way."""
        if self.penalty == "gd":
            return reference.distance(genome, self.config.genome_config)
        shared, other = weight_protection(genome, reference)
        return shared + self.options.lambda_2 / (self.reg or 1.0) * other

    def distances_to_references(self) -> torch.Tensor | None:
        """Mean distance (``distance``) of each asked genome to the last ``references`` task
        references (float64, ``(population,)``), or ``None`` before the first ``end_task``.
        Computed once per asked population and set of references."""
        if not self.reference_genomes:
            return None
        if self._distances is None:
            refs = self.reference_genomes[-self.references:]
            self._distances = torch.tensor([numerics.ordered_mean(self.distance(g, r) for r in refs)
                                            for g in self.asked_genomes], dtype=torch.float64)
        return self._distances

    def regularise(self, fitness: torch.Tensor) -> torch.Tensor:
        """``fitness - reg * mean distance to the references`` (``reg``: lambda; under ``wp`` that
        is ``lambda_1 * shared + lambda_2 * other``, averaged over the references); ``fitness``
        itself when ``reg == 0`` or before the first ``end_task``."""
        if self.reg == 0 or not self.reference_genomes:
            return fitness
        distance = self.distances_to_references().to(fitness.device)
        return (fitness.double() - self.reg * distance).to(fitness.dtype)

    def tell(self, fitness: torch.Tensor, selection_fitness: torch.Tensor) -> GenerationReport:
        genomes = self.asked_genomes
        raw = self._per_genome(fitness, "fitness")
        selection = self._per_genome(selection_fitness, "selection_fitness")
        for genome, r, s in zip(genomes, raw, selection):
            genome.raw_fitness = r
            genome.fitness = s
        diagnostics = self._diagnostics(genomes)
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
        self._distances = None
        return GenerationReport(species_sizes=species_sizes, extra=diagnostics)

    def _diagnostics(self, genomes: list) -> dict[str, float]:
        """The ``diagnostics`` of the evaluated ``genomes`` (the module docstring); a genome
        without connections has no disabled ones."""
        distances = self.distances_to_references()
        disabled = [sum(not c.enabled for c in g.connections.values()) / len(g.connections)
                    if g.connections else 0.0 for g in genomes]
        return {"distance_mean": math.nan if distances is None else distances.mean().item(),
                "distance_std": math.nan if distances is None else distances.std(unbiased=False).item(),
                "disabled_fraction": numerics.ordered_mean(disabled)}

    def end_task(self) -> None:
        """The best genome of the task (by selection fitness) becomes a reference."""
        if self.task_best is not None:
            self.reference_genomes.append(self.task_best)
        self.task_best = None
        self._distances = None

    def adopt(self, exported: dict[str, Any]) -> None:
        """Put the exported genome (``export``) back into the population the next ``ask`` returns,
        in place of the genome with the lowest fitness of the last generation: a new offspring has
        not been evaluated yet and counts lowest (the newest first), so the elites are kept. It
        gets a new genome key, and the node counter moves past its node keys (a from-scratch
        population's may lie below them). Where crossover lines genes up by innovation number
        (genetics 2.0) its connections are renumbered as this population numbers them
        (``_renumber``); otherwise (0.92) its numbers are labels only and the innovation tracker
        moves past them. The population is then speciated again, as neat-python speciates a new
        one. The population's size is unchanged."""
        if self._asked is not None:
            raise RuntimeError("adopt() goes between tell() and the next ask()")
        check_export(exported, self.obs_dim)
        for key in ("genetics", "unconnected_outputs"):
            if exported.get(key) != getattr(self, key):
                raise ValueError(f"the controller has {key} {exported.get(key)!r}, "
                                 f"this optimiser {getattr(self, key)!r}")
        victim = min(self.population.values(), key=lambda g: (-math.inf if g.fitness is None else g.fitness, -g.key))
        genome = genome_from_export({**exported, "genome_key": next(self.reproduction.genome_indexer)}, self.config)
        del self.population[victim.key]
        self.reproduction.ancestors.pop(victim.key, None)
        if genetics_version(self.genetics).crossover_by_innovation:
            self._renumber(genome)
        else:  # labels only; moving past them keeps any label from naming two keys
            tracker = self.reproduction.innovation_tracker
            tracker.global_counter = max([tracker.global_counter, *(c.innovation for c in genome.connections.values())])
        self.population[genome.key] = genome
        self.reproduction.ancestors[genome.key] = ()
        gc = self.config.genome_config
        following = _take_counter(gc, "node_indexer")
        gc.node_indexer = itertools.count(max(max(genome.nodes) + 1, following or 0))
        with self._neat_random():  # the generation this population was speciated in (tell counts on after it)
            self.species.speciate(self.config, self.population, max(self.generation - 1, 0))
        self._distances = None

    def _renumber(self, genome) -> None:
        """Give each connection of ``genome`` (not yet in the population) the innovation number the
        population gives its key: the one most of the population's genes with that key carry, the
        oldest (lowest) among equally common ones (2.0's tracker numbers a key again when a later
        generation adds it again). A key no genome has gets a number from the innovation tracker,
        as a connection added by mutation does. An exported genome's numbers are another tracker's
        (a from-scratch population starts a new one, numbering in first-seen order, so the same
        number names another key there) or an older generation's; 2.0's crossover would then pair
        unrelated genes and miss homologous ones. Draws nothing from ``random``."""
        carriers = collections.Counter((key, gene.innovation) for member in self.population.values()
                                       for key, gene in member.connections.items())
        numbers: dict[tuple[int, int], int] = {}
        for key, innovation in sorted(carriers, key=lambda pair: (-carriers[pair], pair[1])):
            numbers.setdefault(key, innovation)  # the most common first, then the oldest
        tracker = self.reproduction.innovation_tracker
        for key, gene in genome.connections.items():
            gene.innovation = numbers[key] if key in numbers else tracker.get_innovation_number(*key, "add_connection")

    # ---------------------------------------------------------------------------- state

    def state_dict(self) -> dict[str, Any]:
        """Plain facts plus every piece of neat-python state as JSON text (``algorithms.neat.state``):
        loads with ``torch.load(weights_only=True)`` and continues bit-for-bit."""
        gc = self.config.genome_config
        neat_state.check_components(self.reproduction, self.species)
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
        types = neat_state.object_types(self.config, self.species, self.reproduction)
        return {
            "format": STATE_FORMAT,
            "obs_dim": self.obs_dim,
            "population_size": self.config.pop_size,
            "genetics": self.genetics,
            "unconnected_outputs": self.unconnected_outputs,
            "generation": self.generation,
            "neat_version": getattr(neat, "__version__", "unknown"),
            "state": neat_state.dumps(state, types),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        if state.get("format") != STATE_FORMAT:
            raise ValueError(f"not a NEAT optimiser state (format {state.get('format')!r})")
        stored = {"obs_dim": state["obs_dim"], "population_size": state["population_size"],
                  "genetics": state["genetics"]}
        mine = {"obs_dim": self.obs_dim, "population_size": self.config.pop_size, "genetics": self.genetics}
        for key, value in mine.items():
            if stored[key] != value:
                raise ValueError(f"state has {key}={stored[key]!r}, this optimiser {value!r}")
        data = neat_state.loads(state["state"], neat_state.object_types(self.config, self.species, self.reproduction))
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
        self._distances = None
        if self._asked is not None:  # ask() again gives the same genomes in the same order
            self._policy = compile_genomes(self._asked, self.config, self.device,
                                           unconnected_outputs=self.unconnected_outputs)

    # ---------------------------------------------------------------------------- export

    def reference_export(self) -> dict[str, Any] | None:
        """The latest task reference (``end_task``), exported as ``export`` does but without a
        generation: the one the optimiser is at is not the reference's, and the export stays the
        same until ``end_task`` takes the next one."""
        return self._export_genome(self.reference_genomes[-1]) if self.reference_genomes else None

    def export(self, index: int) -> dict[str, Any]:
        """Genome ``index`` of the last asked population, JSON-serialisable (``_export_genome``)."""
        return self._export_genome(self.asked_genomes[index], self.generation)

    def _export_genome(self, genome, generation: int | None = None) -> dict[str, Any]:
        """``genome``, JSON-serialisable.

        ``genome``: every gene (disabled connections included), enough to rebuild it.
        ``network``: neat-python 2.0's ``neat.export`` JSON of its ``FeedForwardNetwork``
        (``created_timestamp`` dropped; its ``metadata`` has ``generation`` where given). Under
        ``unconnected_outputs == "zero"`` the outputs listed in ``zero_outputs`` are 0.0 whatever
        ``network`` says.
        """
        gc = self.config.genome_config
        layers, _links = genome_layers(genome, gc, self.unconnected_outputs)
        computed = set().union(*layers) if layers else set()
        with warnings.catch_warnings():  # neat.export calls datetime.utcnow()
            warnings.simplefilter("ignore", DeprecationWarning)
            network = json.loads(export_network_json(
                neat.nn.FeedForwardNetwork.create(genome, self.config),
                metadata={"genome_id": genome.key, **({"generation": generation} if generation is not None else {})}))
        network["metadata"].pop("created_timestamp", None)
        return {
            "format": "neat-python-genome",
            "genome_key": int(genome.key),
            "num_inputs": gc.num_inputs,
            "num_outputs": gc.num_outputs,
            "activation": {"name": "neat_sigmoid", "slope": NEAT_SIGMOID_SLOPE},
            "unconnected_outputs": self.unconnected_outputs,
            "zero_outputs": [k for k in gc.output_keys if k not in computed],
            "genetics": self.genetics,
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
