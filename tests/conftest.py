"""Shared test set-up: importing brdffit turns on JAX's float64 mode before any test builds an array, and the
session shares one compilation cache.

The cache: the controller makes one temporary folder for the session and names it in ``BRDFFIT_CACHE_DIR``, which
the xdist workers and every ``brdffit`` process a test starts inherit; each process turns JAX's persistent cache on
there (`brdffit.compilation_cache.enable_compilation_cache`, as the CLI does). A program that one worker compiled is then loaded
by the other worker and by the tests' subprocesses without being traced again (`brdffit.programs`), and
nothing is written into the user's own cache. Most of the suite's time is tracing and compiling (issue 15); the
compiled programs change no result (`tests/test_programs.py`). The folder is removed when the session ends.
"""

import os
import shutil
import tempfile

import numpy as np
import pytest

import brdffit  # noqa: F401  (enables jax_enable_x64)
from brdffit.compilation_cache import enable_compilation_cache

_OWNER = "BRDFFIT_TEST_CACHE_OWNER"


def pytest_configure(config):
    if not hasattr(config, "workerinput"):  # the controller, or a run without xdist: a fresh folder
        os.environ["BRDFFIT_CACHE_DIR"] = tempfile.mkdtemp(prefix="brdffit-test-cache-")
        os.environ[_OWNER] = str(os.getpid())
    enable_compilation_cache()


def pytest_unconfigure(config):
    if os.environ.get(_OWNER) == str(os.getpid()):
        shutil.rmtree(os.environ["BRDFFIT_CACHE_DIR"], ignore_errors=True)


def pytest_collection_modifyitems(config, items):
    """Test files in the order the two workers should start them (pyproject runs xdist with ``--dist loadfile
    --no-loadscope-reorder``, so this order is kept): files with more tests marked ``slow`` first, then by their
    number of tests, so that the long files do not start last and leave one worker running alone at the end
    (longest first, Graham's LPT rule). Within a file the order is unchanged."""
    slow, count = {}, {}
    for item in items:
        count[item.path] = count.get(item.path, 0) + 1
        slow[item.path] = slow.get(item.path, 0) + (item.get_closest_marker("slow") is not None)
    items.sort(key=lambda item: (-slow[item.path], -count[item.path], str(item.path)))


@pytest.fixture
def rng():
    """A seeded NumPy generator, so that random test inputs are the same on every run."""
    return np.random.default_rng(20240607)
