"""Shared test set-up: importing brdffit turns on JAX's float64 mode before any test builds an array, and the
session shares one compilation cache.

The cache: the controller makes one temporary folder for the session and names it in ``BRDFFIT_CACHE_DIR``, which
the xdist workers and every ``brdffit`` process a test starts inherit; each process turns JAX's persistent cache on
there (`brdffit.compilation_cache.enable_compilation_cache`, as the CLI does). A program that one worker compiled is then loaded
by the other worker and by the tests' subprocesses without being traced again (`brdffit.programs`), and
nothing is written into the user's own cache. Most of the suite's time is tracing and compiling (issue 15); the
compiled programs change no result (`tests/test_programs.py`). The folder is removed when the session ends.

BLAS: each test process (the controller without xdist, each xdist worker) runs NumPy's and SciPy's BLAS with one
thread, as `brdffit.blas_threads.one_blas_thread` does for a fit and for the same reason: the suite runs two workers
on a 2-core host, and an OpenBLAS thread team per call then spins waiting for a core (the tests' own quadratures,
such as the eigen-decomposition behind an 800-node Gauss-Legendre rule, took tens of times longer). A test that
needs more threads sets them itself (`tests/test_blas_threads.py`); the ``brdffit`` processes that tests start keep
the user's default.
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
    import scipy.linalg  # noqa: F401 - loads SciPy's own BLAS, so that the limit reaches it too
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=1, user_api="blas")  # for the whole process (module doc)


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


@pytest.fixture(scope="module")
def mi():
    """Mitsuba 3 in its ``scalar_rgb`` variant; the test skips where it is not installed or lacks that variant."""
    mitsuba = pytest.importorskip("mitsuba", reason="Mitsuba 3 (test extra) is not installed")
    try:
        mitsuba.set_variant("scalar_rgb")
    except (AttributeError, ImportError, ValueError) as err:
        pytest.skip(f"Mitsuba's scalar_rgb variant is not available: {err}")
    return mitsuba
