"""Delimited text tables (CSV, TSV, whitespace) of BRDF samples, one sample per row.

The canonical layout (what `write_table` writes and `read_table` reads without options)::

    # brdffit table: angles in degrees, values f_r in 1/sr        (comment lines start with '#')
    # brdffit-meta: {"source": ...}                                 (the Measurements' meta as one JSON line)
    theta_i,phi_i,theta_o,phi_o,R,G,B,sigma_R,sigma_G,sigma_B,weights
    30.0,0.0,30.0,180.0,0.31,0.29,0.25,0.01,0.01,0.01,1.0

Angles are in degrees; every other numeric column is a channel named by its header, except ``sigma_<channel>``
(the σ of that channel) and ``weights``. Instrument files are read with a column mapping, e.g. the NIST PTFE file::

    read_table("PTFE.data.csv", columns={"theta_i": "thetai", "phi_i": "phi", "theta_o": "thetar", "phi_o": "phir"},
               values="f_r11", where={"lambda": 0.532})

A negative polar angle means the direction lies at azimuth φ + 180° (a common gonio-reflectometer convention):
θ -> |θ|, φ -> φ + 180°.
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from ..measurements import MeasurementError, Measurements
from ._common import FormatError, atomic_path, decode_text, memory_guarded, parse_meta_json, read_file_bytes

__all__ = ["read_table", "write_table", "ANGLE_COLUMNS", "META_PREFIX"]

ANGLE_COLUMNS = ("theta_i", "phi_i", "theta_o", "phi_o")
WEIGHTS_COLUMN = "weights"
SIGMA_PREFIX = "sigma_"
META_PREFIX = "# brdffit-meta:"
_HEADER_COMMENT = "# brdffit table: angles in degrees, values f_r in 1/sr"
_MISSING = ("", "nan", "NaN", "NAN", "NA", "N/A", "na", "-")


def _parse_float(text: str) -> float | None:
    """The number in a cell, NaN for an empty/missing marker, None if it is not a number.

    Only ASCII numbers are numbers: Python's float() also reads other scripts' digits ('٣٠', full-width '４０') and
    digit groups ('1_000'), which no instrument writes and which would silently change what a cell says.
    """
    if text in _MISSING:
        return math.nan
    if not text.isascii() or "_" in text:
        return None
    try:
        return float(text)
    except ValueError:
        return None


class _Table:
    """The cells of a text table, with the file line of every data row.

    A table whose every cell is a plain ASCII number is held as one array (``block``), its cells split from the
    lines only when a message or a text column needs them (`rows`)."""

    def __init__(self, path, names: list[str] | None, rows: list[list[str]] | None, lines: list[int],
                 comments: list[str], *, block: np.ndarray | None = None, text: list[str] | None = None,
                 delimiter: str | None = None):
        self.path, self.names, self.lines, self.comments = path, names, lines, comments
        self._rows, self._text, self._delimiter = rows, text, delimiter
        self.n_rows = len(lines)
        if block is not None:
            self.n_columns = block.shape[1]
        else:
            self.n_columns = len(rows[0]) if rows else len(names or [])
        self._numbers: dict[int, np.ndarray] = {} if block is None else dict(enumerate(block.T))

    @property
    def rows(self) -> list[list[str]]:
        """The cells of every data row (split on first use where the table was read as one array)."""
        if self._rows is None:
            self._rows = _cells(self.path, self._text, self._delimiter)
        return self._rows

    def label(self, col: int) -> str:
        return f"{col + 1} ({self.names[col]!r})" if self.names else f"{col + 1}"

    def index(self, key, role: str) -> int:
        if isinstance(key, (int, np.integer)) and not isinstance(key, bool):
            if 0 <= int(key) < self.n_columns:
                return int(key)
            raise FormatError(self.path, f"{role}: column index {key} is out of range (the table has "
                                         f"{self.n_columns} columns, numbered from 0)")
        if isinstance(key, str):
            if self.names and key in self.names:
                return self.names.index(key)
            have = f"columns: {', '.join(self.names)}" if self.names else "the file has no header; use indices"
            raise FormatError(self.path, f"{role}: no column {key!r} ({have})")
        raise TypeError(f"{role}: a column is named by its header (str) or its index (int), got {key!r}")

    def _fast_numbers(self, col: int) -> np.ndarray | None:
        """The column as numbers when every cell is a plain ASCII number (the common case): what `_parse_float`
        gives cell by cell, with its checks made once on the whole column instead of once a cell; else None."""
        cells = [row[col] for row in self.rows]
        joined = "\0".join(cells)
        if not joined.isascii() or "_" in joined:
            return None
        try:
            return np.array([float(cell) for cell in cells])
        except ValueError:  # a missing marker or a cell that is not a number: read cell by cell
            return None

    def is_text_column(self, col: int) -> bool:
        """True when no cell of the column reads as a number (a label column such as a material name)."""
        if col in self._numbers:
            return False
        fast = self._fast_numbers(col)
        if fast is not None:
            self._numbers[col] = fast
            return False
        return all(_parse_float(row[col]) is None or row[col] in _MISSING for row in self.rows) and any(
            row[col] not in _MISSING for row in self.rows)

    def numbers(self, col: int, allow_missing: bool = True) -> np.ndarray:
        if col not in self._numbers:
            out = self._fast_numbers(col)
            if out is None:
                out = np.empty(self.n_rows)
                for r, row in enumerate(self.rows):
                    cell = row[col]
                    value = _parse_float(cell)
                    if value is None:
                        raise FormatError(self.path, f"cannot read {cell[:40]!r} as a number", line=self.lines[r],
                                          column=self.label(col))
                    out[r] = value
            self._numbers[col] = out
        out = self._numbers[col]
        if not allow_missing:
            bad = np.flatnonzero(np.isnan(out))
            if bad.size:
                r = int(bad[0])
                raise FormatError(self.path, f"empty or missing cell {self.rows[r][col][:40]!r} where a number is "
                                             "required", line=self.lines[r], column=self.label(col))
        return out


def _split_lines(path, text: str, delimiter: str | None) -> _Table:
    comments, body, numbers = [], [], []
    for lineno, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if not stripped:
            continue
        if stripped.startswith("#"):
            comments.append(stripped)
            continue
        body.append(line)
        numbers.append(lineno)
    if not body:
        raise FormatError(path, "no table rows (the file is empty or holds only comments)")
    if delimiter is None:
        first = body[0]
        if Path(path).suffix.lower() == ".tsv" or "\t" in first:
            delimiter = "\t"
        elif "," in first:
            delimiter = ","
        elif ";" in first:
            delimiter = ";"
    first = _cells(path, body[:1], delimiter)[0]
    header = any(_parse_float(c) is None for c in first)
    names = None
    if header:
        names = [c.strip().strip('"').strip("'") for c in first]
        for k, name in enumerate(names):
            if not name:
                raise FormatError(path, f"header column {k + 1} has no name", line=numbers[0])
        seen = set()
        for k, name in enumerate(names):
            if name in seen:
                raise FormatError(path, f"header names column {name!r} twice", line=numbers[0], column=k + 1)
            seen.add(name)
        body, numbers = body[1:], numbers[1:]
        if not body:
            raise FormatError(path, "a header but no data rows")
    width = len(first)
    block = _numeric_block(body, delimiter, width)
    if block is not None:
        return _Table(path, names, None, numbers, comments, block=block, text=body, delimiter=delimiter)
    cells = _cells(path, body, delimiter)
    for r, row in enumerate(cells):
        if len(row) != width:
            what = "the header" if names else "the first row"
            hint = " (truncated?)" if len(row) < width else ""
            raise FormatError(path, f"{len(row)} cells where {what} has {width}{hint}", line=numbers[r])
    return _Table(path, names, cells, numbers, comments)


def _whitespace(delimiter: str | None) -> bool:
    return delimiter is None or delimiter.isspace() and delimiter != "\t"


def _cells(path, lines: list[str], delimiter: str | None) -> list[list[str]]:
    """The cells of ``lines``: split on whitespace, or read by `csv` (quotes honoured) and stripped."""
    if _whitespace(delimiter):
        return [line.split() for line in lines]
    try:
        cells = [[c.strip() for c in fields] for fields in csv.reader(lines, delimiter=delimiter)]
    except csv.Error as err:
        raise FormatError(path, f"cannot split the table into cells: {err}") from None
    if len(cells) != len(lines):  # a quoted cell ran over a line end
        raise FormatError(path, "a quoted cell is not closed on its line")
    return cells


def _numeric_block(lines: list[str], delimiter: str | None, width: int) -> np.ndarray | None:
    """The rows as one ``(rows, width)`` float array when every line has ``width`` cells and every cell is a plain
    ASCII number (the common case; what `_parse_float` gives cell by cell, parsed by NumPy's C reader
    `numpy.loadtxt`, much faster than parsing cell by cell in Python); else None, and
    the cells are read one by one (missing markers, text columns, quotes, and the messages that name a cell)."""
    text = "\n".join(lines)
    if not text.isascii() or "_" in text or '"' in text or "'" in text:
        return None
    try:
        block = np.loadtxt(lines, delimiter=None if _whitespace(delimiter) else delimiter, comments=None,
                           dtype=float, ndmin=2)
    except ValueError:  # an empty cell, a missing marker, a cell that is not a number, a row of another width
        return None
    return block if block.shape == (len(lines), width) else None


def _read_text(path) -> str:
    path = Path(path)
    return decode_text(path, read_file_bytes(path), "a text table")


def _as_list(x) -> list:
    if x is None:
        return []
    if isinstance(x, (str, int, np.integer)):
        return [x]
    return list(x)


def _where_mask(table: _Table, where: Mapping) -> tuple[np.ndarray, dict]:
    keep = np.ones(table.n_rows, dtype=bool)
    record = {}
    for key, wanted in where.items():
        col = table.index(key, "where")
        name = table.names[col] if table.names else str(col)
        if isinstance(wanted, str):
            cells = np.array([row[col] for row in table.rows], dtype=object)
            match = cells == wanted
            available = sorted(set(cells.tolist()))
        else:
            column = table.numbers(col)
            if callable(wanted):
                match = np.asarray(wanted(column), dtype=bool)
                if match.shape != column.shape:
                    raise ValueError(f"where[{key!r}]: the function must return one bool per row")
                wanted = getattr(wanted, "__name__", "function")
            else:
                targets = np.asarray(_as_list(wanted) if not np.isscalar(wanted) else [wanted], dtype=float)
                match = np.isclose(column[:, None], targets[None, :], rtol=1e-9, atol=1e-12).any(axis=1)
            available = [float(v) for v in np.unique(column[np.isfinite(column)])]
        if not (keep & match).any():
            shown = ", ".join(map(str, available[:12])) + (", ..." if len(available) > 12 else "")
            raise FormatError(table.path, f"no row has {name} = {wanted!r} (values in that column: {shown})")
        keep &= match
        record[name] = wanted if isinstance(wanted, (str, int, float)) else str(wanted)
    return keep, record


@memory_guarded("reading the table")
def _angle_columns(path: Path, table, columns: Mapping | None) -> tuple[dict, dict, int | None]:
    """The angle and weight columns of `read_table`'s ``columns`` mapping (canonical names where a key is not
    given; positions for a file without a header and without a mapping).

    Returns:
        ``(mapping, angle_cols, weights_col)``: the mapping as used, angle name -> column index, and the weights'
        column index (None: no weights).
    """
    mapping = dict(columns or {})
    unknown = set(mapping) - {*ANGLE_COLUMNS, WEIGHTS_COLUMN}
    if unknown:
        raise ValueError(f"columns: unknown key {sorted(unknown)[0]!r}; keys are "
                         f"{', '.join(ANGLE_COLUMNS)} and {WEIGHTS_COLUMN}")
    if table.names is None and not mapping:
        mapping = {name: k for k, name in enumerate(ANGLE_COLUMNS)}
        if table.n_columns < 5:
            raise FormatError(path, f"a table without a header needs the 4 angle columns and at least one value "
                                    f"column; this one has {table.n_columns} columns")
    angle_cols = {}
    for name in ANGLE_COLUMNS:
        key = mapping.get(name, name)
        if table.names is None and isinstance(key, str):
            raise FormatError(path, f"the file has no header, so columns={{{name!r}: <index>}} must give indices")
        angle_cols[name] = table.index(key, f"angle {name}")
    weights_col = None
    if WEIGHTS_COLUMN in mapping:
        weights_col = table.index(mapping[WEIGHTS_COLUMN], "weights")
    elif table.names and WEIGHTS_COLUMN in table.names:
        weights_col = table.names.index(WEIGHTS_COLUMN)
    return mapping, angle_cols, weights_col


def _value_columns(path: Path, table, values, used: set) -> list[int]:
    """The value columns: those named by ``values``, else every numeric column not ``used`` (angles, weights,
    filters, the channel column) and not a σ column; none may be ``used``."""
    if values is None:
        value_cols = [c for c in range(table.n_columns) if c not in used
                      and not (table.names and table.names[c].startswith(SIGMA_PREFIX))
                      and not table.is_text_column(c)]
        if not value_cols:
            raise FormatError(path, "no value column: every column is an angle, weights, sigma or text; name the "
                                    "values with values=[...]")
    else:
        value_cols = [table.index(v, "values") for v in _as_list(values)]
        if not value_cols:
            raise ValueError("values: name at least one value column")
    clash = used & set(value_cols)
    if clash:
        raise ValueError(f"values: column {table.label(sorted(clash)[0])} is also used as an angle, weight or filter")
    return value_cols


def _canonical_angles(theta_i, phi_i, theta_o, phi_o, degrees: bool) -> tuple:
    """The angles in radians with θ ≥ 0 (a negative θ is the same direction at φ + π, the instruments' signed
    in-plane angle) and φ wrapped into [0, 2π), wrapped in the file's unit first so that 186.34° stays the double
    nearest 186.34 (the arrays of θ and φ are changed in place)."""
    half_turn = 180.0 if degrees else math.pi
    for theta, phi in ((theta_i, phi_i), (theta_o, phi_o)):
        flip = theta < 0
        theta[flip] = -theta[flip]
        phi[flip] += half_turn
        phi[:] = np.mod(phi, 2 * half_turn)
    if degrees:
        return tuple(np.radians(a) for a in (theta_i, phi_i, theta_o, phi_o))
    return theta_i, phi_i, theta_o, phi_o


def read_table(path, *, columns: Mapping | None = None, values=None, sigma=None, where: Mapping | None = None,
               channel_column=None, channels: Sequence[str] | None = None, degrees: bool = True,
               delimiter: str | None = None, negative: str = "error", meta: Mapping | None = None) -> Measurements:
    """Read a delimited text table of BRDF samples.

    Arguments:
        path: the file (``.csv``, ``.tsv``, ``.txt``, ...). Lines starting with ``#`` are comments; the first
            other line is a header unless every cell of it is a number.
        columns: where the angles are: ``{"theta_i": "thetai", "phi_i": "phi", "theta_o": "thetar",
            "phi_o": "phir"}`` (header names, or 0-based indices); keys not given take their canonical names
            (``theta_i, phi_i, theta_o, phi_o``, optional ``weights``). A file without a header and without a
            mapping is read positionally: the four angles, then one channel per remaining column.
        values: the value column(s), one channel each (a name or a list). Default: every other numeric column
            (not an angle, ``weights``, ``sigma_*``, a ``where`` or ``channel_column`` column).
        sigma: σ column(s): a name (one value column), a list aligned with ``values``, or a dict
            ``{value column: σ column}``. Default: ``sigma_<value column>`` where it exists; ``False`` ignores σ.
        where: keep only rows where a column has a value: ``{"lambda": 0.532}`` (numbers compare with a relative
            tolerance of 1e-9; a list keeps any of its values; a str compares text; a function of the column array
            returns a boolean mask).
        channel_column: make one channel per distinct value of this column (e.g. ``"lambda"``), pairing rows that
            share the same four angles. Channels are named ``"lambda=0.532"`` (or ``"f_r11@lambda=0.532"`` with
            several value columns); a geometry that lacks a row for some value gets NaN there.
        channels: names for the channels (overrides the header names).
        degrees: whether the angle columns are in degrees (default) or radians.
        delimiter: the cell separator; by default ``"\\t"`` for ``.tsv`` or a tab in the first line, else ``","``,
            else ``";"``, else runs of whitespace.
        negative: ``"error"`` (default) rejects a negative value; ``"missing"`` reads it as missing (NaN).
        meta: entries added to the measurements' meta.

    Returns:
        `Measurements` with ``meta["source"]`` the file (a meta line written by `write_table` is restored too).

    Raises:
        FormatError: an empty, binary or truncated file, a Git LFS pointer, a duplicate or missing column, a cell
            that is not a number (with its line and column), a filter that matches no row.
        MeasurementError: numbers that break the rules of `Measurements` (angles out of range, negative values),
            naming the file line.
    """
    if negative not in ("error", "missing"):
        raise ValueError(f"negative must be 'error' or 'missing', got {negative!r}")
    path = Path(path)
    table = _split_lines(path, _read_text(path), delimiter)
    file_meta = _meta_from_comments(path, table.comments)

    mapping, angle_cols, weights_col = _angle_columns(path, table, columns)
    where = dict(where or {})
    where_cols = {table.index(k, "where") for k in where}
    pivot_col = None if channel_column is None else table.index(channel_column, "channel_column")
    used = set(angle_cols.values()) | where_cols | ({weights_col} - {None}) | ({pivot_col} - {None})
    value_cols = _value_columns(path, table, values, used)

    sigma_cols = _sigma_columns(table, value_cols, sigma)

    keep, where_record = _where_mask(table, where) if where else (np.ones(table.n_rows, dtype=bool), {})
    lines = np.asarray(table.lines)[keep]

    def column(col, allow_missing=True):
        return table.numbers(col, allow_missing)[keep]

    theta_i, phi_i, theta_o, phi_o = (column(angle_cols[n], allow_missing=False) for n in ANGLE_COLUMNS)
    vals = np.stack([column(c) for c in value_cols], axis=1)
    if any(c is None for c in sigma_cols):
        raise ValueError("sigma: give a σ column for every value column or for none")
    sig = np.stack([column(c) for c in sigma_cols], axis=1) if sigma_cols else None
    wts = None if weights_col is None else column(weights_col, allow_missing=False)

    theta_i, phi_i, theta_o, phi_o = _canonical_angles(theta_i, phi_i, theta_o, phi_o, degrees)

    n_negative = 0
    if negative == "missing":
        neg = vals < 0
        n_negative = int(neg.sum())
        vals[neg] = np.nan

    value_names = [table.names[c] if table.names else f"c{k}" for k, c in enumerate(value_cols)]
    if pivot_col is not None:
        theta_i, phi_i, theta_o, phi_o, vals, sig, wts, lines, value_names = _pivot(
            table, column(pivot_col, allow_missing=False), lines, (theta_i, phi_i, theta_o, phi_o), vals, sig, wts,
            value_names, table.names[pivot_col] if table.names else f"column{pivot_col}")
    if channels is not None:
        channels = [channels] if isinstance(channels, str) else list(channels)
        if len(channels) != vals.shape[1]:
            raise ValueError(f"channels: {len(channels)} names for {vals.shape[1]} value columns")
        value_names = channels

    info = dict(file_meta)
    if "source" in info and info["source"] != str(path):
        info.setdefault("derived_from", info["source"])
    info.update({"source": str(path), "format": "table"})
    reader = {"degrees": degrees}
    if columns:
        reader["columns"] = {k: v if isinstance(v, str) else int(v) for k, v in mapping.items()}
    if values is not None:
        reader["values"] = [table.names[c] if table.names else c for c in value_cols]
    if where_record:
        reader["where"] = where_record
    if pivot_col is not None:
        reader["channel_column"] = table.names[pivot_col] if table.names else pivot_col
    if n_negative:
        reader["negative_as_missing"] = n_negative
    info["reader"] = reader
    info.update(meta or {})
    try:
        return Measurements(theta_i, phi_i, theta_o, phi_o, vals, sigma=sig, weights=wts, channels=value_names,
                            meta=info).check_informative()
    except MeasurementError as err:
        column_name = _error_column(err, table, angle_cols, value_cols, sigma_cols, weights_col, pivot_col)
        raise err.with_file(path, lines if err.row is not None else None, column=column_name) from None


def _error_column(err, table, angle_cols, value_cols, sigma_cols, weights_col, pivot_col):
    if not table.names:
        return None
    if err.field in angle_cols:
        return table.names[angle_cols[err.field]]
    if err.field == "weights" and weights_col is not None:
        return table.names[weights_col]
    if err.field in ("values", "sigma") and pivot_col is None and err.channel is not None:
        cols = value_cols if err.field == "values" else sigma_cols
        return table.names[cols[err.channel]]
    return None


def _sigma_columns(table: _Table, value_cols: list[int], sigma) -> list[int | None]:
    if sigma is False:
        return []
    if sigma is None:
        if not table.names:
            return []
        found = [table.names.index(SIGMA_PREFIX + table.names[c]) if SIGMA_PREFIX + table.names[c] in table.names
                 else None for c in value_cols]
        if any(c is not None for c in found) and any(c is None for c in found):
            lacking = table.names[value_cols[found.index(None)]]
            raise FormatError(table.path, f"sigma columns for some channels but no {SIGMA_PREFIX + lacking!r}; give "
                                          "every channel its sigma column, or none (or read with sigma=False)")
        return found if any(c is not None for c in found) else []
    if isinstance(sigma, Mapping):
        by_value = {table.index(k, "sigma"): table.index(v, "sigma") for k, v in sigma.items()}
        unknown = set(by_value) - set(value_cols)
        if unknown:
            raise ValueError(f"sigma: column {table.label(sorted(unknown)[0])} is not a value column")
        return [by_value.get(c) for c in value_cols]
    cols = [table.index(s, "sigma") for s in _as_list(sigma)]
    if len(cols) != len(value_cols):
        raise ValueError(f"sigma: {len(cols)} σ columns for {len(value_cols)} value columns")
    return cols


def _pivot(table, key, lines, angles, vals, sig, wts, value_names, pivot_name):
    levels = np.unique(key)
    if np.isnan(levels).any():
        raise FormatError(table.path, f"channel_column {pivot_name!r} has empty cells")
    raw = np.stack(angles, axis=1)
    geometry, first, inverse = np.unique(raw, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    order = np.argsort(first, kind="stable")  # geometries in order of first appearance
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    slot = rank[inverse]
    level = np.searchsorted(levels, key)
    n_geo, n_lev, n_val = len(order), len(levels), vals.shape[1]
    occupied = np.zeros((n_geo, n_lev), dtype=bool)
    for r, (g, k) in enumerate(zip(slot, level)):
        if occupied[g, k]:
            raise FormatError(table.path, f"two rows with {pivot_name} = {levels[k]:.12g} at the same angles "
                                          "(cannot make channels from them)", line=int(lines[r]))
        occupied[g, k] = True
    out = np.full((n_geo, n_lev, n_val), np.nan)
    out[slot, level] = vals
    out_sig = None
    if sig is not None:
        out_sig = np.full((n_geo, n_lev, n_val), np.nan)
        out_sig[slot, level] = sig
        out_sig = out_sig.reshape(n_geo, n_lev * n_val)
    geo_rows = first[order]
    names = [f"{pivot_name}={lev:.12g}" if n_val == 1 else f"{v}@{pivot_name}={lev:.12g}"
             for lev in levels for v in value_names]
    new_angles = tuple(a[geo_rows] for a in angles)
    return (*new_angles, out.reshape(n_geo, n_lev * n_val), out_sig, None if wts is None else wts[geo_rows],
            lines[geo_rows], names)


def _meta_from_comments(path, comments: list[str]) -> dict:
    meta = {}
    for line in comments:
        if line.startswith(META_PREFIX):
            meta = parse_meta_json(path, line[len(META_PREFIX):], f"the {META_PREFIX!r} line")
            if not isinstance(meta, dict):
                raise FormatError(path, f"the {META_PREFIX!r} line must hold a JSON object")
    others = [c for c in comments if not c.startswith(META_PREFIX) and c != _HEADER_COMMENT]
    if others:
        meta.setdefault("comments", [c.lstrip("#").strip() for c in others])
    return meta


def _format(x: float) -> str:
    return "nan" if math.isnan(x) else repr(x)


def _format_angles(radians: np.ndarray) -> list[str]:
    """Degrees as text, as short as possible while reading back (× π/180) to the very same radians.

    Tries 15, 16 and 17 significant digits of the degrees, then the neighbouring doubles; when none is exact
    (rare) the 17-digit text is kept, which reads back within an ulp.
    """
    degrees = np.degrees(radians)
    out = np.array([repr(d) for d in degrees.tolist()], dtype=object)
    todo = np.ones(len(degrees), dtype=bool)
    candidates = [(degrees, digits) for digits in (15, 16, 17)]
    candidates += [(np.nextafter(degrees, np.inf), 17), (np.nextafter(degrees, -np.inf), 17)]
    for values, digits in candidates:
        rows = np.flatnonzero(todo)
        if not rows.size:
            break
        text = np.array([f"{d:.{digits}g}" for d in values[rows].tolist()], dtype=object)
        exact = np.radians(text.astype(float)) == radians[rows]
        out[rows[exact]] = text[exact]
        todo[rows[exact]] = False
    return out.tolist()


def write_table(measurements: Measurements, path, *, delimiter: str | None = None, write_meta: bool = True) -> None:
    """Write measurements in the canonical table layout (angles in degrees), atomically.

    Arguments:
        measurements: the `Measurements`.
        path: the file; ``.tsv`` gets tabs, anything else commas.
        delimiter: override the separator.
        write_meta: write the meta as a ``# brdffit-meta: {...}`` comment line (restored by `read_table`).

    Values are written with Python's shortest round-trip repr, so they come back exactly; angles are written in
    degrees with 15 significant digits where that converts back to the very same radians (almost always), else
    with 17; missing values are written as ``nan``.
    """
    if not isinstance(measurements, Measurements):
        raise TypeError(f"expected brdffit.Measurements, got {type(measurements).__name__}")
    m = measurements
    path = Path(path)
    if delimiter is None:
        delimiter = "\t" if path.suffix.lower() == ".tsv" else ","
    reserved = set(ANGLE_COLUMNS) | {WEIGHTS_COLUMN}
    for name in m.channels:
        if name in reserved or name.startswith(SIGMA_PREFIX) or name.startswith("#"):
            raise ValueError(f"channel name {name!r} clashes with the canonical layout (angles, 'weights', "
                             "'sigma_*', '#'); rename it with m.replace(channels=...)")
    header = [*ANGLE_COLUMNS, *m.channels]
    cols = list(m.values.T)
    if m.sigma is not None:
        header += [SIGMA_PREFIX + c for c in m.channels]
        cols += list(m.sigma.T)
    if m.weights is not None:
        header.append(WEIGHTS_COLUMN)
        cols.append(m.weights)
    text_cols = [_format_angles(a) for a in (m.theta_i, m.phi_i, m.theta_o, m.phi_o)]
    text_cols += [[_format(x) for x in col.tolist()] for col in cols]
    with atomic_path(path, suffix=path.suffix or ".tmp") as tmp:
        with open(tmp, "w", newline="", encoding="utf-8") as fh:
            fh.write(_HEADER_COMMENT + "\n")
            if write_meta:
                fh.write(f"{META_PREFIX} {json.dumps(m.meta, sort_keys=True)}\n")
            writer = csv.writer(fh, delimiter=delimiter, lineterminator="\n")
            writer.writerow(header)
            writer.writerows(zip(*text_cols))

