"""The portable arithmetic (``envs.numerics``) and what it promises: the arena's step and the
built-in controllers give the same bits eagerly and compiled, at any batch size, and under every
ATen dispatch this CPU offers (the scalar one of a CPU without AVX2, AVX2, AVX-512), so that a
run's fitness depends on its seed and settings alone. Each check compares whole tensors bit for
bit; torch's own ``sqrt``, ``sin``, ``sigmoid`` and matrix products fail them. The step eagerly
against compiled, bit for bit, is ``tests/test_paper_tasks_identical.py``'s (one stored digest for
both), and whole runs under every speed setting ``tests/test_same_numbers_anywhere.py``'s."""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from envs import numerics

ROOT = Path(__file__).resolve().parents[1]


def test_sqrt_is_correctly_rounded():
    x = torch.rand(200_000, generator=torch.Generator().manual_seed(0)) * 800
    exact = torch.tensor([math.sqrt(v) for v in x.double().tolist()], dtype=torch.float64).float()
    assert torch.equal(numerics.sqrt(x), exact)


def test_the_tables_follow_their_functions():
    x = torch.linspace(-30, 30, 100_001)
    assert float((numerics.sigmoid(x).double() - torch.sigmoid(x.double())).abs().max()) < 1e-7
    assert float((numerics.tanh(x / 4).double() - torch.tanh(x.double() / 4)).abs().max()) < 2e-7
    assert numerics.sigmoid(torch.tensor([-math.inf, math.inf])).tolist() == [0.0, 1.0]
    degrees = torch.rand(100_000, generator=torch.Generator().manual_seed(1)) * 360
    sin, cos = numerics.sin_cos_degrees(degrees)
    radians = torch.deg2rad(degrees.double())
    assert float((sin.double() - torch.sin(radians)).abs().max()) < 1e-7
    assert float((cos.double() - torch.cos(radians)).abs().max()) < 1e-7


def test_a_table_value_does_not_depend_on_its_neighbours():
    """The body of a tensor and its tail (which torch's vectorised kernels treat apart) agree."""
    x = torch.randn(1_003, generator=torch.Generator().manual_seed(2)) * 5
    whole = numerics.sigmoid(x)
    assert all(torch.equal(numerics.sigmoid(x[i:i + 7]), whole[i:i + 7]) for i in range(0, 990, 7))


def test_a_grid_product_is_exact_in_any_order():
    gen = torch.Generator().manual_seed(3)
    x = torch.rand(4, 9, 100, generator=gen) * 2 - 1  # 100 terms: two chunks
    w = torch.randn(4, 100, 5, generator=gen)
    got = numerics.exact_bmm(x, numerics.grid_weights(w))
    reversed_terms = numerics.exact_bmm(x.flip(-1), numerics.grid_weights(w.flip(1)))
    assert torch.equal(got, reversed_terms)
    assert torch.allclose(got.double(), torch.bmm(x.double(), w.double()), atol=1e-4)


FITNESS = """
import hashlib, sys, torch
from dataclasses import replace
from algorithms import make_optimizer
from envs import TASKS, ForagingConfig
from lifelong_evo.evaluate import evaluate
algo, threads = sys.argv[1], int(sys.argv[2])
config = replace(ForagingConfig(), duration=500)
policy = make_optimizer(algo, obs_dim=config.obs_dim, population_size=20, seed=6).ask()
fitness = evaluate(policy, config, [TASKS["red"], TASKS["green"]], 3, torch.Generator().manual_seed(7),
                   eval_threads=threads)
print(hashlib.sha256(fitness.numpy().tobytes()).hexdigest(), float(fitness.abs().sum()))
"""


def _fitness(algo: str, capability: str, threads: int) -> tuple[str, float]:
    # the checkout first, then whatever the caller's path holds (where the packages may live)
    path = os.pathsep.join([str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])])
    env = {**os.environ, "PYTHONPATH": path, "ATEN_CPU_CAPABILITY": capability}
    result = subprocess.run([sys.executable, "-c", FITNESS, algo, str(threads)], env=env, capture_output=True,
                            text=True, timeout=600, check=True)
    digest, total = result.stdout.split()
    return digest, float(total)


@pytest.mark.parametrize("algo", ["neat", "openai-es"])
def test_fitness_is_the_same_under_every_dispatch_and_thread_count(algo):
    """A population's fitness under ATen's scalar, AVX2 and AVX-512 kernels (as far as this CPU
    has them) and over one or two evaluation threads. OpenAI-ES samples its population under the
    portable update (``algorithms.portable_update``), whose normal draws the scalar dispatch gives
    alike too."""
    settings = [("default", 2), ("avx2", 1), ("avx512", 2)]
    runs = {(capability, threads): _fitness(algo, capability, threads) for capability, threads in settings}
    assert next(iter(runs.values()))[1] > 0, "a fixture that scores 0 everywhere proves nothing"
    assert len({digest for digest, _ in runs.values()}) == 1, runs


def test_native_is_torchs_own_arithmetic():
    """``use("native")`` switches every portable function back to torch's (and portable is the default)."""
    x = torch.randn(10_000, generator=torch.Generator().manual_seed(8)) * 3
    assert numerics.mode() == "portable"
    portable = numerics.sigmoid(x), numerics.tanh(x), numerics.sqrt(x.abs())
    numerics.use("native")
    try:
        assert torch.equal(numerics.sigmoid(x), torch.sigmoid(x)) and torch.equal(numerics.tanh(x), torch.tanh(x))
        assert torch.equal(numerics.sqrt(x.abs()), torch.sqrt(x.abs()))
        assert not torch.equal(numerics.sigmoid(x), portable[0]) and not torch.equal(numerics.tanh(x), portable[1])
    finally:
        numerics.use("portable")
    with pytest.raises(ValueError, match="numerics must be one of portable, native"):
        numerics.use("fast")


def test_a_run_records_its_numerics_and_resume_keeps_them(tmp_path, capsys):
    from lifelong_evo.commands.cli import main
    from lifelong_evo.json_files import read_json
    from lifelong_evo.rundir import RunDir
    from lifelong_evo.runs import configuration_of

    small = ["--algo", "neat", "--preset", "smoke", "--generations", "1", "--env", "duration=30", "--no-record",
             "--quiet", "--out", str(tmp_path), "--name", "run"]
    try:
        assert main([*small, "--numerics", "native"]) == 0
    finally:
        numerics.use("portable")  # the run chose native for this process
    run = RunDir(tmp_path / "run")
    assert read_json(run.config)["numerics"] == "native" and read_json(run.summary)["numerics"] == "native"
    before = {path: path.read_bytes() for path in run.path.rglob("*") if path.is_file()}
    assert main([*small, "--resume", "--numerics", "portable"]) == 2
    assert "--numerics 'portable' (stored: 'native')" in capsys.readouterr().err
    assert {path: path.read_bytes() for path in run.path.rglob("*") if path.is_file()} == before
    # a config.json written before the setting existed ran natively, and reads so
    written = read_json(run.config)
    del written["numerics"]
    run.config.write_text(json.dumps(written))
    assert run.read_config().numerics == "native" and configuration_of(written)["numerics"] == "native"
