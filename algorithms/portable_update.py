"""Portable arithmetic for the evolution strategies' own computations (EvoTorch's updates and
sampling, the regularisers): ``portable_update()``, a torch function mode under which they give
the same bits on any x86-64 CPU, whatever ATen's dispatch (scalar, AVX2, AVX-512) and the thread
count.

Why: EvoTorch's updates sum over the population and over the parameters (``sum``, ``mean``,
``norm``), take ``exp``, ``log`` and square roots, rank with an unstable sort, and move Adam's
moments with ``lerp_``, ``addcmul_`` and ``addcdiv_``. ATen sums in an order that follows the
vector width, computes ``exp`` and ``log`` with vectorised approximations in a tensor's body and
the C library in its tail, may fuse a multiply and an add in one kernel and not in another, and
orders equal fitnesses as its sort goes. Each changes a last bit; an evolution turns one into
another population.

What the mode does instead, each built from IEEE's correctly rounded operations on whole tensors
(elementwise ``+ - * /``, which no vector width changes) and the C library's double-precision
functions on Python floats:

- ``sum``, ``mean`` and ``norm`` (p = 2) of floating tensors: float64 partial sums in a fixed
  pairwise order (halves added elementwise), rounded once to the input's type;
- ``exp``, ``log`` and ``pow`` with an exponent other than 2: each element in double precision
  (Python's ``math``), rounded to the input's type; ``sqrt`` and ``pow(x, 0.5)``: correctly
  rounded (``envs.numerics.sqrt``);
- ``topk``, ``sort`` and ``argsort``: stable, so equal values keep their index order;
- ``lerp_``, ``addcmul_``, ``addcdiv_`` and ``add``/``sub`` with an ``alpha``: as separate
  multiplications and additions, never fused;
- ``normal_`` into float32 (EvoTorch's sampling): drawn in float64 and rounded (ATen draws
  float32 normals with a vectorised formula on AVX2 and another without; ``torch.randn`` is not
  replaced, so ``strict_update`` refuses it).

Any other function passes through unchanged: ``STRICT`` names the ones known to be exact
elementwise operations or bookkeeping, and ``strict_update()`` (tests) refuses the rest, so a
new optimiser's update that calls an unlisted function shows it. Under ``--numerics native``
none of this applies (``envs.numerics.native()``)."""
from __future__ import annotations

import math
from contextlib import nullcontext
from typing import Any, Callable

import torch
from torch.overrides import TorchFunctionMode

from envs import numerics

T = torch.Tensor


def fixed_order_sum(x: T, dim: int | tuple[int, ...] | None = None, keepdim: bool = False) -> T:
    """The sum of ``x`` over ``dim`` (all when None) as float64 pairwise sums in a fixed order,
    rounded to ``x``'s dtype."""
    dims = tuple(range(x.dim())) if dim is None else ((dim,) if isinstance(dim, int) else tuple(dim))
    dims = tuple(sorted(d % max(x.dim(), 1) for d in dims))
    kept = [d for d in range(x.dim()) if d not in dims]
    values = x.to(torch.float64).permute(*dims, *kept) if x.dim() else x.to(torch.float64).reshape(1)
    values = values.reshape(-1, *[x.shape[d] for d in kept])
    if values.shape[0] == 0:
        total = torch.zeros(values.shape[1:], dtype=torch.float64, device=x.device)
    else:
        while values.shape[0] > 1:
            half = values.shape[0] // 2
            paired = values[:half] + values[half:2 * half]
            values = torch.cat([paired, values[2 * half:]]) if values.shape[0] % 2 else paired
        total = values[0]
    if keepdim:
        for d in dims:
            total = total.unsqueeze(d)
    return total.to(x.dtype)


def _elementwise(x: T, function: Callable[[float], float]) -> T:
    """``function`` of each element in double precision, rounded to ``x``'s floating dtype (torch's
    default one for an integer ``x``, as ``torch.exp`` and ``torch.log`` do)."""
    values = [function(v) for v in x.detach().to(torch.float64).reshape(-1).tolist()]
    dtype = x.dtype if x.is_floating_point() else torch.get_default_dtype()
    return torch.tensor(values, dtype=torch.float64, device=x.device).reshape(x.shape).to(dtype)


def _log(v: float) -> float:
    return math.log(v) if v > 0 else (-math.inf if v == 0 else math.nan)


def _sum(x: T, dim=None, keepdim: bool = False, *, dtype=None) -> T:
    x = x if dtype is None else x.to(dtype)
    return fixed_order_sum(x, dim, keepdim)


def _mean(x: T, dim=None, keepdim: bool = False, *, dtype=None) -> T:
    x = x if dtype is None else x.to(dtype)
    total = fixed_order_sum(x, dim, keepdim)
    count = x.numel() // max(total.numel(), 1)
    return (total.to(torch.float64) / count).to(x.dtype)


def _std(x: T, dim=None, unbiased: bool | None = None, keepdim: bool = False, *, correction=None) -> T:
    if isinstance(dim, bool):  # std(unbiased) without a dimension
        dim, unbiased = None, dim
    correction = correction if correction is not None else (0 if unbiased is False else 1)
    values = x.to(torch.float64)
    total = fixed_order_sum(values, dim, keepdim=True)
    count = values.numel() // max(total.numel(), 1)
    deviations = values - total / count
    spread = fixed_order_sum(deviations * deviations, dim, keepdim) / max(count - correction, 0)
    return torch.sqrt(spread).to(x.dtype)


def _norm(x: T, p: Any = "fro", dim=None, keepdim: bool = False, out=None, dtype=None) -> T:
    if p not in ("fro", 2, 2.0) or dtype is not None or out is not None:
        raise NotImplementedError(f"portable_update: norm with p={p!r}, dtype={dtype!r}")
    squares = x.to(torch.float64) * x.to(torch.float64)
    return torch.sqrt(fixed_order_sum(squares, dim, keepdim)).to(x.dtype)


def _pow(x: T, exponent: Any) -> T:
    if isinstance(exponent, torch.Tensor):
        raise NotImplementedError("portable_update: pow with a tensor exponent")
    if exponent == 2:
        return x * x
    if exponent == 1:
        return x.clone()
    if exponent == 0.5:
        return numerics.sqrt(x) if x.dtype == torch.float32 else torch.sqrt(x)
    if not x.is_floating_point():  # an integer tensor's power stays an integer tensor (exact)
        return torch.pow(x, exponent)
    return _elementwise(x, lambda v: math.pow(v, exponent))


def _topk(x: T, k: int, dim: int = -1, largest: bool = True, sorted: bool = True):
    order = torch.argsort(x, dim=dim, descending=largest, stable=True).narrow(dim, 0, k)
    return torch.return_types.topk((torch.gather(x, dim, order), order))


def _argsort(x: T, dim: int = -1, descending: bool = False, stable: bool = False) -> T:
    return torch.argsort(x, dim=dim, descending=descending, stable=True)


def _sort(x: T, dim: int = -1, descending: bool = False, stable: bool = False):
    return torch.sort(x, dim=dim, descending=descending, stable=True)


def _lerp_(self: T, end: T, weight: Any) -> T:
    """ATen's formula, unfused: ``self + w (end - self)`` for |w| < 0.5, else ``end - (end - self)(1 - w)``."""
    weight = torch.as_tensor(weight, dtype=self.dtype, device=self.device)
    difference = end - self
    return self.copy_(torch.where(weight.abs() < 0.5, self + weight * difference, end - difference * (1 - weight)))


def _addcmul_(self: T, tensor1: T, tensor2: T, *, value: Any = 1) -> T:
    return self.copy_(self + value * (tensor1 * tensor2))


def _addcdiv_(self: T, tensor1: T, tensor2: T, *, value: Any = 1) -> T:
    return self.copy_(self + value * (tensor1 / tensor2))


def _add(function: Callable, x: T, other: Any, *, alpha: Any = 1, out=None) -> T:
    if alpha in (1, -1) or out is not None:
        return function(x, other, alpha=alpha) if out is None else function(x, other, alpha=alpha, out=out)
    return function(x, other * alpha if isinstance(other, torch.Tensor) else other * alpha)


def _normal_(x: T, mean: float = 0.0, std: float = 1.0, *, generator=None) -> T:
    if x.dtype != torch.float32:
        return torch.Tensor.normal_(x, mean, std, generator=generator)
    drawn = torch.empty(x.shape, dtype=torch.float64, device=x.device).normal_(mean, std, generator=generator)
    return x.copy_(drawn)


REPLACED: dict[Callable, Callable] = {
    torch.sum: _sum, T.sum: _sum, torch.mean: _mean, T.mean: _mean, torch.norm: _norm, T.norm: _norm,
    torch.std: _std, T.std: _std,
    torch.exp: lambda x: _elementwise(x, math.exp), T.exp: lambda x: _elementwise(x, math.exp),
    torch.log: lambda x: _elementwise(x, _log), T.log: lambda x: _elementwise(x, _log),
    torch.sqrt: lambda x: numerics.sqrt(x), T.sqrt: lambda x: numerics.sqrt(x),
    torch.pow: _pow, T.pow: _pow, T.__pow__: _pow,
    torch.topk: _topk, T.topk: _topk, torch.argsort: _argsort, T.argsort: _argsort, torch.sort: _sort,
    T.sort: _sort, T.lerp_: _lerp_, T.addcmul_: _addcmul_, T.addcdiv_: _addcdiv_,
    torch.add: lambda *a, **k: _add(torch.add, *a, **k), T.add: lambda *a, **k: _add(T.add, *a, **k),
    T.add_: lambda *a, **k: _add(T.add_, *a, **k), torch.sub: lambda *a, **k: _add(torch.sub, *a, **k),
    T.sub: lambda *a, **k: _add(T.sub, *a, **k), T.sub_: lambda *a, **k: _add(T.sub_, *a, **k),
    T.normal_: _normal_,
}
"""The functions ``portable_update`` computes otherwise (module docstring)."""


class _PortableUpdate(TorchFunctionMode):
    def __init__(self, strict: bool = False):
        super().__init__()
        self.strict = strict

    def __torch_function__(self, func, types, args=(), kwargs=None):
        kwargs = kwargs or {}
        replacement = REPLACED.get(func)
        if replacement is not None:
            return replacement(*args, **kwargs)
        if self.strict and func not in STRICT and not _bookkeeping(func):
            raise NotImplementedError(f"portable_update: {getattr(func, '__qualname__', func)} is not known to be exact")
        return func(*args, **kwargs)


def _bookkeeping(func: Callable) -> bool:
    """Attribute reads and writes, and the profiler's marks (``torch.optim``'s steps make them)."""
    name = getattr(func, "__name__", "") or ""
    return name in ("__get__", "__set__") or "record_function" in name or "_RecordFunction" in name


def portable_update():
    """The context under which an optimiser computes its update, samples and regularises: the
    portable arithmetic above, or nothing under ``--numerics native``."""
    return nullcontext() if numerics.native() else _PortableUpdate()


def strict_update():
    """``portable_update`` that raises NotImplementedError for a function neither replaced nor in
    ``STRICT`` (tests: an update that calls one may give other bits on another CPU)."""
    return _PortableUpdate(strict=True)


def _names(owner: Any, names: str) -> set:
    return {getattr(owner, name) for name in names.split()}


STRICT: set = (
    _names(T, "__add__ __radd__ __iadd__ __sub__ __rsub__ __isub__ __mul__ __rmul__ __imul__ __truediv__ "
              "__rtruediv__ __itruediv__ __neg__ __abs__ __lt__ __le__ __gt__ __ge__ __eq__ __ne__ __and__ __or__ "
              "__invert__ __getitem__ __setitem__ __bool__ __float__ __int__ __index__ __len__ __iter__ __format__ "
              "__repr__ __contains__ __array__ __array_wrap__ __reduce_ex__ __deepcopy__ __rdiv__ __div__ "
              "mul mul_ div div_ neg abs abs_ where clamp clamp_ clamp_min clamp_max minimum maximum sign "
              "lt le gt ge eq ne logical_and logical_or logical_not isfinite isnan isinf all any "
              "argmax argmin max min floor ceil round trunc "
              "clone detach detach_ to cpu cuda contiguous copy_ fill_ zero_ fill_diagonal_ requires_grad_ "
              "reshape view view_as flatten unsqueeze squeeze expand expand_as movedim permute t transpose narrow "
              "index_select gather masked_fill masked_fill_ repeat diagonal numel dim size item tolist numpy "
              "float double long int bool type type_as new_zeros new_ones new_empty new_tensor new_full "
              "uniform_ random_ dtype device shape is_complex is_floating_point data_ptr")
    | _names(torch, "mul div neg abs where clamp minimum maximum sign lt le gt ge eq ne logical_and logical_or "
                    "logical_not isfinite isnan isinf all any argmax argmin max min floor ceil round trunc "
                    "clone cat stack reshape flatten unsqueeze squeeze movedim permute narrow index_select gather "
                    "zeros ones full empty zeros_like ones_like full_like empty_like arange tensor as_tensor "
                    "randint rand broadcast_tensors outer diagonal result_type is_complex device")
    | {torch._C._set_grad_enabled}
)
"""The functions known to be exact elementwise operations (or no arithmetic at all), which
``strict_update`` lets through, besides attribute reads and writes and the profiler's marks. ``outer`` is one product per element; ``rand``/``randint`` and
``uniform_`` draw the same bits under every dispatch."""
