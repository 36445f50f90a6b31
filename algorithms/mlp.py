"""A fixed-topology MLP controller evaluated for a whole population in one batched computation.

Network: ``obs_dim -> hidden[0] -> ... -> hidden[-1] -> 3``; ``tanh`` on the hidden layers,
the logistic sigmoid on the 3 outputs (so outputs lie in ``[0, 1]``, as ``BatchedPolicy`` asks).

Flat parameter layout (``layer_sizes = (n_0, n_1, ..., n_L)``, ``n_0 = obs_dim``, ``n_L = 3``):
for each layer ``l = 1..L`` in order, the weight matrix ``W_l`` of shape ``(n_l, n_{l-1})``
(``(out, in)``, row-major, the ``torch.nn.Linear.weight`` layout), then its bias ``b_l`` of
length ``n_l``. Layer ``l`` computes ``act(x @ W_l.T + b_l)``, with the portable arithmetic of
``envs.numerics``: the product exact on its grid (inputs clipped to [-1, 1], weights to
[-128, 128]) and the activations from its tables, so a controller gives the same outputs on
every CPU. With the default ``(41, 16, 3)``
that is ``41*16 + 16 + 16*3 + 3 = 723`` parameters.

``check_export`` refuses what is not an exported MLP; ``mlp_network`` gives one as a drawing shows
it, its distance per layer to a reference.
"""
from __future__ import annotations

import functools
import math
from collections.abc import Sequence

import torch

from envs import numerics

from .base import ControllerNetwork, ExportError, is_integer, is_number, shown_value

N_OUTPUTS = 3
"""Controller outputs (one per wheel)."""


def layer_sizes_for(obs_dim: int, hidden: Sequence[int] = (16,)) -> tuple[int, ...]:
    """``(obs_dim, *hidden, 3)``, validated."""
    sizes = (int(obs_dim), *(int(h) for h in hidden), N_OUTPUTS)
    if any(s < 1 for s in sizes):
        raise ValueError(f"layer sizes must be positive integers, got {list(sizes)}")
    return sizes


def n_parameters(layer_sizes: Sequence[int]) -> int:
    """Length of the flat parameter vector for ``layer_sizes``."""
    sizes = [int(s) for s in layer_sizes]
    if len(sizes) < 2:
        raise ValueError(f"need at least an input and an output layer, got {sizes}")
    return sum(n_out * n_in + n_out for n_in, n_out in zip(sizes[:-1], sizes[1:]))


def unflatten(params: torch.Tensor, layer_sizes: Sequence[int]) -> list[tuple[torch.Tensor, torch.Tensor]]:
    """Views ``[(W_1, b_1), ...]`` into ``params`` of shape ``(..., n_parameters)``:
    ``W_l`` is ``(..., out, in)``, ``b_l`` is ``(..., out)``."""
    sizes = [int(s) for s in layer_sizes]
    expected = n_parameters(sizes)
    if params.shape[-1] != expected:
        raise ValueError(f"layer sizes {sizes} need {expected} parameters, got {params.shape[-1]}")
    layers, start = [], 0
    batch = params.shape[:-1]
    for n_in, n_out in zip(sizes[:-1], sizes[1:]):
        w = params[..., start:start + n_out * n_in].reshape(*batch, n_out, n_in)
        start += n_out * n_in
        b = params[..., start:start + n_out]
        start += n_out
        layers.append((w, b))
    return layers


class MLPPolicy:
    """``BatchedPolicy`` over ``P`` MLPs given as rows of ``params`` ``(P, n_parameters)``.

    ``policy(obs)`` maps ``(P, E, A, obs_dim)`` to ``(P, E, A, 3)``: controller ``p`` sees
    ``obs[p]``. Each layer is one exact batched product over ``(P, E*A, in)``
    (``numerics.exact_bmm``); runs on the device of ``params``.
    """

    def __init__(self, params: torch.Tensor, layer_sizes: Sequence[int]):
        if params.ndim != 2:
            raise ValueError(f"params must be (population, n_parameters), got shape {tuple(params.shape)}")
        self.layer_sizes = tuple(int(s) for s in layer_sizes)
        self.params = params
        self.population_size = int(params.shape[0])
        # (P, in, out) weights (contiguous for the native baddbmm, which is faster with a
        # contiguous right operand) and (P, 1, out) biases, once
        self._layers = [(w.transpose(1, 2).contiguous(), b.unsqueeze(1).contiguous())
                        for w, b in unflatten(params, self.layer_sizes)]

    @functools.cached_property
    def _grids(self) -> list[torch.Tensor]:
        """The weights on ``numerics.exact_bmm``'s grid, made at the first portable call."""
        return [numerics.grid_weights(w_t) for w_t, _ in self._layers]

    def __call__(self, observations: torch.Tensor) -> torch.Tensor:
        if observations.ndim != 4 or observations.shape[0] != self.population_size \
                or observations.shape[-1] != self.layer_sizes[0]:
            raise ValueError(
                f"observations must be (population={self.population_size}, envs, agents, "
                f"obs_dim={self.layer_sizes[0]}), got {tuple(observations.shape)}")
        p, e, a, d = observations.shape
        x = observations.to(self.params.dtype).reshape(p, e * a, d)
        last = len(self._layers) - 1
        native = numerics.native()
        for i, (w_t, b) in enumerate(self._layers):
            x = torch.baddbmm(b, x, w_t) if native else numerics.exact_bmm(x, self._grids[i], b)
            x = numerics.sigmoid(x) if i == last else numerics.tanh(x)
        return x.reshape(p, e, a, N_OUTPUTS)

    def shard(self, start: int, stop: int) -> "MLPPolicy":
        return MLPPolicy(self.params[start:stop], self.layer_sizes)

    @classmethod
    def from_export(cls, exported: dict, device: str | torch.device = "cpu") -> "MLPPolicy":
        """A one-controller policy from an ``export()`` dict (``layer_sizes``, ``parameters``);
        ExportError where it is not one (``check_export``)."""
        check_export(exported)
        params = torch.as_tensor(exported["parameters"], dtype=torch.float32, device=device).reshape(1, -1)
        return cls(params, exported["layer_sizes"])


def check_export(exported: dict, obs_dim: int | None = None) -> None:
    """ExportError unless ``exported`` is an MLP export: ``layer_sizes`` a list of at least two
    positive integers ending in ``N_OUTPUTS`` (and starting with ``obs_dim``, where given), and
    ``parameters`` a list of exactly ``n_parameters(layer_sizes)`` finite numbers."""
    sizes = exported.get("layer_sizes")
    if not isinstance(sizes, list) or len(sizes) < 2 or not all(is_integer(s) and s >= 1 for s in sizes):
        raise ExportError(f"layer_sizes is {shown_value(sizes)}, not a list of at least two positive integers")
    if sizes[-1] != N_OUTPUTS:
        raise ExportError(f"layer_sizes {sizes} ends in {sizes[-1]}, not in the {N_OUTPUTS} outputs of a controller")
    if obs_dim is not None and sizes[0] != obs_dim:
        raise ExportError(f"layer_sizes {sizes} takes {sizes[0]} inputs, not the arena's {obs_dim} observations")
    params = exported.get("parameters")
    if not isinstance(params, list):
        raise ExportError(f"parameters is {shown_value(params)}, not a list of numbers")
    bad = next((i for i, p in enumerate(params) if not is_number(p)), None)
    if bad is not None:
        raise ExportError(f"parameters[{bad}] is {shown_value(params[bad])}, not a finite number")
    if len(params) != n_parameters(sizes):
        raise ExportError(f"parameters has {len(params)} numbers, and layer_sizes {sizes} need {n_parameters(sizes)}")


def mlp_network(exported: dict, reference: dict | None = None) -> ControllerNetwork:
    """The exported MLP as a drawing shows it (``algorithms.network_from_export``): its layer sizes
    and, with a ``reference`` MLP, each layer's Euclidean distance (weights and biases) to the
    reference's and that of all its parameters. The regulariser's own penalty is not given: l2's
    is the squared distance over the parameter count, and ewc weighs each parameter by an
    importance that no file holds. ExportError where the two have other layer sizes."""
    sizes = tuple(exported["layer_sizes"])
    if reference is None:
        return ControllerNetwork(layer_sizes=sizes)
    if tuple(reference["layer_sizes"]) != sizes:
        raise ExportError(f"the reference has layer sizes {reference['layer_sizes']}, the controller {list(sizes)}")
    mine, theirs = (unflatten(torch.tensor(e["parameters"], dtype=torch.float64), sizes) for e in (exported, reference))
    distances = tuple(math.sqrt(((w - v) ** 2).sum().item() + ((b - c) ** 2).sum().item())
                      for (w, b), (v, c) in zip(mine, theirs))
    return ControllerNetwork(layer_sizes=sizes, layer_distances=distances,
                             measures=(("Euclidean distance", math.sqrt(sum(d * d for d in distances))),))
