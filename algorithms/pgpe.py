"""PGPE: Sehnke, Osendorfer, Rückstieß, Graves, Peters & Schmidhuber (2010), "Parameter-exploring
policy gradients", Neural Networks 23(4), with the ClipUp optimiser of Toklu, Liskowski &
Srivastava (2020), "ClipUp: A Simple and Powerful Optimizer for Distribution-based Policy
Evolution", PPSN XVI. EvoTorch's ``PGPE`` with its defaults: mirrored sampling, centred ranks,
adaptive per-parameter standard deviations (learning rate 0.1, at most 20% change per generation).

``sigma``: initial standard deviation (default 0.1); ``learning_rate``: ClipUp step size
(default 0.1, maximum speed twice that: ClipUp's suggested 0.1-0.3 range with sigma 0.1).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from evotorch.algorithms import PGPE as _EvoPGPE

from .es import ESOptions, GaussianES


class PGPE(GaussianES):
    """PGPE with ClipUp (see the module docstring)."""

    name: ClassVar[str] = "pgpe"
    searcher_class = _EvoPGPE
    even_population = True

    @dataclass(frozen=True)
    class Options(ESOptions):
        sigma: float = 0.1
        """Initial standard deviation of the search distribution (adapted per parameter)."""
        learning_rate: float = 0.1
        """ClipUp's step size for the centre (its maximum speed is twice that)."""

    def _searcher_options(self):
        return {"center_learning_rate": self.learning_rate, "stdev_learning_rate": 0.1,
                "optimizer": "clipup", "ranking_method": "centered", "symmetric": True,
                "stdev_max_change": 0.2}
