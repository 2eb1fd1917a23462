"""The work of a database fit that runs on the Dask workers: read a batch of materials, fit those of one shape
with one `brdffit.fit_many` (one compiled program per worker and shape), turn the results into rows.

Every task catches the failure of a material and returns it as that material's row (status ``"error"``), so a
bad file or a failed fit never stops the batch (docs/batch.md).
"""

from __future__ import annotations

import functools
import time

import numpy as np

from .sources import Source, error_text, read_sources

__all__ = ["configure", "fit_batch", "result_row", "error_row", "FIT_SAMPLES"]

# The most samples (materials times samples each) of one `fit_many` call of a task: a batch of larger materials is
# fitted in equal parts within it, so that `batch` sets a task's size and not its memory (a batch of 128 MERL-size
# materials would hold their data, and each pass its tangents, for all of them at once).
FIT_SAMPLES = 1 << 18


@functools.cache
def configure(cache_dir: str | None) -> None:
    """Point this worker's JAX at a persistent compilation cache (once per process and folder), so that workers
    on one machine compile each program once between them and a restarted worker starts warm.

    Arguments:
        cache_dir: the cache folder (shared by the workers), or None to leave JAX as it is.
    """
    if cache_dir is None:
        return
    import jax

    jax.config.update("jax_compilation_cache_dir", str(cache_dir))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)


def _flat(name: str, value):
    """``(label, number)`` pairs of a parameter or metric: ``name`` for a scalar, ``name[i]`` per channel."""
    value = np.asarray(value, dtype=float)
    if value.ndim == 0:
        return [(name, float(value))]
    return [(f"{name}[{i}]", float(v)) for i, v in enumerate(value.ravel())]


def result_row(key: str, result, seconds: float) -> dict:
    """The table row of a fitted material (columns: `brdffit.distributed.table`).

    Arguments:
        key: the source's key.
        result: its `FitResult`.
        seconds: the time spent on it.
    """
    row = {"source": key, "status": result.status, "model": result.spec, "error": "", "time": float(seconds),
           "n_samples": float(result.n_samples), "cost": float(result.cost), "aic": float(result.aic),
           "bic": float(result.bic), "steps": float(result.steps)}
    for name, value in result.params.items():
        row.update(_flat(name, value))
    for name, value in result.stderr.items():
        row.update(_flat(f"stderr.{name}", value))
    for name, value in result.metrics.items():
        row.update(_flat(name, value))
    return row


def error_row(key: str, message: str, model: str = "") -> dict:
    """The table row of a material that could not be read or fitted."""
    return {"source": key, "status": "error", "model": model, "error": message}


def _fit_together(loaded: list, spec: str, fit_options: dict) -> list[dict]:
    """Rows of materials fitted together with one `fit_many`; if that fails, each is fitted alone, so that only
    the failing ones get an error row."""
    from .. import fit_many

    start = time.perf_counter()
    try:
        results = fit_many([m for _, m in loaded], spec, **fit_options)
    except Exception as err:
        if len(loaded) == 1:
            return [error_row(loaded[0][0].key, error_text(err), spec)]
        return [row for item in loaded for row in _fit_together([item], spec, fit_options)]
    share = (time.perf_counter() - start) / len(loaded)
    return [result_row(source.key, result, share) for (source, _), result in zip(loaded, results)]


def _select_one(item, candidates: tuple, fit_options: dict) -> dict:
    """The row of one material whose model `brdffit.select` chooses among ``candidates``."""
    from .. import select

    source, m = item
    start = time.perf_counter()
    try:
        selection = select(m, candidates, **fit_options)
    except Exception as err:
        return error_row(source.key, error_text(err), "auto")
    return result_row(source.key, selection.result, time.perf_counter() - start)


def fit_batch(sources: list[Source], model, read_options: dict | None, fit_options: dict,
              cache_dir: str | None) -> tuple[list[dict], list[Source]]:
    """Read a batch of materials and fit them: those of one shape (samples, channels) together.

    Arguments:
        sources: the materials.
        model: a spec string (one `fit_many` per shape), or a tuple of candidate specs (a `brdffit.select` per
            material).
        read_options: keywords of `brdffit.io.load`.
        fit_options: keywords of `brdffit.fit_many` (and of the candidates' fits for a selection).
        cache_dir: JAX's persistent compilation cache on this worker (`configure`).

    Returns:
        The rows of the materials, in order (an error row where one could not be read or fitted), and the member
        sources of the multi-material files among ``sources`` (which get no row: their members will).
    """
    configure(cache_dir)
    label = model if isinstance(model, str) else "auto"
    rows, members, shapes = {}, [], {}
    for read in read_sources(sources, read_options):
        key = read.source.key
        if read.error:
            rows[key] = error_row(key, read.error, label)
        elif read.members:
            members.extend(read.members)
        else:
            m = read.measurements
            shapes.setdefault((m.n, m.n_channels), []).append((read.source, m))
    for (samples, _), loaded in shapes.items():
        if isinstance(model, str):
            parts = -(-len(loaded) * samples // FIT_SAMPLES)  # equal parts: their sizes share compiled programs
            for part in np.array_split(np.arange(len(loaded)), max(1, min(parts, len(loaded)))):
                rows.update((row["source"], row) for row in _fit_together([loaded[i] for i in part], model,
                                                                          fit_options))
        else:
            rows.update((item[0].key, _select_one(item, model, fit_options)) for item in loaded)
    return [rows[source.key] for source in sources if source.key in rows], members
