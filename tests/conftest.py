"""Checks that every test gets."""
from __future__ import annotations

import platform

import pytest

import envs.execution as execution


def pytest_terminal_summary(terminalreporter):
    """The machine the suite ran on, beside its result (``-q`` hides pytest's header): the
    stored-bytes tests (``test_same_numbers_anywhere``) promise the same bytes on any x86-64 CPU,
    and a pass counts for the kind of CPU it ran on (docs/usage.md, Reproducibility)."""
    import torch

    from lifelong_evo.provenance import machine

    found = machine("cpu")
    terminalreporter.write_line(f"machine: {found['cpu']}, {found['vector_isa']}, {found['cpus']} CPUs; "
                                f"Python {platform.python_version()}, torch {torch.__version__}")


@pytest.fixture(autouse=True)
def compiling_did_not_fall_back():
    """A test that compiles the step checks the compiled step only where compiling worked: where
    it failed, the step runs eagerly (``envs.execution.compiled_phase``) and a comparison with
    eager numbers would pass without having compiled anything. The fallback is cleared after it is
    reported, so that one test's failure to compile is reported once, not by every later test."""
    yield
    failed, execution._compiling_failed = execution._compiling_failed, None
    assert failed is None, f"compiling the step failed, so it ran eagerly: {failed}"
