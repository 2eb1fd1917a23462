"""The results table of a database fit: one row per material, stored as ``.h5``, ``.csv`` or ``.parquet``, every
write atomic (a temporary file beside the target, renamed into place; `brdffit.io._common.atomic_path`).

Columns (docs/batch.md): ``source``, ``status`` (a fit status of `brdffit.fitting.status.STATUSES`, or
``"error"``), ``model``, ``error`` (the message of a failed material, else empty), ``time`` (seconds: the
material's share of its batch), ``n_samples``, ``cost``, ``aic``, ``bic``, ``steps``; then each parameter as
``name`` (a shape parameter) or ``name[i]`` (one per channel), as `brdffit.Posterior.to_dict` names them; its
standard error as ``stderr.name[i]``; each metric per channel as ``rmse_rel[i]``, ... A number a row lacks (a
parameter of another model, every number of a failed material) is NaN (an empty CSV cell).

In HDF5 the table is the group ``/batch`` of a brdffit file: one dataset per column (UTF-8 strings or float64),
the column order in the attribute ``columns`` (JSON). Parquet needs pyarrow (``pip install 'brdffit[parquet]'``).
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np

from ..io._common import FormatError, atomic_path

__all__ = ["TABLE_FORMATS", "TEXT_COLUMNS", "LEADING_COLUMNS", "TABLE_GROUP", "table_format", "columns",
           "complete", "write_results", "read_results"]

TABLE_FORMATS = {".h5": "hdf5", ".hdf5": "hdf5", ".csv": "csv", ".parquet": "parquet"}
TEXT_COLUMNS = ("source", "status", "model", "error")
LEADING_COLUMNS = TEXT_COLUMNS + ("time", "n_samples", "cost", "aic", "bic", "steps")
TABLE_GROUP = "batch"


def _pyarrow():
    try:
        import pyarrow
        import pyarrow.parquet  # noqa: F401  (binds pyarrow.parquet)
    except ImportError:
        raise ImportError("a .parquet results table needs pyarrow: pip install 'brdffit[parquet]' (or pyarrow), or "
                          "write .h5 or .csv") from None
    return pyarrow


def table_format(path) -> str:
    """The storage of a results table path: ``"hdf5"``, ``"csv"`` or ``"parquet"``.

    Raises:
        ValueError: another extension. ImportError: ``.parquet`` without pyarrow installed.
    """
    ext = Path(path).suffix.lower()
    if ext not in TABLE_FORMATS:
        raise ValueError(f"{path}: a results table is {', '.join(TABLE_FORMATS)}, not {ext or '(no extension)'!r}")
    if TABLE_FORMATS[ext] == "parquet":
        _pyarrow()
    return TABLE_FORMATS[ext]


def columns(rows) -> list[str]:
    """The table's columns: `LEADING_COLUMNS`, then every other column in the order rows first name it."""
    names = dict.fromkeys(LEADING_COLUMNS)
    for row in rows:
        names.update(dict.fromkeys(row))
    return list(names)


def _column(rows, name: str) -> list:
    if name in TEXT_COLUMNS:
        return [str(row.get(name, "")) for row in rows]
    return [float(row.get(name, math.nan)) for row in rows]


def complete(rows) -> list[dict]:
    """The rows with every column of the table, in its order: "" for missing text, NaN for a missing number (as
    `read_results` gives them back)."""
    rows = list(rows)
    names = columns(rows)
    return _rows({name: _column(rows, name) for name in names}, names)


def write_results(rows, path) -> None:
    """Write the rows (dicts column -> text or number) to ``path``, replacing it atomically.

    Arguments:
        rows: the rows, in order.
        path: ``.h5`` / ``.hdf5`` (the group ``/batch``; other groups of an existing brdffit file are kept),
            ``.csv`` or ``.parquet``.

    Raises:
        ValueError, ImportError: see `table_format`. FormatError: an existing ``.h5`` that is not a brdffit file.
    """
    rows = list(rows)
    kind = table_format(path)
    names = columns(rows)
    if kind == "hdf5":
        from ..io.hdf5 import update_hdf5

        def write(group):
            import h5py

            group.attrs["columns"] = json.dumps(names)
            for name in names:
                values = _column(rows, name)
                if name in TEXT_COLUMNS:
                    group.create_dataset(name, data=np.array(values, dtype=object), dtype=h5py.string_dtype())
                else:
                    group.create_dataset(name, data=np.array(values, dtype=np.float64))

        update_hdf5(path, TABLE_GROUP, write)
    elif kind == "csv":
        with atomic_path(path, suffix=".csv") as tmp, open(tmp, "w", newline="", encoding="utf-8") as fh:
            writer = csv.writer(fh)
            writer.writerow(names)
            table = [_column(rows, name) for name in names]
            for cells in zip(*table):
                # repr keeps every digit of a float (a read gives the same number back); NaN is an empty cell.
                writer.writerow(["" if isinstance(c, float) and math.isnan(c) else (repr(c) if isinstance(c, float)
                                                                                    else c) for c in cells])
    else:
        pa = _pyarrow()
        table = pa.table({name: pa.array(_column(rows, name)) for name in names})
        with atomic_path(path, suffix=".parquet") as tmp:
            pa.parquet.write_table(table, tmp)


def _rows(table: dict, names: list[str]) -> list[dict]:
    size = len(table[names[0]]) if names else 0
    return [{name: table[name][i] for name in names} for i in range(size)]


def read_results(path) -> list[dict]:
    """The rows of a results table written by `write_results` (numbers as float, NaN where a row has none).

    Raises:
        FileNotFoundError: no such file. FormatError: a file that is not a results table. ValueError, ImportError:
            see `table_format`.
    """
    kind = table_format(path)
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file")
    if kind == "hdf5":
        from ..io.hdf5 import read_hdf5_group

        def read(group):
            names = json.loads(group.attrs["columns"])
            return _rows({name: (group[name].asstr()[()].tolist() if name in TEXT_COLUMNS
                                 else group[name][()].astype(float).tolist()) for name in names}, names)

        return read_hdf5_group(path, TABLE_GROUP, read)
    if kind == "csv":
        with open(path, newline="", encoding="utf-8") as fh:
            reader = csv.reader(fh)
            names = next(reader, None)
            if not names or "source" not in names:
                raise FormatError(path, "not a results table: the first line names no 'source' column")
            rows = []
            for line, cells in enumerate(reader, start=2):
                if len(cells) != len(names):
                    raise FormatError(path, f"{len(cells)} cells where the header names {len(names)}", line=line)
                row = {}
                for name, cell in zip(names, cells):
                    if name in TEXT_COLUMNS:
                        row[name] = cell
                        continue
                    try:
                        row[name] = float(cell) if cell else math.nan
                    except ValueError:
                        raise FormatError(path, f"{cell!r} is not a number", line=line, column=name) from None
                rows.append(row)
            return rows
    pa = _pyarrow()
    try:
        table = pa.parquet.read_table(path)
    except pa.ArrowException as err:
        raise FormatError(path, f"cannot be read as Parquet: {err}") from None
    if "source" not in table.column_names:
        raise FormatError(path, "not a results table: no 'source' column")
    return _rows(table.to_pydict(), table.column_names)
