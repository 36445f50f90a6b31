"""The evolution strategies' own arithmetic under ``--numerics portable`` (the default):
``algorithms.portable_update``. Its functions against torch's, every ES's update and sampling
made only of exact or replaced functions, and the same bits under ATen's scalar, AVX2 and
AVX-512 dispatch (which the native arithmetic does not give)."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from torch.overrides import TorchFunctionMode

import algorithms.es as es
from algorithms import REGISTRY, make_optimizer
from algorithms.portable_update import fixed_order_sum, portable_update, strict_update
from envs import numerics

ROOT = Path(__file__).resolve().parent.parent
EVOLUTION_STRATEGIES = sorted(name for name, cls in REGISTRY.items() if issubclass(cls, es.ESOptimizer))
PORTABLE_ES = [name for name in EVOLUTION_STRATEGIES if name != "cmaes"]
"""Full CMA-ES's update is LAPACK's and MKL's linear algebra, which stays native
(docs/usage.md, Reproducibility)."""


def _play(optimizer, generations: int = 3) -> list[torch.Tensor]:
    """A few generations on a fixed fitness with ties (15 zeros), a task end after the second;
    the centres and regularised fitnesses met on the way."""
    seen = []
    for generation in range(generations):
        optimizer.ask()
        fitness = (torch.arange(optimizer.population_size) * 7919 % 307).float()
        fitness[:15] = 0
        regularised = optimizer.regularise(fitness)
        optimizer.tell(fitness, regularised)
        if generation == 1:
            optimizer.end_task()
        seen += [optimizer.centre.clone(), regularised.clone()]
    return seen


def test_fixed_order_sum_is_a_sum():
    """The same shapes as ``torch.sum`` over any dims, with and without ``keepdim``; exact where the
    terms and partial sums are integers; within float32 rounding of torch's sum elsewhere."""
    draw = torch.Generator().manual_seed(4)
    x = torch.rand(7, 5, 3, generator=draw)
    for dim in (None, 0, 1, 2, -1, (0, 2)):
        for keepdim in (False, True):
            expected = torch.sum(x, dim, keepdim) if dim is not None else torch.sum(x)
            got = fixed_order_sum(x, dim, keepdim) if dim is not None else fixed_order_sum(x)
            assert got.shape == expected.shape and got.dtype == x.dtype
            assert torch.allclose(got, expected, rtol=1e-6)
    integers = torch.randint(-1000, 1000, (301, 4), generator=draw).float()
    assert torch.equal(fixed_order_sum(integers, 0), integers.sum(0))
    assert torch.equal(fixed_order_sum(torch.empty(0, 3), 0), torch.zeros(3))


def test_replaced_functions_keep_their_meaning():
    """Under the portable mode: ``topk`` keeps equal values in index order, ``std`` is the
    population's or the sample's as asked, ``exp``/``log``/``sqrt``/``pow`` round the exact values."""
    values = torch.tensor([3.0, 1.0, 3.0, 2.0, 3.0])
    x = torch.rand(50, generator=torch.Generator().manual_seed(5)) + 0.5
    with portable_update():
        top = torch.topk(values, 3)
        population_std, sample_std = x.std(unbiased=False), x.std()
        exp, log, sqrt, cube = torch.exp(x), torch.log(x), torch.sqrt(x), x ** 3
        log_of_integers = torch.log(torch.arange(1, 40))
    assert torch.equal(log_of_integers, torch.log(torch.arange(1, 40).double()).float())
    assert top.indices.tolist() == [0, 2, 4] and top.values.tolist() == [3.0, 3.0, 3.0]
    assert torch.allclose(population_std, x.std(unbiased=False)) and torch.allclose(sample_std, x.std())
    assert population_std < sample_std
    for got, exact in ((exp, x.double().exp()), (log, x.double().log()), (sqrt, x.double().sqrt()),
                       (cube, x.double() ** 3)):
        assert torch.equal(got, exact.float())


@pytest.mark.parametrize("algo", EVOLUTION_STRATEGIES)
def test_every_es_computes_only_with_exact_or_replaced_functions(algo, monkeypatch):
    """Construction, sampling, the regulariser (L2 and EWC-style importance) and the update of
    every ES call no torch function outside ``STRICT`` and the replaced ones, but full CMA-ES's
    linear algebra."""
    monkeypatch.setattr(es, "portable_update", strict_update)
    for options in ({"reg": 1.0}, {"reg": 1.0, "importance": "ewc"}):
        optimizer = make_optimizer(algo, obs_dim=18, population_size=40, seed=1, **options)
        if algo in PORTABLE_ES:
            _play(optimizer)
        else:
            with pytest.raises(NotImplementedError, match="matmul|cholesky"):
                _play(optimizer)


def test_the_mode_is_off_under_native_arithmetic():
    assert isinstance(portable_update(), TorchFunctionMode)
    numerics.use("native")
    try:
        assert not isinstance(portable_update(), TorchFunctionMode)
    finally:
        numerics.use("portable")


UPDATES = """
import hashlib, sys, torch
from algorithms import make_optimizer
from tests.test_portable_update import PORTABLE_ES, _play
torch.set_num_threads(int(sys.argv[1]))
for algo in PORTABLE_ES:
    seen = _play(make_optimizer(algo, obs_dim=18, population_size=60, seed=5, reg=1.0))
    print(algo, hashlib.sha256(b"".join(t.numpy().tobytes() for t in seen)).hexdigest())
"""


def _updates(capability: str, threads: int) -> str:
    path = os.pathsep.join([str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])])
    env = {**os.environ, "PYTHONPATH": path, "ATEN_CPU_CAPABILITY": capability}
    return subprocess.run([sys.executable, "-c", UPDATES, str(threads)], env=env, capture_output=True, text=True,
                          timeout=600, check=True, cwd=ROOT).stdout


def test_es_updates_are_the_same_under_every_dispatch_and_thread_count():
    """Every portable ES's samples, regularised fitness and centres over three generations (a
    task end among them), under ATen's scalar, AVX2 and AVX-512 kernels (as far as this CPU has
    them) and over one or two torch threads: the same bits. (Natively the scalar dispatch
    already moves sep-CMA-ES's first update.)"""
    best = torch.backends.cpu.get_cpu_capability().lower()
    runs = {(capability, threads): _updates(capability, threads)
            for capability, threads in [("default", 2), ("avx2", 1), (best, 2)]}
    assert len(next(iter(runs.values())).splitlines()) == len(PORTABLE_ES)
    assert len(set(runs.values())) == 1, runs
