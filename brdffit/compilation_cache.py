"""Where compiled programs are kept between processes, and turning that on.

JAX's persistent compilation cache (``jax_compilation_cache_dir``) keeps XLA's executables on disk; `brdffit.programs`
keeps its own executables in a folder of the same directory. The CLI turns both on for every command that
compiles; a Python user can call `enable_compilation_cache` too. This module does not import JAX until it is
called, so that ``brdffit --help`` stays light.
"""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["cache_dir", "enable_compilation_cache"]


def cache_dir() -> Path:
    """The cache directory: $BRDFFIT_CACHE_DIR, else the user cache directory ($XDG_CACHE_HOME or ~/.cache) under
    brdffit/jax."""
    if os.environ.get("BRDFFIT_CACHE_DIR"):
        return Path(os.environ["BRDFFIT_CACHE_DIR"])
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "brdffit" / "jax"


def enable_compilation_cache(job: str | None = None) -> None:
    """Turn on JAX's persistent compilation cache (and so `brdffit.programs`' kept executables) in `cache_dir`, so
    that a second process starts warm. An unwritable directory leaves it off: it only costs time.

    Arguments:
        job: what the process is about to do, in words that decide its programs (the CLI: the command, its options
            and the data's shape). With it, the kept executables that the last process with the same job used are
            read in the background from now on (`brdffit.programs.prefetch`), and at exit this process's are
            recorded for the next one (`brdffit.programs.record`).
    """
    import jax

    try:
        directory = cache_dir()
        directory.mkdir(parents=True, exist_ok=True)
    except OSError:
        return
    jax.config.update("jax_compilation_cache_dir", str(directory))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    if job is not None:
        import atexit

        from . import programs

        programs.prefetch(job)
        atexit.register(programs.record, job)
