"""CMA-ES: Hansen & Ostermeier (2001), "Completely Derandomized Self-Adaptation in Evolution
Strategies", Evolutionary Computation 9(2); Hansen (2016), "The CMA Evolution Strategy: A Tutorial"
(arXiv:1604.00772). EvoTorch's ``CMAES`` (active CMA-ES, pycma-style defaults).

``sep-cmaes``: the separable variant (diagonal covariance), Ros & Hansen (2008), "A Simple
Modification in CMA-ES Achieving Linear Time and Space Complexity", PPSN X: ``CMAES(separable=True)``.

``sigma`` is the initial step size (default 0.5); ``learning_rate`` is ``c_m``, the learning rate
of the mean (default 1, the standard CMA-ES). Each generation's samples are ranked by selection
fitness with the default CMA-ES weights (``mu = popsize // 2``, negative weights for the rest).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import torch
from evotorch.algorithms import CMAES as _EvoCMAES

from .es import ESOptimizer, ESOptions
from .mlp import layer_sizes_for, n_parameters


class _AskTellCMAES(_EvoCMAES):
    """EvoTorch's CMA-ES, with two changes: ``step()`` reuses the samples handed out by ask, and
    the full covariance's rank-mu sum is one matmul.

    EvoTorch sums the weighted outer products ``w_i y_i y_i^T`` through a (popsize, d, d) tensor.
    ``Y^T diag(w) Y`` is the same sum as one matmul, without that tensor; only the order of the
    float additions differs (timings: docs/performance.md).
    """

    asked: tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None = None

    def sample_distribution(self, num_samples=None):
        if self.asked is not None:
            return self.asked
        return super().sample_distribution(num_samples)

    def update_C(self, zs, ys, assigned_weights, h_sig):
        if self.separable:
            return super().update_C(zs, ys, assigned_weights, h_sig)
        d = self._problem.solution_length
        if self.active:  # EvoTorch's own reweighting of the negative weights
            assigned_weights = torch.where(
                assigned_weights > 0, assigned_weights, d * assigned_weights / torch.norm(zs, dim=-1).pow(2.0))
        c1a = self.c_1 * (1 - (1 - h_sig**2) * self.c_c * (2 - self.c_c))
        weighted_pc = (self.c_1 / (c1a + 1e-23)) ** 0.5 * self.p_c
        r1_update = c1a * (torch.outer(weighted_pc, weighted_pc) - self.C)
        weighted_outer_sum = (assigned_weights.unsqueeze(-1) * ys).T @ ys
        weighted_outer_sum = (weighted_outer_sum + weighted_outer_sum.T) / 2  # exactly symmetric, as EvoTorch's sum is
        rmu_update = self.c_mu * (weighted_outer_sum - torch.sum(self.weights) * self.C)
        self.C = self.C + r1_update + rmu_update


class CMAES(ESOptimizer):
    """Full-covariance CMA-ES (see the module docstring)."""

    name: ClassVar[str] = "cmaes"
    separable: ClassVar[bool] = False

    @dataclass(frozen=True)
    class Options(ESOptions):
        sigma: float = 0.5
        """Initial step size."""
        learning_rate: float = 1.0
        """c_m, the learning rate of the mean (1: the standard CMA-ES)."""

    @classmethod
    def memory_needs(cls, population_size: int, obs_dim: int, options: ESOptions) -> tuple[int, int]:
        state, per_row = super().memory_needs(population_size, obs_dim, options)
        if cls.separable:
            return state, per_row
        # the covariance matrix, its eigendecomposition and the update's d x d terms: about 10
        # float32 copies, measured
        d = n_parameters(layer_sizes_for(obs_dim, options.hidden))
        return state + 40 * d * d, per_row

    def _make_searcher(self, centre_init):
        return _AskTellCMAES(self.problem, stdev_init=self.sigma_init, popsize=self.n_samples,
                             center_init=centre_init, c_m=self.learning_rate, separable=self.separable)

    @property
    def centre(self) -> torch.Tensor:
        return self.searcher.m

    def _move_centre(self, centre):
        self.searcher.m = centre

    def _sample(self):
        zs, ys, xs = self.searcher.sample_distribution()
        self._asked = (zs, ys, xs)
        return xs

    def _update(self, selection_fitness):
        s = self.searcher
        s.asked = self._asked
        self.problem.told = selection_fitness
        try:
            s.step()  # EvoTorch's own CMA-ES step on the asked samples and the told fitness
        finally:
            s.asked, self.problem.told, self._asked = None, None, None
        return {"sigma": float(s.sigma), "stdev_mean": float(self.search_variance().sqrt().mean())}

    def search_variance(self) -> torch.Tensor:
        s = self.searcher
        diag_c = s.C if self.separable else torch.diagonal(s.C)
        return s.sigma ** 2 * diag_c

    _STATE = ("m", "sigma", "C", "A", "p_sigma", "p_c")

    def _searcher_state(self) -> dict[str, Any]:
        s = self.searcher
        state = {k: getattr(s, k) for k in self._STATE}
        state = {k: v.clone() if isinstance(v, torch.Tensor) else float(v) for k, v in state.items()}
        state["steps_count"] = s._steps_count
        return state

    def _load_searcher_state(self, state):
        s = self.searcher
        for k in self._STATE:
            v = state[k]
            setattr(s, k, self._tensor(v) if isinstance(v, torch.Tensor) else float(v))
        s._steps_count = int(state["steps_count"])

    def _pending_state(self):
        zs, ys, _ = self._asked
        return {"zs": zs.clone(), "ys": ys.clone()}

    def _load_pending_state(self, state):
        self._asked = (self._tensor(state["zs"]), self._tensor(state["ys"]),
                       self._population[:self.n_samples].clone())


class SepCMAES(CMAES):
    """Separable CMA-ES: diagonal covariance, O(n) per sample instead of O(n^2)."""

    name: ClassVar[str] = "sep-cmaes"
    separable: ClassVar[bool] = True
