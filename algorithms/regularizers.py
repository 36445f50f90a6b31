"""The regulariser shared by every evolution strategy: an EWC-style quadratic pull towards the
controller of the previous task.

Regularised (selection) fitness of a controller with flat parameters ``theta`` (length ``n``)::

    f_reg(theta) = f(theta) - lambda * (1/n) * sum_i w_i * (theta_i - ref_i)^2

(the mean over parameters, so that ``lambda`` means the same for any network size). This is the
penalty of Elastic Weight Consolidation (Kirkpatrick et al., 2017, "Overcoming catastrophic
forgetting in neural networks", PNAS 114(13):3521-3526), ``lambda/2 * sum_i F_i (theta_i -
theta*_i)^2``, with the Fisher diagonal ``F`` replaced by the importance ``w`` below and the sum by
a mean; with ``w = 1`` it is the paper's genetic-distance penalty for a fixed topology.

* ``lambda = 0`` switches it off; before the first ``end_task()`` there is no reference and the
  penalty is zero (``f_reg = f``).
* Reference ``ref`` (taken at ``end_task()``, i.e. at the drift):
  ``"centre"``: the search distribution's centre at the end of the task that just ended;
  ``"best"``: the controller with the highest selection fitness seen during that task
  (the paper's choice for NEAT), falling back to the centre if none was told.
* Importance ``w`` (taken at the same moment, normalised to mean 1 so that ``lambda`` keeps its
  scale):
  ``"l2"``: ``w_i = 1``.
  ``"ewc"``: a diagonal importance per parameter from the search distribution of the task that
  just ended:

  - CMA-ES (full or separable): the precision of the search distribution,
    ``w_i ∝ 1 / (sigma^2 * C_ii)``; CMA-ES shrinks the variance along the directions where the
    fitness is most sensitive, so a small variance marks an important parameter.
  - Gaussian ESs (OpenAI-ES, PGPE, SNES): a Fisher-like sensitivity of the fitness, averaged
    over the last ``K = FISHER_WINDOW`` generations of the task. For one generation with samples
    ``x_j = mu + sigma * z_j`` (``j = 1..N``) and centred ranks ``u_j`` in ``[-0.5, 0.5]`` of their
    selection fitness (Salimans et al. 2017)::

        a_i = mean_j u_j * z_ji              (slope: E[u z_i]        = sigma_i * dJ/dmu_i)
        b_i = mean_j u_j * (z_ji^2 - 1)      (spread: E[u (z_i^2-1)] = sigma_i * dJ/dsigma_i)
        s_i = (a_i^2 + b_i^2 / 2) / sigma_i^2 = (dJ/dmu_i)^2 + (dJ/dsigma_i)^2 / 2

    where ``J(mu, sigma) = E[u]`` is the expected ranked fitness; ``a^2 + b^2/2`` is the squared
    norm of the gradient ``(dJ/dmu_i, dJ/dsigma_i)`` under the inverse Fisher information
    ``diag(sigma_i^2, sigma_i^2/2)`` of ``N(mu_i, sigma_i^2)``.
    ``w_i ∝ (1/K) * sum_k s_{k,i}``. The slope term marks parameters the fitness still climbs
    along; the spread term marks parameters at a peak (there the slope vanishes but widening the
    distribution along ``i`` costs fitness, ``b_i < 0``), which is what EWC's Fisher diagonal, an
    approximation of the loss curvature at the old optimum, measures. (The squared mean gradient
    alone vanishes at an optimum.)

  If an importance estimate is degenerate (all zero, or not finite), ``w = 1`` is used.
"""
from __future__ import annotations

from typing import Any, Literal, get_args

import torch
from evotorch.tools.ranking import rank

Reference = Literal["centre", "best"]
Importance = Literal["l2", "ewc"]
REFERENCES: tuple[str, ...] = get_args(Reference)
IMPORTANCES: tuple[str, ...] = get_args(Importance)
FISHER_WINDOW = 10
"""Generations whose sensitivities make the Gaussian ESs' Fisher-like importance."""


def penalty(params: torch.Tensor, reference: torch.Tensor, importance: torch.Tensor | None = None) -> torch.Tensor:
    """``mean_i w_i (theta_i - ref_i)^2`` for each row ``theta`` of ``params`` ``(N, n)``; ``(N,)``."""
    sq = (params - reference.to(params)) ** 2
    if importance is not None:
        sq = sq * importance.to(params)
    return sq.mean(dim=-1)


def regularised_fitness(fitness: torch.Tensor, params: torch.Tensor, reg: float,
                        reference: torch.Tensor | None, importance: torch.Tensor | None = None) -> torch.Tensor:
    """``fitness - reg * penalty(params, reference, importance)`` (``reg``: lambda); ``fitness``
    unchanged (a copy) when ``reg == 0`` or there is no reference yet."""
    if reg == 0 or reference is None:
        return fitness.clone()
    pen = penalty(params, reference, importance)
    return fitness - reg * pen.to(device=fitness.device, dtype=fitness.dtype)


def normalise_importance(w: torch.Tensor) -> torch.Tensor:
    """``w / mean(w)``; all ones if ``w`` is degenerate (non-finite, negative or all zero)."""
    w = w.detach().clone()
    mean = w.mean()
    if not bool(torch.isfinite(w).all()) or bool((w < 0).any()) or not float(mean) > 0:
        return torch.ones_like(w)
    return w / mean


def precision_importance(variance: torch.Tensor) -> torch.Tensor:
    """EWC importance from per-coordinate search variances (CMA-ES: ``sigma^2 * diag(C)``)."""
    return normalise_importance(1.0 / variance.clamp_min(torch.finfo(variance.dtype).tiny))


def gaussian_sensitivity(samples: torch.Tensor, mu: torch.Tensor, sigma: torch.Tensor,
                         fitness: torch.Tensor) -> torch.Tensor:
    """One generation's ``s_i = (a_i^2 + b_i^2 / 2) / sigma_i^2`` (module docstring) from the
    samples ``(N, n)`` of ``N(mu, diag(sigma^2))`` and their fitness ``(N,)`` (maximised)."""
    u = rank(fitness.to(samples.dtype), "centered", higher_is_better=True).unsqueeze(1)
    z = (samples - mu) / sigma
    a = (u * z).mean(dim=0)
    b = (u * (z * z - 1)).mean(dim=0)
    return (a * a + 0.5 * b * b) / (sigma * sigma)


class Regularizer:
    """Reference, importance and the bookkeeping to take them at a drift; see the module docstring.

    The optimiser calls ``observe`` after every generation and ``end_task(centre, ...)`` at a drift;
    ``__call__(fitness, params)`` gives the regularised fitness.
    """

    def __init__(self, reg: float, *, n_parameters: int, reference: str = "centre",
                 importance: str = "l2", device: str | torch.device = "cpu"):
        if reference == "center":
            reference = "centre"
        if reference not in REFERENCES:
            raise ValueError(f"reference must be one of {REFERENCES}, got {reference!r}")
        if importance not in IMPORTANCES:
            raise ValueError(f"importance must be one of {IMPORTANCES}, got {importance!r}")
        reg = float(reg)
        if not reg >= 0:
            raise ValueError(f"reg (lambda) must be >= 0, got {reg}")
        self.reg, self.reference_mode, self.importance_mode = reg, reference, importance
        self.n_parameters, self.device = int(n_parameters), torch.device(device)
        self.reference: torch.Tensor | None = None
        self.importance: torch.Tensor | None = None
        self.tasks_ended = 0
        # during a task: best controller by selection fitness; the last generations' sensitivities
        self.best_params: torch.Tensor | None = None
        self.best_fitness: float = float("-inf")
        self._sens = torch.zeros(FISHER_WINDOW, self.n_parameters, device=self.device)
        self._sens_count = 0

    def __call__(self, fitness: torch.Tensor, params: torch.Tensor) -> torch.Tensor:
        return regularised_fitness(fitness, params, self.reg, self.reference, self.importance)

    def distances(self, params: torch.Tensor) -> torch.Tensor | None:
        """``penalty`` of each row of ``params`` (the selection fitness loses ``reg`` times it),
        also when ``reg == 0``; ``None`` before the first ``end_task``."""
        return None if self.reference is None else penalty(params, self.reference, self.importance)

    @property
    def needs_sensitivity(self) -> bool:
        """Whether ``observe_gaussian`` is used (Gaussian ESs with ``importance="ewc"``)."""
        return self.importance_mode == "ewc"

    def observe(self, params: torch.Tensor, selection_fitness: torch.Tensor) -> None:
        """Track the best controller of the task (for ``reference="best"``)."""
        i = int(torch.argmax(selection_fitness))
        value = float(selection_fitness[i])
        if value > self.best_fitness:
            self.best_fitness = value
            self.best_params = params[i].detach().clone()

    def observe_gaussian(self, samples: torch.Tensor, mu: torch.Tensor, sigma: torch.Tensor,
                         fitness: torch.Tensor) -> None:
        """Record one generation's ``gaussian_sensitivity`` (kept for the last ``FISHER_WINDOW``)."""
        s = gaussian_sensitivity(samples.detach(), mu.detach(), sigma.detach(), fitness.detach())
        self._sens[self._sens_count % FISHER_WINDOW] = s.to(self._sens)
        self._sens_count += 1

    def fisher_diagonal(self) -> torch.Tensor | None:
        """Mean sensitivity over the last ``FISHER_WINDOW`` generations (``None`` if none)."""
        k = min(self._sens_count, FISHER_WINDOW)
        return None if k == 0 else self._sens[:k].mean(dim=0)

    def end_task(self, centre: torch.Tensor, variance: torch.Tensor | None = None) -> None:
        """Take the reference and importance at a drift.

        ``variance``: per-coordinate search variance (CMA-ES) for ``importance="ewc"``; if
        ``None`` the Fisher-like diagonal of the recorded sensitivities is used instead.
        """
        if self.reference_mode == "best" and self.best_params is not None:
            ref = self.best_params
        else:
            ref = centre
        self.reference = ref.detach().clone().to(self.device, torch.float32)
        if self.importance_mode == "l2":
            self.importance = None
        elif variance is not None:
            self.importance = precision_importance(variance.detach().to(self.device, torch.float32))
        else:
            fisher = self.fisher_diagonal()
            self.importance = (torch.ones(self.n_parameters, device=self.device) if fisher is None
                               else normalise_importance(fisher))
        self.tasks_ended += 1
        self.best_params, self.best_fitness = None, float("-inf")
        self._sens.zero_()
        self._sens_count = 0

    def state_dict(self) -> dict[str, Any]:
        return {"reference_mode": self.reference_mode,
                "importance_mode": self.importance_mode, "reference": self.reference,
                "importance": self.importance, "tasks_ended": self.tasks_ended,
                "best_params": self.best_params, "best_fitness": self.best_fitness,
                "sensitivity": self._sens.clone(), "sensitivity_count": self._sens_count}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        # lambda is the run's setting, not state: a run may start from the first task of one with
        # another lambda (the reference and the importance do not depend on it)
        for key in ("reference_mode", "importance_mode"):
            if state[key] != getattr(self, key):
                raise ValueError(f"checkpoint has regulariser {key}={state[key]!r}, "
                                 f"this optimiser {getattr(self, key)!r}")

        def dev(t):
            return None if t is None else t.to(self.device)

        self.reference, self.importance = dev(state["reference"]), dev(state["importance"])
        self.tasks_ended = int(state["tasks_ended"])
        self.best_params, self.best_fitness = dev(state["best_params"]), float(state["best_fitness"])
        self._sens = dev(state["sensitivity"]).clone()
        self._sens_count = int(state["sensitivity_count"])
