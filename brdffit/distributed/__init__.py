"""Fitting a whole database on Dask distributed (docs/batch.md), one concept per module:

- `sources`: what is read: a file per material, or the material groups of a multi-material HDF5 file;
- `tasks`: what the workers do: read shapes, fit a batch of equally shaped materials, make rows;
- `table`: the results table (``.h5``, ``.csv``, ``.parquet``), written atomically;
- `database`: `fit_database`, the client that plans the batches and records the rows, and its local cluster;
- `affinity`: the local cluster's cores shared out among its workers.

The public names are imported on first use (`brdffit._lazy`), so that importing brdffit never loads Dask.
"""

from .._lazy import exports as _exports

# The most materials of one task (`fit_database`'s ``batch``, the CLI's ``--batch``): declared here, where the CLI
# reads it without loading Dask. Larger batches share a task's reading, scheduling and the engine's per-batch work
# among more materials (docs/benchmarks.md compares batch sizes); a task's `fit_many` calls are bounded in samples
# (`brdffit.distributed.tasks.FIT_SAMPLES`), so the batch does not bound memory.
DEFAULT_BATCH = 128

_PUBLIC = {"fit_database": "database:fit_database",
           "Source": "sources:Source", "expand_sources": "sources:expand_sources",
           "read_results": "table:read_results", "write_results": "table:write_results",
           "TABLE_FORMATS": "table:TABLE_FORMATS"}
_exports(__name__, _PUBLIC)

__all__ = sorted(_PUBLIC) + ["DEFAULT_BATCH"]
