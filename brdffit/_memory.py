"""glibc's malloc tuned for brdffit: fewer arenas under an address-space limit, so that JAX fits where ``ulimit -v``
allows, and, in the console script's own process, freed memory kept for the next pass.

glibc's malloc gives each thread that allocates an arena of its own, up to 8 per core, and reserves 64 MiB of
address space for each. The reservation costs no memory, but it counts against ``RLIMIT_AS`` (``ulimit -v``):
JAX's thread pools took 1.49 GB of address space on a 2-core machine before any work, 0.57 GB with at most two
arenas, and on a machine with more cores its threads (and so its arenas) are more. Under a finite address-space
limit brdffit therefore caps the arenas at two (``mallopt(M_ARENA_MAX, 2)``, what ``MALLOC_ARENA_MAX=2`` sets)
when it is imported, before JAX starts its threads. Without a limit, or where the user set ``MALLOC_ARENA_MAX``,
or without glibc, nothing changes.

XLA's CPU runtime allocates each execution's buffers anew and frees them after it. glibc serves an allocation above
its mmap threshold (at most 32 MiB), or one larger than a thread arena's 64 MiB heap, by a fresh mapping that it
unmaps when it is freed, so every pass of a fit faults its buffers in again page by page: `brdffit export --to pbrt
--fit` of the shipped clay's fit took 3.9 million page faults, 16 s of system time of its 52 s of CPU. The console
script's process (`brdffit.cli.run`) therefore allocates from one heap that keeps what is freed
(`keep_freed_memory`): 0.25 million faults and 2.2 s of system time for that export, 2.0 → 1.2 s for the RGL-EPFL
paper's default fit (docs/benchmarks.md), at the price of the freed memory, up to `KEPT_HEAP`, staying with the
process until it ends (that export's peak resident memory 808 → 884 MB). A process that imports brdffit as a
library keeps its malloc as it is.
"""

from __future__ import annotations

import os

__all__ = ["cap_malloc_arenas", "keep_freed_memory", "ARENAS_UNDER_LIMIT", "KEPT_HEAP"]

ARENAS_UNDER_LIMIT = 2
# The free memory at the top of the heap that `keep_freed_memory` leaves to the process (M_TRIM_THRESHOLD): more
# than a pass's buffers need, so that the heap is not trimmed between passes (every command stays under the 2 GiB
# address-space limit of tests/test_memory_limits.py with it).
KEPT_HEAP = 1 << 30
_M_TRIM_THRESHOLD, _M_MMAP_MAX, _M_ARENA_MAX = -1, -4, -8  # <malloc.h>
# The environment variables through which a user tunes glibc's malloc: where any is set, brdffit leaves it alone.
_USER_TUNING = ("MALLOC_ARENA_MAX", "MALLOC_MMAP_MAX_", "MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_",
                "MALLOC_TOP_PAD_", "GLIBC_TUNABLES")


def _mallopt():
    """glibc's ``mallopt``, or None (not POSIX, no C library to load, not glibc: musl has no mallopt)."""
    try:
        import ctypes

        return ctypes.CDLL(None).mallopt
    except (ImportError, OSError, AttributeError):
        return None


def cap_malloc_arenas() -> bool:
    """Cap glibc's malloc arenas at `ARENAS_UNDER_LIMIT` where an address-space limit is set; True where it did."""
    if "MALLOC_ARENA_MAX" in os.environ:
        return False
    try:
        import resource
    except ImportError:  # not POSIX
        return False
    if resource.getrlimit(resource.RLIMIT_AS)[0] == resource.RLIM_INFINITY:
        return False
    mallopt = _mallopt()
    return mallopt is not None and mallopt(_M_ARENA_MAX, ARENAS_UNDER_LIMIT) == 1


def keep_freed_memory() -> bool:
    """In a process of brdffit's own, before JAX starts its threads: one malloc arena for every thread, no mapping
    of its own for a large allocation, and up to `KEPT_HEAP` of freed memory kept at the heap's top (the module
    doc), so that a pass reuses the pages of the one before. Nothing where the user tunes malloc through its
    environment variables, or without glibc.

    Returns:
        True where it did.
    """
    mallopt = _mallopt()
    if mallopt is None or any(name in os.environ for name in _USER_TUNING):
        return False
    return all(mallopt(option, value) == 1
               for option, value in ((_M_ARENA_MAX, 1), (_M_MMAP_MAX, 0), (_M_TRIM_THRESHOLD, KEPT_HEAP)))
