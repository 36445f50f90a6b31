"""Portable arithmetic: functions whose every result is the same bits on any x86-64 CPU, in
eager and in compiled code, whatever the batch size, the vector width of the kernels (ATen's
AVX2, AVX-512 or scalar dispatch) and the BLAS library's choices.

Why it is needed: torch's ``sin``, ``exp``, ``sigmoid``, ``tanh`` and even ``sqrt`` use vectorised
approximations in the body of a tensor and the C library in its tail, so one value rounds
differently by where it lies in the batch, by the CPU's vector width, and in compiled code
against eager; a matrix product sums in an order its BLAS picks by shape and by CPU vendor. A
lifelong run turns one such last-bit difference into another population.

What is used instead, each from IEEE's correctly rounded operations only (``+ - * /``, ``floor``,
``round``, conversions; compiled code contracts nothing, as inductor passes ``-ffp-contract=off``):

- ``sqrt``: the square root of a float32 in float64, rounded to float32: the correctly rounded
  float32 square root (float64 carries more than twice float32's precision).
- ``Table``: a function sampled on a grid (in pure Python floats, so the same everywhere) and
  interpolated linearly: ``sin_cos_degrees``, ``sigmoid`` (and ``tanh`` from it) are within about
  one float32 rounding of the exact function.
- ``exact_bmm``: a batched matrix product on a fixed-point grid (inputs in [-1, 1] on multiples of
  ``2**-INPUT_BITS``, weights in ``[-WEIGHT_LIMIT, WEIGHT_LIMIT]`` on multiples of
  ``2**-WEIGHT_BITS``), summed in float64, where every product and every partial sum of up to
  ``CHUNK_TERMS`` terms is an exact integer: any summation order gives the same sum (longer sums
  add their chunks in a fixed order).
- ``ordered_sum``: a sum of Python floats added left to right (Python 3.12's ``sum`` compensates
  its roundings, so the same floats sum to other last bits on 3.11 and on 3.12).

The module is shared by the arena and the built-in controllers (``algorithms``), and knows
nothing of either. ``use("native")`` switches both to torch's own functions (faster, with numbers
that follow the machine and the speed settings): the choice is the process's, made before a run
plays its first episode (``RunConfig.numerics``).
"""
from __future__ import annotations

import math
from typing import Callable, Iterable, Literal

import torch

Numerics = Literal["portable", "native"]
NUMERICS: tuple[str, ...] = ("portable", "native")
"""``portable``: this module's arithmetic, the same bits everywhere; ``native``: torch's own."""
_mode: str = "portable"


def use(mode: str) -> None:
    """Compute with ``mode`` (one of ``NUMERICS``) from now on in this process."""
    global _mode
    if mode not in NUMERICS:
        raise ValueError(f"numerics must be one of {', '.join(NUMERICS)}, got {mode!r}")
    _mode = mode


def mode() -> str:
    """The arithmetic this process computes with (``use``)."""
    return _mode


def native() -> bool:
    """Whether this process computes with torch's own functions (``use``)."""
    return _mode == "native"

INPUT_BITS = 20
"""Inputs of ``exact_bmm`` lie on multiples of 2**-20 (about 1e-6) in [-1, 1]."""
WEIGHT_BITS = 20
"""Weights of ``exact_bmm`` lie on multiples of 2**-20."""
WEIGHT_LIMIT = 128.0
"""Weights of ``exact_bmm`` are clipped to [-128, 128]: 2**7 * 2**20 * 2**20 = 2**47 bounds a product."""
CHUNK_TERMS = 2 ** 6
"""Terms summed exactly at once: every partial sum of 2**6 products is below 2**53, an integer
float64 holds exactly. Longer sums add these chunks' sums one after the other."""


def ordered_sum(values: Iterable[float]) -> float:
    """The sum of ``values`` added left to right, each addition rounded: what Python 3.11's
    ``sum`` computes, on every Python (the float sums that reach a run's numbers use it; this one
    does not depend on the arithmetic mode, as the Python version is no speed setting)."""
    total = 0
    for value in values:
        total = total + value
    return total


def ordered_mean(values: Iterable[float]) -> float:
    """``ordered_sum(values) / len(values)``; ZeroDivisionError for no values."""
    values = list(values)
    return ordered_sum(values) / len(values)


def sqrt(x: torch.Tensor) -> torch.Tensor:
    """The correctly rounded square root of float32 ``x`` (other dtypes: torch's own)."""
    if x.dtype != torch.float32 or native():
        return torch.sqrt(x)
    return torch.sqrt(x.to(torch.float64)).to(torch.float32)


class Table:
    """``function`` on ``[low, high]`` (both multiples of the step), sampled every
    ``2**-resolution_bits`` and interpolated linearly; outside the range, the value at the nearest
    end. The samples are computed with Python floats by ``function`` (which must use IEEE
    operations only, so that they are the same on every machine), then rounded to the table's
    dtype. An argument is only ever scaled by a power of two, never shifted, so no bit of it is
    lost on the way to its sample and fraction."""

    def __init__(self, function: Callable[[float], float], low: float, high: float, resolution_bits: int):
        self.low, self.high = float(low), float(high)
        self.scale = float(2 ** resolution_bits)
        self.first = int(self.low * self.scale)
        count = int(self.high * self.scale) - self.first
        self.samples = [function((self.first + i) / self.scale) for i in range(count + 2)]  # one past the end
        self._tensors: dict[tuple[torch.dtype, str], tuple[torch.Tensor, torch.Tensor]] = {}

    def tensors(self, dtype: torch.dtype, device: str) -> tuple[torch.Tensor, torch.Tensor]:
        """(values, differences to the next value) as ``dtype`` on ``device``, made once."""
        if (dtype, device) not in self._tensors:
            values = torch.tensor(self.samples, dtype=torch.float64).to(dtype)
            self._tensors[dtype, device] = values[:-1].to(device), (values[1:] - values[:-1]).to(device)
        return self._tensors[dtype, device]

    def __call__(self, x: torch.Tensor, shift: int = 0) -> torch.Tensor:
        """The function at ``x``, or at ``x + shift`` steps when ``x + shift`` steps lies in range."""
        values, slopes = self.tensors(x.dtype, str(x.device))
        position = x.clamp(self.low, self.high) * self.scale
        below = position.floor()
        fraction = position - below
        # the sample's number as a float (exact: an integer below 2**24), then int32: torch's int64
        # arithmetic and its gathers are several times slower than this on the CPU
        index = (below + float(shift - self.first)).to(torch.int32).view(-1)
        return values.index_select(0, index).view(x.shape) + fraction * slopes.index_select(0, index).view(x.shape)


def _sin_degrees(degrees: float) -> float:
    """sin of an angle in degrees by Taylor series after reduction to [-45, 45] degrees, in
    IEEE double operations only (``math.sin`` is the C library's, which may differ in the last
    bit between versions)."""
    quadrant = math.floor(degrees / 90.0 + 0.5)
    x = (degrees - 90.0 * quadrant) * (math.pi / 180.0)  # |x| <= pi / 4
    square = x * x
    sin_term, cos_term, sin_sum, cos_sum = x, 1.0, x, 1.0
    for k in range(1, 12):  # 11 terms: the remainder is below 1e-30
        sin_term = -sin_term * square / ((2 * k) * (2 * k + 1))
        cos_term = -cos_term * square / ((2 * k - 1) * (2 * k))
        sin_sum += sin_term
        cos_sum += cos_term
    return (sin_sum, cos_sum, -sin_sum, -cos_sum)[quadrant % 4]


LN2 = 0.6931471805599453
"""ln 2 rounded to a double (a literal: the C library's ``log`` is not needed)."""


def _exp(x: float) -> float:
    """exp by ``2**k * exp(r)``, ``|r| <= ln 2 / 2``, with a Taylor series for exp(r), in IEEE
    double operations only."""
    k = math.floor(x / LN2 + 0.5)
    r = x - k * LN2
    term, total = 1.0, 1.0
    for n in range(1, 20):
        term = term * r / n
        total += term
    return math.ldexp(total, k)


def _sigmoid(x: float) -> float:
    """The logistic function, exactly 0 and 1 from -``SIGMOID_RANGE`` and ``SIGMOID_RANGE`` on."""
    if abs(x) >= SIGMOID_RANGE:
        return 0.0 if x < 0 else 1.0
    return 1.0 / (1.0 + _exp(-x)) if x >= 0 else _exp(x) / (1.0 + _exp(x))


def _tanh(x: float) -> float:
    """tanh, exactly -1 and 1 from -``TANH_RANGE`` and ``TANH_RANGE`` on."""
    if abs(x) >= TANH_RANGE:
        return math.copysign(1.0, x)
    small = _exp(-2.0 * abs(x))
    return math.copysign((1.0 - small) / (1.0 + small), x)


SIN_DEGREES = Table(_sin_degrees, 0.0, 450.0, 6)
"""sin of an angle in [0, 450] degrees (cos is sin 90 degrees on), every 1/64 degree."""
SIGMOID_RANGE = 24.0
"""Beyond +-24, sigmoid is 0 or 1: sigmoid(-24) = 3.8e-11 is lost in 2 * out - 1 (a wheel's
speed) and in ``exact_bmm``'s input grid alike."""
SIGMOID = Table(_sigmoid, -SIGMOID_RANGE, SIGMOID_RANGE, 10)
"""The logistic function every 1/1024 on [-24, 24] (its ends exactly 0 and 1)."""
TANH_RANGE = 12.0
"""Beyond +-12, tanh is -1 or 1 (1 - tanh(12) = 7.6e-11)."""
TANH = Table(_tanh, -TANH_RANGE, TANH_RANGE, 10)
"""tanh every 1/1024 on [-12, 12] (its ends exactly -1 and 1)."""


def sin_cos_degrees(degrees: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(sin, cos) of angles in [0, 360] degrees (cos: the sine table 90 degrees on)."""
    if native():
        radians = torch.deg2rad(degrees)
        return torch.sin(radians), torch.cos(radians)
    return SIN_DEGREES(degrees), SIN_DEGREES(degrees, shift=int(90 * SIN_DEGREES.scale))


def sigmoid(x: torch.Tensor) -> torch.Tensor:
    """The logistic function: 0 from -``SIGMOID_RANGE`` down (-inf gives 0.0), 1 from ``SIGMOID_RANGE`` up."""
    return torch.sigmoid(x) if native() else SIGMOID(x)


def tanh(x: torch.Tensor) -> torch.Tensor:
    """tanh: -1 and 1 beyond ``TANH_RANGE``."""
    return torch.tanh(x) if native() else TANH(x)


def grid_weights(w: torch.Tensor) -> torch.Tensor:
    """Weights for ``exact_bmm``: clipped to ``WEIGHT_LIMIT`` and counted in steps of
    ``2**-WEIGHT_BITS``, as float64 integers (convert once per population, not per call)."""
    return torch.round(w.to(torch.float64).clamp(-WEIGHT_LIMIT, WEIGHT_LIMIT) * 2.0 ** WEIGHT_BITS)


GRID_UNIT = 2.0 ** -(INPUT_BITS + WEIGHT_BITS)
"""The value of 1 in a product of grid inputs and grid weights."""


def input_grid(x: torch.Tensor) -> torch.Tensor:
    """Inputs for an exact product: clipped to [-1, 1] and counted in steps of
    ``2**-INPUT_BITS``, as float64 integers."""
    return torch.round(x.clamp(-1.0, 1.0) * 2.0 ** INPUT_BITS).to(torch.float64)


def grid_bmm(left: torch.Tensor, right: torch.Tensor) -> torch.Tensor:
    """``left @ right`` for float64 integer grids (``input_grid`` and ``grid_weights``, in either
    order), in units of ``GRID_UNIT``: exact for each ``CHUNK_TERMS`` terms, and the chunks added
    in order, so the same bits whatever the BLAS does."""
    terms = left.shape[-1]
    total = torch.bmm(left[..., :CHUNK_TERMS], right[..., :CHUNK_TERMS, :])
    for start in range(CHUNK_TERMS, terms, CHUNK_TERMS):
        total = total + torch.bmm(left[..., start:start + CHUNK_TERMS], right[..., start:start + CHUNK_TERMS, :])
    return total * GRID_UNIT


def exact_bmm(x: torch.Tensor, w_grid: torch.Tensor, bias: torch.Tensor | None = None) -> torch.Tensor:
    """``bias + x @ w`` for ``x (P, R, K)`` and ``w_grid (P, K, N)`` from ``grid_weights``, with
    ``x`` on ``input_grid`` (``grid_bmm``). ``bias`` (broadcast to ``(P, R, N)``) is added in
    float64; the result is rounded to ``x``'s dtype."""
    total = grid_bmm(input_grid(x), w_grid)
    if bias is not None:
        total = total + bias.to(torch.float64)
    return total.to(x.dtype)
