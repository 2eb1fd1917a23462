"""Fewer malloc arenas under an address-space limit, so that JAX fits where ``ulimit -v`` allows.

glibc's malloc gives each thread that allocates an arena of its own, up to 8 per core, and reserves 64 MiB of
address space for each. The reservation costs no memory, but it counts against ``RLIMIT_AS`` (``ulimit -v``):
JAX's thread pools took 1.49 GB of address space on a 2-core machine before any work, 0.57 GB with at most two
arenas, and on a machine with more cores its threads (and so its arenas) are more. Under a finite address-space
limit brdffit therefore caps the arenas at two (``mallopt(M_ARENA_MAX, 2)``, what ``MALLOC_ARENA_MAX=2`` sets)
when it is imported, before JAX starts its threads. Without a limit, or where the user set ``MALLOC_ARENA_MAX``,
or without glibc, nothing changes.
"""

from __future__ import annotations

import os

__all__ = ["cap_malloc_arenas", "ARENAS_UNDER_LIMIT"]

ARENAS_UNDER_LIMIT = 2
_M_ARENA_MAX = -8  # <malloc.h>


def cap_malloc_arenas() -> bool:
    """Cap glibc's malloc arenas at `ARENAS_UNDER_LIMIT` where an address-space limit is set; True where it did."""
    if "MALLOC_ARENA_MAX" in os.environ:
        return False
    try:
        import ctypes
        import resource

        if resource.getrlimit(resource.RLIMIT_AS)[0] == resource.RLIM_INFINITY:
            return False
        mallopt = ctypes.CDLL(None).mallopt
    except (ImportError, OSError, AttributeError):  # not POSIX, no C library to load, not glibc (musl: no mallopt)
        return False
    return mallopt(_M_ARENA_MAX, ARENAS_UNDER_LIMIT) == 1
