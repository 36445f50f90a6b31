"""Compiling the step never ends a run (issue #60): inductor's artefacts are kept apart per CPU
dispatch, processes that compile at once on one cache finish with the right numbers, and when
compiling fails the step runs eagerly, with one warning line, once per process.

The subprocess tests compile for real, each on a fresh, empty cache (``TORCHINDUCTOR_CACHE_DIR``
in ``tmp_path``), so that nothing another test or run compiled can hide a fault."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import threading
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Callable

import pytest
import torch

import envs.execution as execution
from envs import TASKS, ForagingConfig, ForagingEnv
from lifelong_evo.commands.cli import main

ROOT = Path(__file__).resolve().parents[1]
WARNING = "warning: compiling the step failed ("
TINY_RUN = ["--algo", "neat", "--reg", "2", "--preset", "smoke", "--generations", "3", "--env", "duration=60",
            "--eval-threads", "2", "--no-record", "--quiet"]
"""A smoke run cut to mechanics size, with two evaluation threads (two threads meet the failure)."""

ELEMENTWISE = """
import json, os, torch
from envs.execution import compiled_phase, compile_cache_dir
os.environ["TORCHINDUCTOR_CACHE_DIR"] = compile_cache_dir()
phase = compiled_phase(lambda x, y: (x * y + 1.0, torch.where(x > 0.5, y, 2.0 * x)))
x = torch.arange(4000, dtype=torch.float32).reshape(40, 100) / 4000
print(json.dumps([out.flatten().tolist() for out in phase(x, x + 1)]))
"""
"""Elementwise code that inductor vectorises with ``at::vec`` where the dispatch allows, and whose
float results are exact either way, compiled the way ``ForagingEnv.compile`` compiles the step's
phases, in the cache folder it chooses."""


def _python(code: str, cache: Path, capability: str | None) -> subprocess.Popen:
    """Start ``code`` in a fresh interpreter on the inductor cache ``cache`` under the ATen
    dispatch ``capability`` (None: this machine's best)."""
    environment = {**os.environ, "PYTHONPATH": str(ROOT), "TORCHINDUCTOR_CACHE_DIR": str(cache)}
    environment.pop("ATEN_CPU_CAPABILITY", None)
    if capability is not None:
        environment["ATEN_CPU_CAPABILITY"] = capability
    return subprocess.Popen([sys.executable, "-c", code], env=environment, cwd=ROOT, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)


def _finish(process: subprocess.Popen) -> str:
    """``process``'s output, once it has ended well, without a warning or a traceback."""
    out, err = process.communicate(timeout=300)
    assert process.returncode == 0, err[-3000:]
    assert WARNING not in err and "Traceback" not in err, err[-3000:]
    return out


def _needs_a_vector_dispatch() -> None:
    if torch.backends.cpu.get_cpu_capability() == "DEFAULT":
        pytest.skip("this CPU has only the scalar dispatch: there is no other one to mix it with")


def test_a_cache_folder_per_torch_version_and_dispatch(monkeypatch, tmp_path):
    # ATen reads ATEN_CPU_CAPABILITY once, at its first question: asked here first, it keeps this
    # process's dispatch whatever the variable says below
    capability = torch.backends.cpu.get_cpu_capability()
    monkeypatch.setenv("TORCHINDUCTOR_CACHE_DIR", str(tmp_path))
    folders = {}
    for requested in ("default", "avx2", None):
        if requested is None:
            monkeypatch.delenv("ATEN_CPU_CAPABILITY", raising=False)
        else:
            monkeypatch.setenv("ATEN_CPU_CAPABILITY", requested)
        folders[requested] = execution.compile_cache_dir()
    assert len(set(folders.values())) == 3, folders
    for folder in folders.values():
        assert Path(folder).parent == tmp_path and torch.__version__ in Path(folder).name
        assert capability in Path(folder).name
    # a child process inherits the folder its parent chose, through the variable: it chooses its
    # own beside it, never one nested inside
    monkeypatch.setenv("TORCHINDUCTOR_CACHE_DIR", folders["avx2"])
    monkeypatch.setenv("ATEN_CPU_CAPABILITY", "default")
    assert execution.compile_cache_dir() == folders["default"]
    monkeypatch.delenv("TORCHINDUCTOR_CACHE_DIR")
    assert Path(execution.compile_cache_dir()).parent.name.startswith("torchinductor_"), "inductor's per-user folder"


def test_compile_chooses_the_cache_folder_before_anything_compiles(monkeypatch, tmp_path):
    monkeypatch.setenv("TORCHINDUCTOR_CACHE_DIR", str(tmp_path))
    ForagingEnv(ForagingConfig(), batch_size=2).compile()  # torch compiles lazily: nothing is built yet
    assert os.environ["TORCHINDUCTOR_CACHE_DIR"] == execution.compile_cache_dir() != str(tmp_path)


def _exact_elementwise() -> list[list[float]]:
    x = torch.arange(4000, dtype=torch.float32).reshape(40, 100) / 4000
    return [out.flatten().tolist() for out in (x * (x + 1) + 1.0, torch.where(x > 0.5, x + 1, 2.0 * x))]


def test_code_compiled_under_one_dispatch_is_never_loaded_under_another(tmp_path):
    """The issue's crash: a process under the scalar dispatch found, in a cache it shared, the
    vector code an AVX-512 process had generated, and failed to compile it ('at::vec' has not
    been declared). Now each dispatch compiles its own, and both give the exact results."""
    _needs_a_vector_dispatch()
    for capability in (None, "default"):
        assert json.loads(_finish(_python(ELEMENTWISE, cache=tmp_path, capability=capability))) == _exact_elementwise()
    assert len(list(tmp_path.iterdir())) == 2, "one folder per dispatch"


def test_processes_compiling_at_once_under_one_dispatch_and_another(tmp_path):
    """What a sweep of two workers does (each compiles, both at once), here with a third process
    under another dispatch setting, all three on one fresh cache: each compiles, none falls back
    to eager, and each gives the exact results. (Compiled like the step's phases; the step itself
    is compiled in ``test_env_rules.py`` and a compiled run in ``test_lifelong_run.py``.) The two
    under one dispatch share a folder: inductor builds each file under a lock of its own and
    writes every cache entry whole (a temporary file renamed into place)."""
    _needs_a_vector_dispatch()
    processes = [_python(ELEMENTWISE, cache=tmp_path, capability=capability) for capability in ("default", None, None)]
    assert [json.loads(_finish(process)) for process in processes] == [_exact_elementwise()] * 3
    assert len(list(tmp_path.iterdir())) == 2, "one folder per dispatch"


@pytest.mark.skipif(shutil.which("g++") is None, reason="the failing compiler answers inductor's probe with g++'s")
def test_a_failing_compiler_runs_the_step_eagerly_with_one_warning(tmp_path):
    """A C++ compiler that fails every build (inductor takes it from ``CXX``): the run finishes,
    exit 0, with one warning line and no traceback (two evaluation threads meet the failure; the
    warning comes once), and writes the numbers of the same run with ``--no-compile``."""
    compiler = tmp_path / "failing-c++"
    compiler.write_text('#!/bin/sh\ncase "$*" in *--version*) exec g++ "$@";; esac\n'
                        'echo "failing-c++: no build today" >&2\nexit 1\n')
    compiler.chmod(0o755)
    out = tmp_path / "runs"
    run = [sys.executable, "-m", "lifelong_evo", *TINY_RUN, "--out", str(out)]
    environment = {**os.environ, "PYTHONPATH": str(ROOT), "CXX": str(compiler),
                   "TORCHINDUCTOR_CACHE_DIR": str(tmp_path / "cache")}
    failing = subprocess.run([*run, "--name", "compiled", "--compile"], env=environment, cwd=ROOT, text=True,
                             capture_output=True, timeout=300)
    assert failing.returncode == 0, failing.stderr[-3000:]
    lines = failing.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith(WARNING), failing.stderr[-3000:]
    assert "failing-c++: no build today" in lines[0] and "--no-compile" in lines[0]
    assert main([*TINY_RUN, "--out", str(out), "--name", "eager", "--no-compile"]) == 0
    assert (out / "compiled/metrics.csv").read_text() == (out / "eager/metrics.csv").read_text()


class BrokenCompiler:
    """``torch.compile`` as a broken compiler makes it: the functions it gives raise, each after
    calling ``before_failing``."""

    def __init__(self):
        self.before_failing: Callable[[], object] = lambda: None

    def __call__(self, function, **options):
        def compiled(*args, **kwargs):
            self.before_failing()
            raise RuntimeError("simulated compiler failure\nwith a second line")
        return compiled


@pytest.fixture
def compiling_fails(monkeypatch) -> BrokenCompiler:
    """The step's ``torch.compile`` is a ``BrokenCompiler``; the process-wide fallback starts (and
    is left) unset."""
    broken = BrokenCompiler()
    monkeypatch.setattr(execution.torch, "compile", broken)
    monkeypatch.setattr(execution, "_compiling_failed", None)
    return broken


def test_the_fallback_is_taken_once_per_process(compiling_fails, capfd):
    """Two threads step two compiled environments, and both meet the failure at once (each waits
    for the other before failing): one warning in all, and every step gives the eager numbers."""
    compiling_fails.before_failing = threading.Barrier(2).wait
    config = ForagingConfig(duration=30)

    def play(env: ForagingEnv) -> torch.Tensor:
        env.reset(TASKS["red"], generator=1)
        wheels = torch.Generator().manual_seed(2)
        return torch.stack([env.step(torch.rand(4, config.n_agents, 3, generator=wheels) * 2 - 1)[1]
                            for _ in range(30)])

    compiled = [ForagingEnv(config, batch_size=4) for _ in range(2)]
    for env in compiled:
        env.compile()
    with ThreadPoolExecutor(2) as pool:
        results = list(pool.map(play, compiled))
    expected = play(ForagingEnv(config, batch_size=4))
    assert all(torch.equal(result, expected) for result in results)
    err = capfd.readouterr().err
    assert err.count(WARNING) == 1 and len(err.splitlines()) == 1, err
    assert "(RuntimeError: simulated compiler failure)" in err
    assert execution._compiling_failed == "RuntimeError: simulated compiler failure"


def test_a_failure_the_eager_step_shares_is_the_steps_own(compiling_fails, capfd):
    """Wheels of the wrong shape fail compiled and eagerly alike: that error is raised as it is,
    with no warning, and the process still compiles."""
    env = ForagingEnv(ForagingConfig(duration=30), batch_size=4)
    env.compile()
    env.reset(TASKS["red"], generator=1)
    with pytest.raises(RuntimeError):
        env.step(torch.zeros(4, 7))
    assert execution._compiling_failed is None and capfd.readouterr().err == ""
