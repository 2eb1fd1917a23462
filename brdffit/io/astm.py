r"""ASTM E1392 BRDF data: the exchange format of ASTM E1392 ("Standard Practice for Angle Resolved Optical Scatter
Measurements on Specular or Diffuse Surfaces"), in which the Cornell gonioreflectometer data that Lafortune et al.
(1997) fitted and many instruments' exports are written.

What we read and write::

    SOURCE "Cornell University Program of Computer Graphics"   (keyword lines: KEYWORD then its value)
    SAMPLE_NAME "blue paint"
    NUM_POINTS 1439
    VARS theta_i,phi_i,theta_s,phi_s,400nm,410nm,...            (the columns; the last keyword line)
    0.0,0.0,0.1745,3.1416,0.0213,0.0220,...                     (one sample per row)

- **Header.** Every line before ``VARS`` is ``KEYWORD value``; the keywords (``LAB_NAME``, ``SAMPLE_NAME``,
  ``MEAS_NAME``, ``SOURCE``, ``NUM_POINTS``, ...) are kept in ``meta["astm"]["header"]`` and written back.
  ``NUM_POINTS``, where given, must equal the number of rows read (fewer: the file is truncated).
- **Columns.** ``VARS`` names them, separated by commas or whitespace: θi, φi, θs, φs first (``theta_i``,
  ``phi_i``, ``theta_s`` or ``theta_r``, ``phi_s`` or ``phi_r``; s is the scattered direction, brdffit's ωo), then
  one column per channel: a wavelength band (``400nm``, or ``400``) keeps its wavelength (``meta["wavelengths_nm"]``,
  channels named ``400nm``), ``R, G, B`` or any other name are channels of that name. Values are f_r in 1/sr.
- **Rows.** Numbers separated by commas or whitespace, as many as ``VARS`` names; an empty cell or a missing
  marker (``NaN``, ``NA``, as the CSV reader takes them) in a band column is a missing value (NaN); the angles must
  be numbers. Only plain ASCII numbers are numbers (`brdffit.io.table`: not ``1_000``, not other scripts' digits).
- **Angles.** The standard's files (and Cornell's) give radians, θ in [0, π/2]; files from some instruments give
  degrees. ``degrees=None`` decides from the data: radians when every |θ| ≤ π/2 and every |φ| ≤ 2π, degrees when
  some |θ| exceeds π/2 but none 90°, and says which it assumed in ``meta["read"]["angles"]``; ``degrees=True`` or
  ``False`` (``--degrees``, ``--radians``) decides instead. A negative θ (in-plane data with signed angles) is the
  direction at |θ| on the other side of the normal: φ + π.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from ..measurements import MeasurementError, Measurements
from ._common import FormatError, atomic_path, decode_text, memory_guarded, read_file_bytes
from .table import _canonical_angles, _numeric_block, _parse_float

__all__ = ["read_astm", "write_astm", "looks_like_astm", "ANGLE_COLUMNS"]

# The names a VARS line may give each angle column, in order (the first is what brdffit writes).
ANGLE_COLUMNS = (("theta_i",), ("phi_i",), ("theta_s", "theta_r", "theta_o"), ("phi_s", "phi_r", "phi_o"))
_KEYWORD = re.compile(r"^\s*([A-Za-z_][A-Za-z0-9_]*)(?:\s+(.*?))?\s*$")
_VARS = re.compile(rb"^\s*VARS[ \t]", re.MULTILINE)
_BAND = re.compile(r"^(\d+(?:\.\d+)?)\s*(nm)?$", re.IGNORECASE)
_SPLIT = re.compile(r"\s*,\s*|\s+")
_ANGLE_TOLERANCE = 1e-6


def looks_like_astm(head: bytes) -> bool:
    """Whether a file's first bytes are ASTM E1392 data: a ``VARS`` keyword line."""
    return b"\0" not in head and _VARS.search(head) is not None


def _cells(line: str) -> list[str]:
    """A row's cells: comma-separated (an empty cell kept) or, without commas, whitespace-separated."""
    if "," in line:
        return [cell.strip() for cell in line.strip().split(",")]
    return line.split()


def _channel(name: str):
    """A VARS channel name -> (channel name, wavelength in nm or None)."""
    band = _BAND.match(name)
    if band:
        wavelength = float(band.group(1))
        return f"{band.group(1)}nm", wavelength
    return name, None


@memory_guarded("ASTM E1392 data")
def read_astm(path, *, degrees: bool | None = None) -> Measurements:
    """Read an ASTM E1392 BRDF file (module docstring).

    Arguments:
        path: the file (``.astm``, or any file whose content has a ``VARS`` line).
        degrees: the angles' unit: None decides from the data (module docstring), True degrees, False radians.

    Returns:
        `Measurements`; ``meta["format"]`` is ``"astm"``, ``meta["astm"]`` holds the header keywords (``header``)
        and the column names (``vars``), ``meta["wavelengths_nm"]`` the bands' wavelengths where every channel is a
        band, ``meta["read"]`` what the reading did (``angles``: the unit and why).

    Raises:
        FileNotFoundError: no such file.
        FormatError: an empty or binary file, no ``VARS`` line, fewer than five columns or angle columns not named
            as the standard names them, a row with another number of cells than ``VARS`` names (its line), a cell
            that is not a number (its line and column), a ``NUM_POINTS`` the rows do not match, angles out of range
            for the unit given.
        MeasurementError: values that break the rules of `Measurements` (negative f_r), naming the file line.
    """
    path = Path(path)
    text = decode_text(path, read_file_bytes(path), "ASTM E1392 data")
    header: dict[str, str] = {}
    names: list[str] | None = None
    rows, lines = [], []
    for number, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        if names is None:
            match = _KEYWORD.match(line)
            if not match:
                raise FormatError(path, f"a header line that is not 'KEYWORD value': {line.strip()[:60]!r}",
                                  line=number)
            keyword, value = match.group(1), (match.group(2) or "")
            if keyword.upper() == "VARS":
                names = [n for n in _SPLIT.split(value.strip()) if n]
                _check_vars(path, names, number)
            else:
                header[keyword] = value.strip().strip('"')
            continue
        rows.append(_cells(line))
        lines.append(number)
    if names is None:
        raise FormatError(path, "no VARS line: an ASTM E1392 file names its columns in a line 'VARS theta_i,phi_i,"
                                "theta_s,phi_s,<channel>,...' before its rows")
    if not rows:
        raise FormatError(path, "a header but no data rows")
    data = _numbers(path, rows, lines, names)
    declared = header.get("NUM_POINTS")
    if declared is not None:
        try:
            expected = int(declared)
        except ValueError:
            raise FormatError(path, f"NUM_POINTS {declared!r} is not a whole number") from None
        if expected != len(rows):
            raise FormatError(path, f"NUM_POINTS says {expected} rows but the file has {len(rows)}"
                                    + (" (truncated?)" if len(rows) < expected else ""))
    degrees, unit = _unit(path, data[:, :4], degrees)
    theta_i, phi_i, theta_o, phi_o = _canonical_angles(*(np.array(data[:, k]) for k in range(4)), degrees)
    channels, wavelengths = zip(*(_channel(n) for n in names[4:]))
    meta = {"source": str(path), "format": "astm", "astm": {"header": header, "vars": list(names)},
            "read": {"rows": len(rows), "angles": unit}}
    if all(w is not None for w in wavelengths):
        meta["wavelengths_nm"] = [float(w) for w in wavelengths]
    try:
        return Measurements(theta_i, phi_i, theta_o, phi_o, data[:, 4:], channels=list(channels), meta=meta)
    except MeasurementError as err:
        raise err.with_file(path, np.asarray(lines) if err.row is not None else None) from None


def _check_vars(path, names: list[str], line: int) -> None:
    """The VARS line names the four angles, in the standard's order, then at least one channel."""
    if len(names) < 5:
        raise FormatError(path, f"VARS names {len(names)} columns ({', '.join(names) or 'none'}); it needs the four "
                                "angles theta_i, phi_i, theta_s, phi_s and at least one value column", line=line)
    for k, (name, allowed) in enumerate(zip(names[:4], ANGLE_COLUMNS)):
        if name.lower() not in allowed:
            raise FormatError(path, f"VARS column {k + 1} is {name!r}; the standard's angle columns are "
                                    "theta_i, phi_i, theta_s (or theta_r), phi_s (or phi_r), in that order", line=line)


def _numbers(path, rows: list[list[str]], lines: list[int], names: list[str]) -> np.ndarray:
    """The rows as numbers (`brdffit.io.table`'s rules: NumPy's reader where every cell is a plain number, else
    cell by cell): a missing cell in a value column is NaN; a row of another width, or anything else not a number,
    is an error naming the line and column."""
    for cells, line in zip(rows, lines):
        if len(cells) != len(names):
            raise FormatError(path, f"{len(cells)} cells where VARS names {len(names)} ({', '.join(names)})"
                                    + (" (truncated?)" if len(cells) < len(names) else ""), line=line)
    block = _numeric_block([",".join(cells) for cells in rows], ",", len(names))
    if block is not None:
        out = block
    else:
        out = np.empty((len(rows), len(names)))
        for i, (cells, line) in enumerate(zip(rows, lines)):
            for k, cell in enumerate(cells):
                value = _parse_float(cell)
                if value is None:
                    raise FormatError(path, f"cannot read {cell[:40]!r} as a number", line=line,
                                      column=f"{k + 1} ({names[k]!r})")
                out[i, k] = value
    bad = ~np.isfinite(out[:, :4])
    if bad.any():
        i, k = np.argwhere(bad)[0]
        raise FormatError(path, f"angle {names[k]} is {rows[i][k]!r}: the angles must be numbers", line=lines[i],
                          column=f"{k + 1} ({names[k]!r})")
    return out


def _unit(path, angles: np.ndarray, degrees: bool | None) -> tuple[bool, str]:
    """Whether the angles are degrees, and the unit assumed with why (module docstring)."""
    theta, phi = np.abs(angles[:, [0, 2]]), np.abs(angles[:, [1, 3]])
    fits_radians = theta.max() <= math.pi / 2 + _ANGLE_TOLERANCE and phi.max() <= 2 * math.pi + _ANGLE_TOLERANCE
    fits_degrees = theta.max() <= 90.0 + _ANGLE_TOLERANCE and phi.max() <= 360.0 + _ANGLE_TOLERANCE
    if degrees is None:
        if fits_radians:
            degrees, unit = False, ("radians, as the standard writes them (every |θ| ≤ π/2 and |φ| ≤ 2π; give "
                                    "degrees=True, --degrees, if they are degrees)")
        elif fits_degrees:
            degrees, unit = True, (f"degrees (some |θ| reaches {theta.max():.4g} > π/2, none beyond 90; give "
                                   "degrees=False, --radians, to refuse them)")
        else:
            raise FormatError(path, f"the angles fit neither radians (|θ| ≤ π/2, |φ| ≤ 2π) nor degrees (|θ| ≤ 90, "
                                    f"|φ| ≤ 360): largest |θ| {theta.max():.6g}, largest |φ| {phi.max():.6g}")
    elif degrees and not fits_degrees or not degrees and not fits_radians:
        limit = "90, |φ| ≤ 360 degrees" if degrees else "π/2, |φ| ≤ 2π radians"
        raise FormatError(path, f"angles given in {'degrees' if degrees else 'radians'} must have |θ| ≤ {limit}: "
                                f"largest |θ| {theta.max():.6g}, largest |φ| {phi.max():.6g}")
    else:
        unit = f"{'degrees' if degrees else 'radians'} (as given)"
    return degrees, unit


def write_astm(measurements: Measurements, path) -> None:
    """Write measurements as an ASTM E1392 file, atomically: the header keywords of a file read before
    (``meta["astm"]["header"]``) with ``NUM_POINTS`` set to the rows written, ``VARS`` with the standard's angle
    names and the channel names (a band as ``400nm``), the angles in radians, a missing value as an empty cell.

    Arguments:
        measurements: the `Measurements`.
        path: the file (``.astm`` by convention).
    """
    m = measurements
    header = dict((m.meta.get("astm") or {}).get("header") or {})
    header.setdefault("SOURCE", "brdffit")
    header["NUM_POINTS"] = str(m.n)
    lines = [f"{key} {_quoted(value)}" for key, value in header.items()]
    lines.append("VARS " + ",".join([names[0] for names in ANGLE_COLUMNS] + [str(c) for c in m.channels]))
    angles = np.stack([np.asarray(a, dtype=float) for a in (m.theta_i, m.phi_i, m.theta_o, m.phi_o)], axis=1)
    values = np.asarray(m.values, dtype=float)
    for a, v in zip(angles, values):
        lines.append(",".join([repr(float(x)) for x in a] + ["" if math.isnan(x) else repr(float(x)) for x in v]))
    with atomic_path(path) as tmp:
        Path(tmp).write_text("\n".join(lines) + "\n", encoding="utf-8")


def _quoted(value: str) -> str:
    """A header value as the standard's files write text: quoted where it has spaces."""
    return f'"{value}"' if re.search(r"\s", value) and not value.replace(".", "").isdigit() else value
