"""Shared fixtures. Real data lives beside the repository in ../shared/data (or $MATA_SHARED_DATA);
tests that need it skip with the reason when it is absent."""

from __future__ import annotations

import os
import signal
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

# A shell that starts the suite as a background job (`bash .ci/run &`, nohup, some CI runners)
# hands it SIGINT ignored, and every process it starts inherits that: the Ctrl-C tests (stop,
# live, Ray) would then test nothing. Python's own handler in the test process makes SIGINT
# behave as on a terminal here and, reset to the default on exec, in every child.
signal.signal(signal.SIGINT, signal.default_int_handler)


def benchmark(name: str):
    """The module ``benchmarks/<name>.py`` (benchmarks are scripts, not a package)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(name, REPO / "benchmarks" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def shared_data_dir() -> Path:
    return Path(os.environ.get("MATA_SHARED_DATA", REPO.parent / "shared" / "data"))


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """../shared/data, or skip: real footage, weights, annotations and published results."""
    path = shared_data_dir()
    if not (path / "README.md").is_file():
        pytest.skip(f"real data not found at {path} (set MATA_SHARED_DATA to the shared/data folder)")
    return path
