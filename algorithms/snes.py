"""SNES: Schaul, Glasmachers & Schmidhuber (2011), "High Dimensions and Heavy Tails for Natural
Evolution Strategies", GECCO 2011. EvoTorch's ``SNES``: separable natural evolution strategy with
NES utilities, a multiplicative (exponential) per-parameter standard-deviation update at the
default rate ``0.2 (3 + ln n) / sqrt(n)``.

``sigma``: initial standard deviation (default 0.5); ``learning_rate``: the centre's learning
rate (default 1, the paper's).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from evotorch.algorithms import SNES as _EvoSNES

from .es import ESOptions, GaussianES


class SNES(GaussianES):
    """SNES (see the module docstring)."""

    name: ClassVar[str] = "snes"
    searcher_class = _EvoSNES

    @dataclass(frozen=True)
    class Options(ESOptions):
        sigma: float = 0.5
        """Initial standard deviation of the search distribution (adapted per parameter)."""
        learning_rate: float = 1.0
        """Learning rate of the centre (1: the paper's)."""

    def _searcher_options(self):
        return {"center_learning_rate": self.learning_rate}
