"""Checks that every test gets."""
from __future__ import annotations

import pytest

import envs.execution as execution


@pytest.fixture(autouse=True)
def compiling_did_not_fall_back():
    """A test that compiles the step checks the compiled step only where compiling worked: where
    it failed, the step runs eagerly (``envs.execution.compiled_phase``) and a comparison with
    eager numbers would pass without having compiled anything."""
    yield
    assert execution._compiling_failed is None, f"compiling the step failed, so it ran eagerly: {execution._compiling_failed}"
