"""Evolution strategies (EvoTorch 0.6) on fixed-topology MLP controllers, behind ask/tell.

One adapter, ``ESOptimizer``, does what every ES shares: the MLP policy over the samples plus the
distribution centre (the last controller, ``centre_index``), seeding, the regulariser
(``algorithms.regularizers``), checkpoints and exports. ``GaussianES`` bridges EvoTorch's
separable-Gaussian searchers (OpenAI-ES, PGPE, SNES); ``algorithms.cmaes`` bridges CMA-ES.
Each algorithm is one small module (``cmaes``, ``openai_es``, ``pgpe``, ``snes``) that only says
which EvoTorch searcher it is and with which settings; the update math is always EvoTorch's.

Ask/tell bridge: EvoTorch's searchers sample *and* evaluate inside ``step()``. Here ``ask()`` draws
the samples with the searcher's own sampler (from the ``Problem``'s seeded generator), and
``tell()`` runs the searcher's own update on the fitness it is told:
Gaussian ESs through ``Distribution.compute_gradients`` + ``searcher._update_distribution`` (the two
calls of ``GaussianSearchAlgorithm._step_non_distributed``), CMA-ES through its unmodified
``step()`` with the asked samples handed back and a ``Problem`` whose evaluation writes the told
fitness. Everything is float32; one seed gives the same numbers on CPU.
"""
from __future__ import annotations

import logging
import math
import numbers
import warnings
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, ClassVar

import torch
from evotorch import Problem
from evotorch.optimizers import ClipUp, TorchOptimizer

from .base import FUNCTIONAL, GenerationReport, Optimizer, OptimizerOptions
from .mlp import MLPPolicy, check_export, layer_sizes_for, n_parameters
from .portable_update import portable_update
from .regularizers import Importance, Reference, Regularizer

STATE_FORMAT = 1


@contextmanager
def _quiet_evotorch():
    """Silence EvoTorch's INFO chatter (dtype/device/actors) while the objects are built, and
    the torch warning its CMAES constructor triggers by copying tensors with ``torch.tensor``."""
    logger = logging.getLogger("evotorch")
    level = logger.level
    logger.setLevel(max(level, logging.WARNING))
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message="To copy construct from a tensor", category=UserWarning)
            warnings.filterwarnings("ignore", message="__array_wrap__ must accept", category=DeprecationWarning)
            yield
    finally:
        logger.setLevel(level)


class TellProblem(Problem):
    """An EvoTorch ``Problem`` whose evaluation writes the fitness set in ``told``; it also
    owns the seeded generator every sample comes from."""

    def __init__(self, solution_length: int, *, seed: int, device: str | torch.device):
        super().__init__("max", solution_length=solution_length, initial_bounds=(-1.0, 1.0),
                         dtype=torch.float32, device=device, seed=seed, store_solution_stats=False)
        self.told: torch.Tensor | None = None

    def _evaluate_batch(self, batch):
        if self.told is None or self.told.shape[0] != len(batch):
            raise RuntimeError("TellProblem evaluated without the matching told fitness")
        batch.set_evals(self.told)


@dataclass(frozen=True)
class ESOptions(OptimizerOptions):
    """The options of every evolution strategy; each algorithm redeclares ``sigma`` and
    ``learning_rate`` with its own default and meaning (and these bounds: ``metadata``, see
    ``lifelong_evo.options``)."""

    hidden: tuple[int, ...] = field(default=(16,), metadata={"min": 1, "max": 4096, "max_items": 16})
    """Hidden layer sizes of the MLP controller, e.g. [32,16] ([]: none, a linear controller)."""
    sigma: float = field(default=0.1, metadata={"above": 0, "max": 1000})
    """Initial standard deviation of the search distribution."""
    learning_rate: float = field(default=1.0, metadata={"above": 0, "max": 1000})
    """Learning rate of the search distribution's centre."""
    reference: Reference = "centre"
    """The regulariser's reference, taken at each task end: the centre, or the task's best controller."""
    importance: Importance = "l2"
    """The regulariser's weight per parameter: all 1 (l2), or estimated from the search (ewc); a synonym
    of --regulariser l2 or ewc."""

    def __post_init__(self):
        object.__setattr__(self, "hidden", tuple(self.hidden))
        super().__post_init__()
        if not all(isinstance(h, numbers.Integral) and not isinstance(h, bool) and h >= 1 for h in self.hidden):
            raise ValueError(f"hidden must list integers >= 1 (the layer sizes), got {list(self.hidden)}")
        for name in ("sigma", "learning_rate"):
            value = getattr(self, name)
            if not (isinstance(value, numbers.Real) and math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a number > 0, got {value!r}")


class ESOptimizer(Optimizer):
    """Shared ask/tell adapter for an ES over ``MLPPolicy`` controllers.

    ``population_size`` is the number of samples per generation; ``ask()`` returns them plus the
    distribution centre as the last controller, so ``self.population_size`` is one more.
    ``options``: the fields of the algorithm's ``Options`` (``ESOptions`` with its defaults;
    ``reference`` and ``importance``: see ``algorithms.regularizers``). The search distribution
    starts centred at the zero vector (all controller outputs 0.5).

    ``diagnostics``: the mean and standard deviation over the asked controllers of the
    regulariser's distance to the reference (``Regularizer.distances``; NaN before the first
    ``end_task``), logged for every lambda, 0 included, so a grid over lambda can be read against
    the spread of fitness it has to compete with.
    """

    Options: ClassVar[type[ESOptions]] = ESOptions
    diagnostics: ClassVar[tuple[str, ...]] = ("distance_mean", "distance_std")
    regularizer_options: ClassVar[tuple[str, ...]] = ("reference", "importance")
    regularisers: ClassVar[dict[str, dict[str, Any]]] = {"l2": {"importance": "l2"}, "ewc": {"importance": "ewc"},
                                                         FUNCTIONAL: {}}
    # after_first_task_options: none. The reference (centre or best) is what the first end_task
    # keeps, and importance=ewc gathers its sensitivities during the task: a run's state at the
    # first task's end differs with either
    even_population: ClassVar[bool] = False
    """Mirrored sampling needs an even number of samples."""

    @classmethod
    def check_population(cls, population_size: int, options: ESOptions | None = None) -> None:
        if population_size < 2:
            raise ValueError(f"{cls.name} needs at least 2 samples per generation, got {population_size}")
        if cls.even_population and population_size % 2:
            raise ValueError(f"{cls.name} samples mirrored pairs: the population must be even, got {population_size}")

    @classmethod
    def memory_needs(cls, population_size: int, obs_dim: int, options: ESOptions) -> tuple[int, int]:
        # measured (docs/usage.md, Memory): about 4 float32 copies of the samples (EvoTorch's, the
        # asked population, the gradient's), and a few of each hidden activation
        d = n_parameters(layer_sizes_for(obs_dim, options.hidden))
        return 16 * (population_size + 1) * d, 16 * (sum(options.hidden) + 3)

    def __init__(self, *, obs_dim: int, population_size: int = 300, seed: int,
                 reg: float = 0.0, device: str | torch.device = "cpu", **options):
        self.options = self.Options(**options)
        self.layer_sizes = layer_sizes_for(obs_dim, self.options.hidden)
        self.n_parameters = n_parameters(self.layer_sizes)
        self.n_samples = int(population_size)
        self.check_population(self.n_samples, self.options)
        self.sigma_init = float(self.options.sigma)
        self.learning_rate = float(self.options.learning_rate)
        self.device = torch.device(device)
        self.seed = int(seed)
        self.regularizer = Regularizer(reg, n_parameters=self.n_parameters,
                                       reference=self.options.reference, importance=self.options.importance,
                                       device=self.device)
        centre_init = torch.zeros(self.n_parameters, dtype=torch.float32, device=self.device)
        with _quiet_evotorch(), portable_update():
            self.problem = TellProblem(self.n_parameters, seed=self.seed, device=self.device)
            self.searcher = self._make_searcher(centre_init)
        self.centre_index = self.n_samples
        self.generation = 0
        self._population: torch.Tensor | None = None  # last asked (N + 1, n_parameters)
        self._pending = False  # asked, not yet told

    # ---- what each algorithm provides -------------------------------------------------------
    def _make_searcher(self, centre_init: torch.Tensor):
        raise NotImplementedError

    def _sample(self) -> torch.Tensor:
        """Draw ``(n_samples, n_parameters)`` samples (may keep what ``_update`` needs)."""
        raise NotImplementedError

    def _update(self, selection_fitness: torch.Tensor) -> dict[str, float]:
        """Apply the library's update for the samples' selection fitness; report scalars."""
        raise NotImplementedError

    @property
    def centre(self) -> torch.Tensor:
        """The search distribution's current centre (1-D)."""
        raise NotImplementedError

    def _move_centre(self, centre: torch.Tensor) -> None:
        """Make ``centre`` the search distribution's centre, leaving everything else as it is."""
        raise NotImplementedError

    def search_variance(self) -> torch.Tensor | None:
        """Per-coordinate variance for the EWC importance (CMA-ES); ``None``: use the Fisher diagonal."""
        return None

    def _searcher_state(self) -> dict[str, Any]:
        raise NotImplementedError

    def _load_searcher_state(self, state: dict[str, Any]) -> None:
        raise NotImplementedError

    def _pending_state(self) -> dict[str, Any]:
        return {}

    def _load_pending_state(self, state: dict[str, Any]) -> None:
        pass

    # ---- the Optimizer interface --------------------------------------------------------------
    @property
    def population_size(self) -> int:
        return self.n_samples + 1

    def ask(self) -> MLPPolicy:
        """The samples and, last, the centre; asking again before ``tell`` returns the same ones."""
        if not self._pending:
            with portable_update():
                samples = self._sample()
            self._population = torch.cat([samples, self.centre.detach().unsqueeze(0)], dim=0)
            self._pending = True
        return MLPPolicy(self._population, self.layer_sizes)

    def regularise(self, fitness: torch.Tensor) -> torch.Tensor:
        if self._population is None:
            raise RuntimeError("regularise() needs an asked population: call ask() first")
        self._check_fitness(fitness, "fitness")
        with portable_update():
            return self.regularizer(fitness, self._population)

    def tell(self, fitness: torch.Tensor, selection_fitness: torch.Tensor) -> GenerationReport:
        if not self._pending:
            raise RuntimeError("tell() without a pending ask(): call ask() first")
        self._check_fitness(fitness, "fitness")
        self._check_fitness(selection_fitness, "selection_fitness")
        if not bool(torch.isfinite(selection_fitness).all()):
            raise ValueError("selection_fitness has non-finite values")
        sel = selection_fitness.detach().to(self.device, torch.float32)
        with portable_update():
            self.regularizer.observe(self._population, sel)
            distances = self.regularizer.distances(self._population)
            extra = {"distance_mean": math.nan if distances is None else distances.mean().item(),
                     "distance_std": math.nan if distances is None else distances.std(unbiased=False).item(),
                     **self._update(sel[:self.n_samples])}
        self._pending = False
        self.generation += 1
        return GenerationReport(extra=extra)

    def end_task(self) -> None:
        with portable_update():
            self.regularizer.end_task(self.centre, self.search_variance())

    def adopt(self, exported: dict[str, Any]) -> None:
        """Move the search distribution's centre to the exported controller (``export``); its
        spread (step size, variances or covariance, CMA-ES's evolution paths) and the centre
        optimiser's state stay as they are. The next ``ask`` samples around it and returns it as
        the centre."""
        if self._pending:
            raise RuntimeError("adopt() goes between tell() and the next ask()")
        check_export(exported, self.layer_sizes[0])
        if list(exported["layer_sizes"]) != list(self.layer_sizes):
            raise ValueError(f"the controller has layer sizes {exported['layer_sizes']}, this optimiser "
                             f"{list(self.layer_sizes)}")
        self._move_centre(torch.tensor(exported["parameters"], dtype=torch.float32, device=self.device))

    def reference_export(self) -> dict[str, Any] | None:
        """The regulariser's reference (the centre, or the task's best: ``reference``), as ``export``
        writes a controller."""
        reference = self.regularizer.reference
        return None if reference is None else {"layer_sizes": list(self.layer_sizes),
                                               "parameters": reference.detach().cpu().tolist()}

    def export(self, index: int) -> dict[str, Any]:
        if self._population is None:
            raise RuntimeError("export() needs an asked population: call ask() first")
        index = int(index)
        if not 0 <= index < self.population_size:
            raise IndexError(f"controller index {index} not in [0, {self.population_size})")
        return {"layer_sizes": list(self.layer_sizes),
                "parameters": self._population[index].detach().cpu().tolist()}

    def state_dict(self) -> dict[str, Any]:
        """Tensors and plain values only (loads with ``torch.load(weights_only=True)``)."""
        return {
            "format": STATE_FORMAT, "algorithm": self.name, "layer_sizes": list(self.layer_sizes),
            "n_samples": self.n_samples, "generation": self.generation,
            "rng_state": self.problem.generator.get_state().clone(),
            "population": None if self._population is None else self._population.clone(),
            "pending": self._pending,
            "pending_state": self._pending_state() if self._pending else {},
            "searcher": self._searcher_state(),
            "regularizer": self.regularizer.state_dict(),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        if state.get("format") != STATE_FORMAT:
            raise ValueError(f"unknown ES state format {state.get('format')!r}")
        for key, mine in (("algorithm", self.name), ("layer_sizes", list(self.layer_sizes)),
                          ("n_samples", self.n_samples)):
            theirs = list(state[key]) if key == "layer_sizes" else state[key]
            if theirs != mine:
                raise ValueError(f"checkpoint has {key}={theirs!r}, this optimiser {mine!r}")
        self.generation = int(state["generation"])
        self.problem.generator.set_state(state["rng_state"].cpu())
        pop = state["population"]
        self._population = None if pop is None else pop.to(self.device, torch.float32).clone()
        self._pending = bool(state["pending"])
        self._load_searcher_state(state["searcher"])
        if self._pending:
            self._load_pending_state(state["pending_state"])
        self.regularizer.load_state_dict(state["regularizer"])

    # ---- helpers ------------------------------------------------------------------------------
    def _check_fitness(self, values: torch.Tensor, what: str) -> None:
        if not isinstance(values, torch.Tensor) or values.shape != (self.population_size,):
            shape = tuple(values.shape) if isinstance(values, torch.Tensor) else type(values).__name__
            raise ValueError(f"{what} must be a tensor of shape ({self.population_size},), got {shape}")

    def _tensor(self, t: torch.Tensor) -> torch.Tensor:
        return t.detach().to(self.device, torch.float32).clone()


def optimizer_state(optimizer) -> dict[str, Any] | None:
    """The mutable state of an EvoTorch centre optimiser (Adam/SGD wrapper or ClipUp)."""
    if optimizer is None:
        return None
    if isinstance(optimizer, TorchOptimizer):
        return {"torch": optimizer.contained_optimizer.state_dict()}
    if isinstance(optimizer, ClipUp):
        return {"clipup_velocity": optimizer._velocity.clone()}
    raise TypeError(f"cannot checkpoint optimiser {type(optimizer).__name__}")


def load_optimizer_state(optimizer, state: dict[str, Any] | None) -> None:
    if optimizer is None or state is None:
        if (optimizer is None) != (state is None):
            raise ValueError("checkpoint and optimiser disagree on having a centre optimiser")
        return
    if isinstance(optimizer, TorchOptimizer):
        optimizer.contained_optimizer.load_state_dict(state["torch"])
    else:
        optimizer._velocity = state["clipup_velocity"].to(optimizer._velocity).clone()


class GaussianES(ESOptimizer):
    """Adapter for EvoTorch's separable-Gaussian searchers (``GaussianSearchAlgorithm``).

    Subclasses set ``searcher_class`` and return its keyword arguments from ``_searcher_options``.
    """

    searcher_class: ClassVar[type]

    def _searcher_options(self) -> dict[str, Any]:
        raise NotImplementedError

    def _make_searcher(self, centre_init):
        return self.searcher_class(self.problem, popsize=self.n_samples, center_init=centre_init,
                                   stdev_init=self.sigma_init, **self._searcher_options())

    @property
    def centre(self) -> torch.Tensor:
        return self.searcher._distribution.mu

    def _move_centre(self, centre):
        self.searcher._distribution = self.searcher._distribution.modified_copy(mu=centre)

    def _sample(self) -> torch.Tensor:
        out = torch.empty(self.n_samples, self.n_parameters, dtype=torch.float32, device=self.device)
        return self.searcher._distribution.sample(out=out, generator=self.problem)

    def _update(self, selection_fitness):
        s = self.searcher
        dist = s._distribution
        samples = self._population[:self.n_samples]
        if self.regularizer.needs_sensitivity:
            self.regularizer.observe_gaussian(samples, dist.mu, dist.sigma, selection_fitness)
        grads = dist.compute_gradients(samples, selection_fitness, objective_sense="max",
                                       ranking_method=s._ranking_method)
        s._update_distribution(grads)
        sigma = s._distribution.sigma
        return {"stdev_mean": float(sigma.mean()), "centre_step": float((s._distribution.mu - dist.mu).norm())}

    def _searcher_state(self):
        d = self.searcher._distribution
        return {"mu": d.mu.clone(), "sigma": d.sigma.clone(), "optimizer": optimizer_state(self.searcher._optimizer)}

    def _load_searcher_state(self, state):
        s = self.searcher
        s._distribution = s._distribution.modified_copy(mu=self._tensor(state["mu"]), sigma=self._tensor(state["sigma"]))
        load_optimizer_state(s._optimizer, state["optimizer"])

