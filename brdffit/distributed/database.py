"""`fit_database`: fit every material of a database on a Dask distributed cluster (docs/batch.md).

The client plans and records; the workers read and fit (`brdffit.distributed.tasks`):

1. the sources are expanded (`expand_sources`: paths, folders, globs; no file is opened on the client); with
   ``resume`` the rows already in the results table are kept and their materials skipped (all but ``"error"``
   rows, which are tried again);
2. the sources are cut, in the order given, into batches of at most ``batch`` (their number a multiple of the
   cluster's workers, their sizes within one of each other: `cut`); a task reads its batch once and fits the
   materials of one shape (samples, channels) together with one `brdffit.fit_many`, so a worker compiles a
   program per shape and reuses it. A database of one shape (MERL, the texels of a scan, one instrument's
   archive) thus gives batches of equally shaped materials; a mixed one is best given grouped by shape.
   Materials of other shapes are not padded into a batch: missing samples would change the engine's seeded
   subsamples. The shapes are not read first in a round of their own: that would read every file twice (an
   opening of a brdffit HDF5 file inspects all of it in a child process; a task inspects its batch's files in
   one);
3. a multi-material HDF5 file given as a whole is found to be one when its task reads it: the task returns its
   member groups, which the client cuts into batches of their own (a table row per member);
4. the rows are written as the tasks' results arrive (the whole table, atomically, at most once a second and at
   the end, also of an interrupted run), and a progress line counts them with an estimate of the time left.

Faults: the scheduler reruns the tasks of a worker that dies on the other workers (Dask's
``distributed.scheduler.allowed-failures``, 3 by default); a batch that still fails gets error rows naming the
reason. An interrupted client leaves the rows received so far, which ``resume`` keeps. The same batches give the
same numbers on any worker; a batch of several materials agrees with the materials' serial fits to the solver's
tolerance, not bit for bit (docs/batch.md).
"""

from __future__ import annotations

import contextlib
import inspect
import math
import os
import time
from pathlib import Path

from ..progress import Progress
from . import DEFAULT_BATCH
from .sources import error_text, expand_sources
from .table import complete, read_results, table_format, write_results
from .tasks import error_row, fit_batch

__all__ = ["fit_database", "local_cluster"]

# The table is rewritten whole; at most this often (and at the end), so that a large database does not spend its
# time rewriting a growing table after every batch; and at most `WRITE_SHARE` of the time (writing a large table
# takes CPU time that the client takes from the workers when it shares their machine).
WRITE_INTERVAL_S = 1.0
WRITE_SHARE = 0.05


def _model_argument(model):
    """A spec string, or the candidates of a per-material selection (``"auto"``: the standard candidates)."""
    from .. import models
    from ..select import DEFAULT_CANDIDATES

    if model == "auto":
        return tuple(DEFAULT_CANDIDATES)
    if isinstance(model, str):
        models.get(model)  # an unknown lobe or option fails here, before any work
        return model
    if isinstance(model, models.Model):
        return model.spec
    candidates = tuple(model)
    if not candidates or not all(isinstance(c, str) for c in candidates):
        raise ValueError(f"model must be a spec, 'auto', or a sequence of candidate specs; got {model!r}")
    for candidate in candidates:
        models.get(candidate)
    return candidates


def _check_fit_options(fit_options: dict, selecting: bool) -> None:
    """Refuse, before any work, keywords that every task would fail on."""
    from ..fitting import fit, fit_many
    from ..select import select

    takers = (fit, select) if selecting else (fit_many,)
    accepted = {name for taker in takers for name, p in inspect.signature(taker).parameters.items()
                if p.kind is p.KEYWORD_ONLY or p.kind is p.POSITIONAL_OR_KEYWORD}
    accepted -= {"measurements", "measurements_list", "model", "candidates", "progress"}
    unknown = sorted(set(fit_options) - accepted)
    if unknown:
        raise TypeError(f"fit_database: unknown fit option(s) {', '.join(unknown)}; it takes "
                        f"{', '.join(sorted(accepted))}")


@contextlib.contextmanager
def _connected(client, workers: int | None):
    """A `distributed.Client`: the one given, one connected to a scheduler address, or one on a LocalCluster of
    ``workers`` single-threaded processes (default: one per core), closed afterwards."""
    from distributed import Client

    if client is not None and workers is not None:
        raise ValueError("workers= sizes the local cluster that fit_database starts; a given client or scheduler "
                         "has its own workers")
    if isinstance(client, str):
        with Client(client) as connected:
            yield connected
    elif client is not None:
        yield client
    else:
        with local_cluster(workers or os.cpu_count() or 1) as cluster, Client(cluster) as connected:
            yield connected


def local_cluster(workers: int):
    """A LocalCluster of ``workers`` single-threaded worker processes on 127.0.0.1, each pinned to its share of the
    cores where there are at least as many cores (`brdffit.distributed.affinity.PinnedCore`), started without the
    ``MALLOC_TRIM_THRESHOLD_`` that Dask's nannies set by default (``distributed.nanny.pre-spawn-environ``).

    Setting that variable turns off glibc's dynamic mmap threshold, so every large array of a fit is mapped and
    faulted in anew, which makes `fit_many` markedly slower; the nanny's other variables (OMP, MKL and OpenBLAS
    threads at 1), which speed it up, are kept. Workers started with ``dask worker`` get it from the same setting:
    set ``DASK_DISTRIBUTED__NANNY__PRE_SPAWN_ENVIRON__MALLOC_TRIM_THRESHOLD_=None`` where they start (docs/batch.md).

    Arguments:
        workers: the number of worker processes.

    Returns:
        The `distributed.LocalCluster` (a context manager).
    """
    import dask
    from distributed import LocalCluster

    cores = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
    plugins = set()
    if 0 < workers <= len(cores):
        from .affinity import PinnedCore

        plugins.add(PinnedCore(cores, workers))
    with dask.config.set({"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}):
        return LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                            dashboard_address=None, plugins=plugins)


class _Record:
    """The rows so far, written to the results table (when there is one) each time new rows arrive, and the
    progress line."""

    def __init__(self, out, given: list[str], kept: list[dict], bar: Progress, todo: int):
        self.out, self.bar, self.todo = out, bar, todo
        self.rows = {row["source"]: row for row in kept}
        self.kept = set(self.rows)
        self.given = list(given)  # the sources' keys in order, multi-material files replaced by their members
        self.done = self.failed = 0
        self.start = time.perf_counter()
        self.next_write, self.unwritten = -math.inf, False

    def expand(self, key: str, members: list[str], fresh: int) -> None:
        """A multi-material file turned out to stand for ``members``, ``fresh`` of which are still to fit."""
        named = set(members)
        rest = [k for k in self.given if k not in named]
        at = rest.index(key)
        self.given = rest[:at] + members + rest[at + 1:]
        self.todo += fresh - 1
        self.bar.total = max(self.todo, 1)

    def add(self, rows: list[dict]) -> None:
        for row in rows:
            self.rows[row["source"]] = row
        self.done += len(rows)
        self.failed += sum(row["status"] == "error" for row in rows)
        self.unwritten = self.unwritten or bool(rows)
        if time.perf_counter() >= self.next_write:
            self.flush()
        if self.done:
            left = (time.perf_counter() - self.start) / self.done * (self.todo - self.done)
            self.bar.update(self.done, f"{self.failed} failed, ETA {left:.0f} s" if self.done < self.todo else "")

    def flush(self) -> None:
        """Write the table if rows arrived since the last write."""
        if self.out is not None and self.unwritten:
            start = time.perf_counter()
            write_results(self.table(), self.out)
            end = time.perf_counter()
            self.next_write = end + max(WRITE_INTERVAL_S, (end - start) / WRITE_SHARE)
            self.unwritten = False

    def table(self) -> list[dict]:
        """Rows of sources not in this run first (they stay in the table), then the sources in order."""
        given = set(self.given)
        order = [key for key in self.rows if key not in given] + self.given
        return complete([self.rows[key] for key in order if key in self.rows])

    def result(self) -> list[dict]:
        return complete([self.rows[key] for key in self.given if key in self.rows])


def fit_database(sources, model, *, client=None, batch: int = DEFAULT_BATCH, out=None, resume: bool = True,
                 workers: int | None = None, read_options: dict | None = None, cache_dir=None,
                 progress: bool = False, **fit_options) -> list[dict]:
    """Fit one model (or a per-material selection) to every material of a database, on a Dask cluster.

    Arguments:
        sources: files of any format `brdffit.io.load` reads, folders, globs, ``FILE::GROUP`` names of a
            multi-material brdffit HDF5 file (a file alone stands for all its material groups), or
            `brdffit.distributed.Source` objects (`expand_sources`).
        model: a spec (``"lambert+ggx"``) or `Model` (fitted with `brdffit.fit_many` in batches), ``"auto"`` (a
            `brdffit.select` among the standard candidates for each material: slow), or a sequence of candidate
            specs to select among.
        client: a `distributed.Client`, or a scheduler address (``"tcp://host:8786"``, a cluster started with
            ``dask scheduler`` and ``dask worker``); None starts a LocalCluster on this machine and closes it at
            the end.
        batch: the most materials one task fits together (>= 1).
        out: the results table, ``.h5`` / ``.hdf5`` / ``.csv`` / ``.parquet`` (`brdffit.distributed.table`),
            rewritten atomically as rows arrive (at most once a second, and at the end); None keeps the rows in
            memory only.
        resume: keep the rows already in ``out`` and skip their materials (rows with status ``"error"`` are
            tried again); False starts a new table.
        workers: processes of the LocalCluster started when ``client`` is None (default: one per core).
        read_options: keywords of `brdffit.io.load` for every file (table options, MERL ``subsample``, ...).
        cache_dir: a folder for JAX's persistent compilation cache on the workers (shared by the workers of one
            machine); None leaves the workers' JAX as it is.
        progress: a progress line on stderr: materials done, failures, time, estimated time left.
        **fit_options: keywords of `brdffit.fit_many` (``loss``, ``solver``, ``fixed``, ``max_steps``, ``seed``,
            ...); of `brdffit.fit` for a selection.

    Returns:
        The rows of the given sources, in order, those kept from ``out`` included: dicts with every column of
        the table (`brdffit.distributed.table`; text, or a float that is NaN where the row has no such number).

    Raises:
        ValueError: a bad ``batch``, ``workers``, ``model`` or ``out`` extension; no sources.
        TypeError: an unknown fit option. ImportError: a ``.parquet`` table without pyarrow.
        FileNotFoundError: a source that does not exist.
    """
    if not isinstance(batch, int) or batch < 1:
        raise ValueError(f"batch must be an integer >= 1, got {batch!r}")
    if workers is not None and (not isinstance(workers, int) or workers < 1):
        raise ValueError(f"workers must be an integer >= 1, got {workers!r}")
    if out is not None:
        table_format(out)
    model = _model_argument(model)
    _check_fit_options(fit_options, selecting=not isinstance(model, str))
    items = expand_sources(sources)
    kept = []
    if resume and out is not None and Path(out).exists():
        kept = [row for row in read_results(out) if row["status"] != "error"]
    done = {row["source"] for row in kept}
    todo = [source for source in items if source.key not in done]
    bar = Progress("batch", len(todo), enabled=progress, unit="materials")
    record = _Record(out, [source.key for source in items], kept, bar, len(todo))
    cache = None if cache_dir is None else str(Path(cache_dir).resolve())
    if todo:
        try:
            with _connected(client, workers) as connected:
                _run(connected, todo, model, batch, read_options, fit_options, cache, record)
        finally:  # an interrupted run keeps every row it received
            record.flush()
    rows = record.result()
    bar.close(f"{record.done} fitted ({record.failed} failed), {sum(r['source'] in record.kept for r in rows)} "
              "already done")
    return rows


def cut(items: list, batch: int, workers: int) -> list[list]:
    """``items`` cut, in order, into batches of at most ``batch``, as many as needed rounded up to a multiple of
    ``workers`` (but never more than the items), their sizes differing by at most one: so that the workers end
    together, where batches of ``batch`` and a remainder would leave some workers idle while others fit the last
    batches (7 batches of <= 32 on 2 workers: one worker fits 4, the other 3 and then waits for it).

    Arguments:
        items: what to cut.
        batch: the most items a batch holds (>= 1).
        workers: the cluster's worker threads (>= 1).
    """
    count = min(len(items), -(-math.ceil(len(items) / batch) // workers) * workers)
    if count == 0:
        return []
    size, extra = divmod(len(items), count)
    batches, start = [], 0
    for i in range(count):
        stop = start + size + (i < extra)
        batches.append(items[start:stop])
        start = stop
    return batches


def _run(client, todo: list, model, batch: int, read_options, fit_options: dict, cache, record: _Record) -> None:
    """Submit the batches, record their rows as they arrive, and batch the members of multi-material files."""
    from distributed import as_completed

    label = model if isinstance(model, str) else "auto"
    pending = {}
    # The workers at the start: the members of multi-material files found later are cut for the same count, so
    # that a run whose worker dies cuts the batches as an undisturbed one does (and gets the same numbers).
    workers = max(1, sum(client.nthreads().values()))

    def submit(group: list):
        future = client.submit(fit_batch, group, model, read_options, fit_options, cache, pure=False)
        pending[future] = group
        return future

    arrived = as_completed([submit(group) for group in cut(todo, batch, workers)])
    for future in arrived:
        group = pending.pop(future)
        try:
            rows, members = future.result()
        except Exception as err:  # the batch's workers kept dying (KilledWorker), or the task could not run
            rows, members = [error_row(source.key, error_text(err), label) for source in group], []
        future.release()
        fresh = []
        for path in dict.fromkeys(member.path for member in members):
            mine = [member for member in members if member.path == path]
            new = [member for member in mine if member.key not in record.kept and member.key not in record.given]
            record.expand(path, [member.key for member in mine], len(new))
            fresh.extend(new)
        record.add(rows)
        for group in cut(fresh, batch, workers):
            arrived.add(submit(group))
