"""Checks that every test gets."""
from __future__ import annotations

import pytest

import envs.execution as execution


@pytest.fixture(autouse=True)
def compiling_did_not_fall_back():
    """A test that compiles the step checks the compiled step only where compiling worked: where
    it failed, the step runs eagerly (``envs.execution.compiled_phase``) and a comparison with
    eager numbers would pass without having compiled anything. The fallback is cleared after it is
    reported, so that one test's failure to compile is reported once, not by every later test."""
    yield
    failed, execution._compiling_failed = execution._compiling_failed, None
    assert failed is None, f"compiling the step failed, so it ran eagerly: {failed}"
