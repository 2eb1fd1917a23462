"""`brdffit.blas_threads.one_blas_thread`: one BLAS thread while a fitting entry point that the main thread called
runs (a selection's candidate fits in their threads included), the previous limits restored after."""

import threading

import pytest

threadpoolctl = pytest.importorskip("threadpoolctl")

import brdffit  # noqa: E402
from brdffit.blas_threads import one_blas_thread  # noqa: E402


def _blas_threads() -> list[int]:
    return [info["num_threads"] for info in threadpoolctl.threadpool_info() if info["user_api"] == "blas"]


@pytest.fixture
def two_threads():
    """BLAS set to two threads for the test (as on a 2-core host), whatever the machine; restored after."""
    import scipy.linalg  # noqa: F401 - SciPy's BLAS loaded, so that the limit reaches it too

    with threadpoolctl.threadpool_limits(limits=2, user_api="blas"):
        yield


def test_the_main_threads_outermost_entry_sets_and_restores_the_limit(two_threads):
    assert _blas_threads() and set(_blas_threads()) == {2}
    seen = {}

    def worker():
        with one_blas_thread():  # from another thread: changes nothing, and its exit restores nothing
            seen["worker inside"] = _blas_threads()
        seen["worker after"] = _blas_threads()

    with one_blas_thread():
        with one_blas_thread():  # nested
            assert set(_blas_threads()) == {1}
        assert set(_blas_threads()) == {1}
        thread = threading.Thread(target=worker)
        thread.start()
        thread.join(20)
    assert set(seen["worker inside"]) == {1} and set(seen["worker after"]) == {1}
    assert set(_blas_threads()) == {2}
    thread = threading.Thread(target=worker)  # a thread alone cannot set it (OpenBLAS ignores it): nothing changes
    thread.start()
    thread.join(20)
    assert set(seen["worker inside"]) == {2} and set(_blas_threads()) == {2}


def test_fit_and_select_run_with_one_blas_thread_and_restore_it(two_threads, monkeypatch):
    from brdffit.fitting import api

    during = []
    diagnose = api.diagnose

    def spy(*args, **kwargs):
        during.append(_blas_threads())
        return diagnose(*args, **kwargs)

    monkeypatch.setattr(api, "diagnose", spy)
    m = brdffit.synth.generate("lambert+ggx", n=400, noise="relative:0.01", seed=3)
    brdffit.fit(m, "lambert+ggx")
    brdffit.select(m, candidates=["lambert", "lambert+ggx"])
    assert during and all(set(threads) == {1} for threads in during)
    assert set(_blas_threads()) == {2}
