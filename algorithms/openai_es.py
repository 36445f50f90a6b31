"""OpenAI-ES: Salimans, Ho, Chen, Sidor & Sutskever (2017), "Evolution Strategies as a Scalable
Alternative to Reinforcement Learning", arXiv:1703.03864.

A fixed isotropic Gaussian (``sigma``, default 0.1) with mirrored sampling, centred-rank fitness
shaping, and Adam (Kingma & Ba 2015) on the centre with step size ``learning_rate``
(default 0.03). EvoTorch has no class of that name; its ``PGPE`` with ``optimizer="adam"``,
``stdev_learning_rate=0``, ``ranking_method="centered"`` and ``symmetric=True`` is exactly this
method. (The paper's L2 weight decay is left out.)
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from evotorch.algorithms import PGPE as _EvoPGPE

from .es import ESOptions, GaussianES


class OpenAIES(GaussianES):
    """OpenAI-ES (see the module docstring)."""

    name: ClassVar[str] = "openai-es"
    searcher_class = _EvoPGPE
    even_population = True

    @dataclass(frozen=True)
    class Options(ESOptions):
        sigma: float = 0.1
        """Standard deviation of the search distribution (fixed)."""
        learning_rate: float = 0.03
        """Adam's step size for the centre."""

    def _searcher_options(self):
        return {"center_learning_rate": self.learning_rate, "stdev_learning_rate": 0.0,
                "optimizer": "adam", "ranking_method": "centered", "symmetric": True,
                "stdev_max_change": None}
