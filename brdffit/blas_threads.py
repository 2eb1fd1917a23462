"""One BLAS thread while brdffit fits: the engine's dense linear algebra is small.

The host-side linear algebra of a fit works on small matrices: the normal equations of the free scalars (a few to
a few hundred: 133 for Lambert and three Lafortune lobes in 31 bands), their eigen-decompositions for the
covariance, and the bounded Gauss-Newton step of the diagnosis. OpenBLAS (NumPy's and SciPy's BLAS) hands even
these to a team of threads, one per core, which spin while they wait for each other. Where the cores are already
busy, with XLA's own threads, the selection's other candidate fitted beside (`brdffit.select.SELECT_THREADS`) or
another job on the host, each call waits for threads that wait for a core, and takes several times as long
(docs/benchmarks.md has the measurement: a selection on a loaded 2-core host took fifteen times as long). One
thread loses nothing at these sizes: the large work of a fit (the passes over the samples) runs in XLA, which has
its own thread pool.

`one_blas_thread` limits every BLAS loaded in the process to one thread (threadpoolctl, the mechanism
scikit-learn uses) while a fitting entry point that the process's main thread called runs, and restores the
previous limits when the outermost one returns. OpenBLAS takes a new thread count only from the main thread (a
call from another thread leaves it as it was), so the limit is set there: it covers a fit, selection or posterior
that the main thread runs and whatever runs beside it (a selection's candidates in their threads). An entry point
called from another thread changes nothing; Dask's workers, where `brdffit.fit_many` runs its fits, start with one
BLAS thread already (distributed's nanny sets ``OPENBLAS_NUM_THREADS=1``). The limit is process-wide, as BLAS
threading is: a user's own NumPy work in another thread during a fit runs single-threaded too.
"""

from __future__ import annotations

import contextlib
import threading

__all__ = ["one_blas_thread"]

_depth = 0  # the main thread's entries running now
_limits = None  # the threadpoolctl limiter of the outermost one, which restores the previous limits


class one_blas_thread(contextlib.ContextDecorator):
    """Context manager and decorator: one BLAS thread while the main thread is inside it (module doc). Re-entrant;
    entered from another thread, it does nothing."""

    def __enter__(self):
        global _depth, _limits
        if threading.current_thread() is threading.main_thread():
            if _depth == 0:
                import scipy.linalg  # noqa: F401 - loads SciPy's own BLAS, so that the limit reaches it too
                from threadpoolctl import threadpool_limits

                _limits = threadpool_limits(limits=1, user_api="blas")
            _depth += 1
        return self

    def __exit__(self, *exc):
        global _depth, _limits
        if threading.current_thread() is threading.main_thread():
            _depth -= 1
            if _depth == 0:
                _limits.restore_original_limits()
                _limits = None
        return False
