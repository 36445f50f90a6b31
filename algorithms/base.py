"""The ask/tell interface every optimiser implements.

One generation of the lifelong loop is::

    policy = optimiser.ask()                       # a BatchedPolicy over the population
    raw = evaluate(policy, tasks)                  # (population,) mean episode reward
    regularised = optimiser.regularise(raw)        # raw - lambda * penalty (raw before a drift)
    report = optimiser.tell(raw, regularised)      # selection uses `regularised`
    ...
    optimiser.end_task()                           # at a drift: take the regulariser's reference
    optimiser.adopt(exported)                      # optional: put an exported controller back (the skill archive)

Optimisers know nothing about environments, Rerun or files: they see observations and fitness
tensors only. Their options (the keyword arguments beyond the common ones) are declared once, as
an ``OptimizerOptions`` dataclass.
"""
from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass, field, fields
from typing import Any, ClassVar, Literal, Protocol, get_args, get_origin, get_type_hints

import torch


class ExportError(ValueError):
    """An exported controller (``Optimizer.export``) that is not what its format says: a missing
    or mistyped field, sizes that disagree, or inputs other than the ones asked for. The message
    names the field and what it must be."""


def is_number(value: Any) -> bool:
    """Whether a JSON value is a finite number (an int or a float, not a boolean; not NaN or an
    infinity, which Python's json reads and no controller's parameter can be)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def is_integer(value: Any) -> bool:
    """Whether a JSON value is an integer (not a boolean)."""
    return isinstance(value, int) and not isinstance(value, bool)


def shown_value(value: Any) -> str:
    """``value`` for a message, cut to one short line (a list of thousands of parameters is not shown whole)."""
    shown = repr(value)
    return shown if len(shown) <= 60 else shown[:40] + "..." + shown[-10:]


class BatchedPolicy(Protocol):
    """Maps observations of a whole population to controller outputs in one call.

    ``observations``: ``(population, envs, agents, obs_dim)``;
    returns ``(population, envs, agents, 3)`` outputs in ``[0, 1]``
    (turned into wheel speeds by ``envs.outputs_to_wheels``).
    """

    population_size: int

    def __call__(self, observations: torch.Tensor) -> torch.Tensor: ...

    def shard(self, start: int, stop: int) -> "BatchedPolicy":
        """Controllers ``start .. stop - 1`` as a policy of their own, giving the outputs they
        give in the whole population, up to float rounding (the evaluator's threads each play
        one shard). Optional: a policy without it is played in one thread."""


@dataclass
class GenerationReport:
    """What an optimiser tells the loop about the generation it was just told."""

    species_sizes: dict[int, int] | None = None
    """NEAT species id -> member count; ``None`` for algorithms without species."""
    extra: dict[str, float] = field(default_factory=dict)
    """Algorithm-specific scalars (for example the ES step size), logged as they are; those
    named in the optimiser's ``diagnostics`` also go to metrics.csv."""


@dataclass(frozen=True)
class Connection:
    """An enabled connection of a NEAT controller, as ``ControllerNetwork`` lists it."""

    source: int
    """neat-python's key of the node it reads: negative for an input."""
    target: int
    weight: float
    new: bool
    """The reference has no enabled connection from ``source`` to ``target`` (False without a reference)."""


@dataclass(frozen=True)
class ControllerNetwork:
    """An exported controller as a drawing shows it, set against a reference controller
    (``algorithms.network_from_export``): what it is made of, and how far it lies from the
    reference by the measures its family has. A NEAT genome fills ``nodes`` and ``connections``,
    an MLP ``layer_sizes`` and ``layer_distances``."""

    nodes: tuple[tuple[int, str], ...] = ()
    """NEAT: ``(key, role)`` of the inputs with an enabled connection, then every hidden and output
    node in key order; ``role`` is ``input``, ``hidden`` or ``output``."""
    connections: tuple[Connection, ...] = ()
    """NEAT: the enabled connections, in the export's order."""
    layer_sizes: tuple[int, ...] = ()
    """An MLP: ``(inputs, *hidden, outputs)``."""
    layer_distances: tuple[float, ...] = ()
    """An MLP with a reference: per layer, the Euclidean distance of its weights and biases to the reference's."""
    measures: tuple[tuple[str, float], ...] = ()
    """``(what is measured, value)`` against the reference, in words a reader can take as they are
    (``genetic distance``); empty without a reference."""


@dataclass(frozen=True)
class OptimizerOptions:
    """An optimiser's options, declared once: each field's default, its type (what a command-line
    or TOML value is parsed to), and its docstring (the one line ``python -m lifelong_evo options``
    shows). Constructing it raises ValueError for a value the optimiser cannot use, so a bad
    option is refused before anything is built.

    This base has no fields; it checks that every ``Literal`` field holds one of its choices.
    Subclasses add fields, and range checks in a ``__post_init__`` that calls this one.
    """

    def __post_init__(self):
        hints = get_type_hints(type(self))
        for f in fields(self):
            choices = get_args(hints[f.name]) if get_origin(hints[f.name]) is Literal else None
            if choices and getattr(self, f.name) not in choices:
                raise ValueError(f"{f.name} must be one of {', '.join(map(repr, choices))}, "
                                 f"got {getattr(self, f.name)!r}")


FUNCTIONAL = "functional"
"""The regulariser every optimiser with a ``reference_export`` can have: lambda times the mean
summed absolute difference between a controller's outputs and the reference's on the
observations the controller saw (``lifelong_evo.evaluate.BesideReference``)."""


class Optimizer(ABC):
    """A population-based optimiser behind the ask/tell interface."""

    name: ClassVar[str]
    """Registry name, e.g. ``"neat"``."""
    has_regularizer: ClassVar[bool] = True
    """Whether ``reg > 0`` (lambda, the regulariser's strength) means anything for this algorithm."""
    regularizer_options: ClassVar[tuple[str, ...]] = ()
    """Options that shape only the regulariser: at ``reg == 0`` they change no controller and no
    fitness (only the distance diagnostics), so runs that differ in nothing else are one
    configuration."""
    Options: ClassVar[type[OptimizerOptions]] = OptimizerOptions
    """The options the constructor takes as keyword arguments (none by default)."""
    regularisers: ClassVar[dict[str, dict[str, Any]]] = {}
    """The regularisers ``--regulariser`` may choose for this optimiser, its default first, each with
    the options that make the optimiser apply it. ``functional`` (``FUNCTIONAL``) names none: the
    lifelong loop applies it, to the controllers' outputs beside ``reference_export``'s, with the
    optimiser built at lambda 0. Empty: the optimiser's own regulariser, unnamed. A run that names
    none applies the first whose options its options match, ``functional`` only where no other
    does (``lifelong_evo.config.resolve_regulariser``)."""
    options_used_by: ClassVar[dict[str, tuple[str, ...]]] = {}
    """Options that only some of ``regularisers`` read, each with those that do (NEAT's ``lambda_2``:
    ``wp``): given under another regulariser, such an option is refused, since it would change
    nothing but the run's configuration."""
    lambda_options: ClassVar[tuple[str, ...]] = ()
    """Options that weigh a penalty beside lambda (NEAT's ``lambda_2``: weight protection's weight
    on the connections the reference lacks, lambda_1 being ``reg``). At ``reg == 0`` no regulariser
    plays, so giving one is refused (it would promise a penalty the run does not apply); a lambda
    choice (``compare``'s model-specific lambda) sweeps them with lambda, as one value."""
    after_first_task_options: ClassVar[tuple[str, ...]] = ()
    """Options that act only from the end of the first task, where the regulariser takes its first
    reference: every number before that end, and the whole ``state_dict`` at it (after that
    ``end_task``), are the same whatever they say, so runs that differ only in them share their
    first task (``--start-from``, ``sweep --share-first-task``). Not an option that shapes what
    ``end_task`` keeps (an ES's ``reference``: the centre or the best) or that chooses a regulariser
    which gathers anything during a task (an ES's ``importance=ewc``). Like lambda, which no
    optimiser may use before its first ``end_task``, and the choice of regulariser itself (its
    options apart), they are trusted: ``tests/test_first_task_settings.py`` plays a first task with
    two values of each declared one, for every registered optimiser."""

    @classmethod
    def choosing_options(cls) -> frozenset[str]:
        """The options that choose among ``regularisers`` (NEAT's ``penalty``, an ES's ``importance``)."""
        return frozenset(key for options in cls.regularisers.values() for key in options)

    @classmethod
    def check_population(cls, population_size: int, options: OptimizerOptions) -> None:
        """Raise ValueError, saying the smallest size it can evolve, unless this optimiser can
        evolve ``population_size`` controllers with ``options`` (checked before anything is
        built; any size >= 1 by default)."""

    @classmethod
    def memory_needs(cls, population_size: int, obs_dim: int, options: OptimizerOptions) -> tuple[int, int]:
        """Bytes this optimiser holds at its peak for ``population_size`` controllers with
        ``obs_dim`` inputs (its state, its samples, its temporaries), and bytes its policy adds per
        (environment, agent) row while it runs: an upper estimate, measured on the built-in
        optimisers, for the check that a run fits in memory (``lifelong_evo.memory``). The default
        guesses an MLP of about 1000 parameters and 64 hidden units."""
        return 16 * population_size * 1000, 16 * 64

    centre_index: int | None = None
    """Index of the search distribution's centre among the controllers (ES), else ``None``."""

    diagnostics: ClassVar[tuple[str, ...]] = ()
    """Names of scalars every ``tell`` reports in ``GenerationReport.extra``, written to
    metrics.csv as columns of their own (NaN, written empty, where a value does not exist yet)."""

    @property
    @abstractmethod
    def population_size(self) -> int:
        """Number of controllers ``ask`` returns (for an ES: samples + centre)."""

    @abstractmethod
    def ask(self) -> BatchedPolicy:
        """The current population as one batched policy."""

    @abstractmethod
    def regularise(self, fitness: torch.Tensor) -> torch.Tensor:
        """Selection fitness: ``fitness - lambda * penalty``; ``fitness`` itself before the first drift."""

    @abstractmethod
    def tell(self, fitness: torch.Tensor, selection_fitness: torch.Tensor) -> GenerationReport:
        """Advance one generation; ``selection_fitness`` drives selection/update."""

    @abstractmethod
    def end_task(self) -> None:
        """Called after the last generation of a task: take the regulariser's reference."""

    @abstractmethod
    def state_dict(self) -> dict[str, Any]:
        """Everything needed to continue bit-for-bit (used by checkpoints)."""

    @abstractmethod
    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore what ``state_dict`` returned."""

    def reference_export(self) -> dict[str, Any] | None:
        """The regulariser's latest reference (taken at ``end_task``) as ``export`` writes a
        controller, or ``None`` before the first: the functional regulariser's reference. An
        optimiser that lists ``functional`` in ``regularisers`` implements it."""
        return None

    @abstractmethod
    def export(self, index: int) -> dict[str, Any]:
        """Controller ``index`` of the last asked population as a JSON-serialisable dict (safe to
        share: never a pickle) that ``algorithms.policy_from_export`` turns back into a policy."""

    def adopt(self, exported: dict[str, Any]) -> None:
        """Put a controller this optimiser exported earlier (``export``) back into the population
        that the next ``ask`` returns, without changing the population's size (the skill archive,
        ``--archive``); called between a ``tell`` and the next ``ask``. Optional: an optimiser
        without it cannot run with an archive (``can_adopt``)."""
        raise NotImplementedError(f"{self.name} cannot take back an exported controller (no adopt)")

    @classmethod
    def can_adopt(cls) -> bool:
        """Whether this optimiser implements ``adopt``."""
        return cls.adopt is not Optimizer.adopt
