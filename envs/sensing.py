"""Tensor helpers of the arena's sensing and picking (the rules that use them: ``envs/foraging.py``).

``OrderKeys`` orders (distance, candidate) pairs as the spec's stable sort does, so that the nearest
candidates come out of ``amin`` reductions; ``distance`` is the one Euclidean distance of the
environment; ``one_hot_rows`` and ``batch_first`` build and lay out observation vectors. Every
helper works on whole batches (no Python loop over environments or agents) on any device.
"""
from __future__ import annotations

import functools
import math
from collections.abc import Sequence

import torch

from . import numerics


class OrderKeys:
    """Integer order keys for (distance, candidate index) pairs, so that ``amin`` finds the
    nearest candidate and its index in one vectorised reduction (``argmin``, ``topk`` and sorts
    are far slower).

    Candidates are numbered in the spec's sensing order (walls top, bottom, left, right, then
    other agents, then boxes). A key is the distance in fixed point, clamped to
    ``[low, high]`` and shifted to be >= 0, then shifted left by ``index_bits`` and or-ed with
    the candidate's number: equal distances order by number, as the spec's stable sort does.
    Distances closer than ``1 / scale`` (2**-22, about 2.4e-7 units, for the paper's arena)
    count as tied. Bit 30 marks a candidate absent (never sensed), above every present key.
    """

    def __init__(self, n_candidates: int, low: float, high: float):
        self.index_bits = max(1, (n_candidates - 1).bit_length())
        self.index_mask = (1 << self.index_bits) - 1
        self.low, self.high = low, high
        self.absent = 1 << 30
        room = (self.absent >> self.index_bits) - 1  # the largest fixed-point distance that fits
        self.scale = float(2 ** math.floor(math.log2(room / (high - low))))
        # the scale is a power of two: scaling is exact, so the shift by -low is exact too
        self.origin = math.ceil(-low * self.scale)

    def keys(self, dist: torch.Tensor, absent: torch.Tensor, first: int) -> torch.Tensor:
        """``dist``: (N, A, B) distances of candidates ``first .. first + N - 1``; ``absent``: bool,
        broadcastable to it. Returns (N, A, B) int32 keys."""
        number = torch.arange(first, first + dist.shape[0], dtype=torch.int32, device=dist.device)
        tag = number.view(-1, *([1] * (absent.dim() - 1))) | (absent.to(torch.int32) << 30)
        fixed = (dist.clamp(min=self.low, max=self.high) * self.scale).to(torch.int32) + self.origin
        return (fixed << self.index_bits) | tag

    def number(self, key: torch.Tensor) -> torch.Tensor:
        return key & self.index_mask

    def is_absent(self, key: torch.Tensor) -> torch.Tensor:
        return key >= self.absent

    @staticmethod
    def next_min(keys: torch.Tensor, previous: torch.Tensor) -> torch.Tensor:
        """The smallest key above ``previous``: keys <= previous wrap to the top under the
        sign flip, so one ``amin`` suffices (no masked copy)."""
        shifted = (keys - (previous + 1)) ^ torch.iinfo(torch.int32).min
        found = (shifted.amin(dim=0) ^ torch.iinfo(torch.int32).min) + previous + 1
        # none left above ``previous``: the wrap-around gives ``previous`` back; mark it absent
        return found | ((found <= previous).to(torch.int32) << 30)

    def smallest(self, groups: Sequence[torch.Tensor], n: int) -> torch.Tensor:
        """The ``n`` smallest keys over the candidate groups (each (N_g, A, B)): ``(n, A, B)``."""
        best = [functools.reduce(torch.minimum, [group.amin(dim=0) for group in groups])]
        for _ in range(n - 1):
            best.append(functools.reduce(torch.minimum, [self.next_min(group, best[-1]) for group in groups]))
        return torch.stack(best)


def distance(dx: torch.Tensor, dy: torch.Tensor) -> torch.Tensor:
    """Euclidean distance, correctly rounded (``numerics.sqrt``); every distance of the env goes
    through here, so equal inputs give equal floats wherever and however they are computed."""
    return numerics.sqrt(dx * dx + dy * dy)


def one_hot_rows(index: torch.Tensor, n_rows: int, dtype: torch.dtype) -> torch.Tensor:
    """``(n_rows, *index.shape[1:])`` with a 1 in row ``index[j]`` for every ``j``: a scatter, so
    that compiled code computes ``index`` once, not once per row."""
    rows = torch.zeros(n_rows, *index.shape[1:], dtype=dtype, device=index.device)
    return rows.scatter_(0, index.long(), 1.0)


def batch_first(features: torch.Tensor) -> torch.Tensor:
    """``(obs_dim, A, B)`` -> ``(B, A, obs_dim)``. Kept out of the compiled graph: torch's copy
    kernel transposes faster than the compiled loop, which also had to write ``features`` first."""
    return features.permute(2, 1, 0).contiguous()
