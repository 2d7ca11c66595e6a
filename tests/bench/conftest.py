"""Fixtures of the benchmark-script tests: the script under test, loaded as a module."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

BENCH_DIR = Path(__file__).resolve().parents[2] / "bench"


@pytest.fixture(scope="module")
def bench(request):
    """The bench/ script that the test module names in ``BENCH`` (e.g. ``"bench_codecs"``)."""
    name = request.module.BENCH
    spec = importlib.util.spec_from_file_location(name, BENCH_DIR / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module
