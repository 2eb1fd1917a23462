r"""ALTA text data: the sample files of the ALTA BRDF library (belcour/alta, MPL-2.0).

What we read and write, as ALTA's sources define it (``documents/data-formats.dox``, ``sources/core/params.h``,
``sources/core/params.cpp``, ``sources/core/data_storage.cpp``)::

    #URL https://...                     (any '#KEY value' line is a header entry; '# text' is a comment)
    #DIM 3 1                             (number of input columns, number of output columns)
    #PARAM_IN ISOTROPIC_TL_TV_PROJ_DPHI  (what the input columns mean)
    #PARAM_OUT INV_STERADIAN             (what the output columns mean)
    #VS 0                                (error bars: 0 none, 1 one radius, 2 a distance below and one above)
    0.2618 0.2618 0.0 72.4568            (one sample per row: inputs, outputs, error bars)

Header lines come before the first data row (``#ALTA END HEADER`` also ends the header); blank lines are skipped.

**Directions.** ALTA's local frame is ours (z the normal, x the tangent); L is the light (our ωi), V the view (ωo).
Input parameterisations read and written:

| ``#PARAM_IN`` | columns | directions |
|---|---|---|
| ``SPHERICAL_TL_PL_TV_PV`` | θl, φl, θv, φv | as they are |
| ``CARTESIAN`` | Vx, Vy, Vz, Lx, Ly, Lz | **V first** (``params.h``: "we always pack the view vector first") |
| ``ISOTROPIC_TL_TV_PROJ_DPHI`` | θl, θv·cosΔφ, θv·sinΔφ | φl = 0, θv the norm of the last two, φv = Δφ their atan2 |
| ``RUSIN_TH_TD_PD`` | θh, θd, φd | φh = 0; ALTA's difference vector is V in the half-vector frame |

The last two are isotropic: they fix an azimuth (φl = 0, φh = 0), so writing turns each pair about the normal into
that position. ``ISOTROPIC_TL_TV_PROJ_DPHI`` follows ALTA's ``params::to_cartesian``, which puts L at φ = 0 and V at
azimuth atan2(x₂, x₁), i.e. Δφ = φv − φl (its ``from_cartesian`` uses φl − φv, the mirror image, which an isotropic
BRDF does not see). ``RUSIN_TH_TD_PD`` follows ``params::half_to_cartesian``: V = Rot_z(φh) Rot_y(θh) d(θd, φd) and L
its mirror image about h, so ALTA's (θd, φd) are Rusinkiewicz's (1998) angles of ωo where brdffit's are those of ωi
(brdffit's φd = ALTA's φd + π); `brdffit.geometry.from_half_diff` computes it with the roles swapped.

**Values.** ``INV_STERADIAN``: f_r in 1/sr, any number of outputs; ``RGB_COLOR`` and ``XYZ_COLOR``: three outputs,
channels ``R, G, B`` or ``X, Y, Z``; ``INV_STERADIAN_COSINE_FACTOR``: f_r · cosθv ("weighted by the cosine factor of
the output direction", ``params.h``), divided back here; a row with V at or below the horizon (θv >= π/2 − 1e-9),
where that division has no value, is read as missing (NaN). A file without ``#PARAM_OUT`` is read as
``INV_STERADIAN`` (the CEA retro-reflection files publish the same measurement with and without that line).

**Error bars (``#VS k``).** After the outputs a row holds k numbers per output (ALTA's own reader takes them for the
first output only and gives the others a default; we read one set per output, as its documentation describes):
k = 1 is a radius r (the interval [y − r, y + r]), k = 2 a distance below a and one above b (the interval
[y − a, y + b], ALTA's reading since its commit 302c046 of 2017; before, the two numbers were the bounds themselves).
σ is half the interval: r, or (a + b)/2. ``#VS`` may repeat its k for every output (``#VS 2 2 2``).
"""

from __future__ import annotations

import dataclasses
import json
import math
import re
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from ..arrays import jitted, padded_columns
from ..measurements import THETA_TOLERANCE, MeasurementError, Measurements, _default_channels
from ._common import FormatError, atomic_path, decode_text, memory_guarded, read_file_bytes

__all__ = ["read_alta", "write_alta", "looks_like_alta", "PARAM_IN", "PARAM_OUT"]

_STRUCTURE = ("DIM", "PARAM_IN", "PARAM_OUT", "VS")
_CHANNELS_KEY = "BRDFFIT_CHANNELS"  # brdffit's own header entry: the channel names (ALTA keeps unknown keys)
_DEFAULT_OUT = "INV_STERADIAN"
_HEADER_BYTES = 4096  # where a '#FORMAT binary' line is looked for (the CEA files' headers take 150 bytes)


# ------------------------------------------------------------------------------------ input parameterisations
def _polar(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """θ and φ of vectors ``v`` (N, 3), not necessarily unit: θ = atan2(|v_xy|, v_z) is accurate at every angle."""
    return np.arctan2(np.hypot(v[:, 0], v[:, 1]), v[:, 2]), np.arctan2(v[:, 1], v[:, 0])


def _spherical_in(x):
    return x[:, 0], x[:, 1], x[:, 2], x[:, 3]


def _spherical_out(m: Measurements):
    return np.stack([m.theta_i, m.phi_i, m.theta_o, m.phi_o], axis=1)


def _cartesian_in(x):
    return (*_polar(x[:, 3:6]), *_polar(x[:, 0:3]))


def _cartesian_out(m: Measurements):
    return np.concatenate([m.wo(), m.wi()], axis=1)


def _cartesian_check(x) -> tuple[int, str] | None:
    """The first row whose V or L is not a unit vector (within 1e-3: files written with ~6 digits pass)."""
    for k, name in ((0, "V"), (3, "L")):
        norm = np.linalg.norm(x[:, k:k + 3], axis=1)
        bad = np.flatnonzero(~(np.abs(norm - 1.0) <= 1e-3))
        if bad.size:
            r = int(bad[0])
            return r, f"CARTESIAN {name} = {x[r, k:k + 3].tolist()} is not a unit vector (norm {norm[r]:.6g})"
    return None


def _projected_in(x):
    # params.cpp, to_cartesian(ISOTROPIC_TL_TV_PROJ_DPHI): L = (sin θl, 0, cos θl); V has polar angle
    # θ = |(x₁, x₂)| and azimuth atan2(x₂, x₁).
    return x[:, 0], np.zeros(len(x)), np.hypot(x[:, 1], x[:, 2]), np.arctan2(x[:, 2], x[:, 1])


def _projected_out(m: Measurements):
    dphi = m.phi_o - m.phi_i
    return np.stack([m.theta_i, m.theta_o * np.cos(dphi), m.theta_o * np.sin(dphi)], axis=1)


def _rusin_in(x):
    from ..geometry import from_half_diff

    # params.h, half_to_cartesian(θh, φh = 0, θd, φd): the rotated difference vector is V, its mirror about h is L.
    theta_o, phi_o, theta_i, phi_i = padded_columns(jitted(from_half_diff), x[:, 0], np.zeros(len(x)), x[:, 1],
                                                    x[:, 2])
    return theta_i, phi_i, theta_o, phi_o


def _rusin_out(m: Measurements):
    from ..geometry import to_half_diff

    # d from V, as ALTA
    theta_h, _, theta_d, phi_d = padded_columns(jitted(to_half_diff), m.theta_o, m.phi_o, m.theta_i, m.phi_i)
    return np.stack([theta_h, theta_d, phi_d], axis=1)


@dataclasses.dataclass(frozen=True)
class InputParam:
    """One ALTA input parameterisation: its columns and the conversions to and from our angles.

    Fields:
        columns: a label per input column (used in error messages).
        to_angles: (N, n) array of a file's inputs -> (θi, φi, θo, φo) in radians.
        from_angles: `Measurements` -> (N, n) array of inputs.
        fixed_azimuth: the azimuth an isotropic parameterisation fixes (``"φi = 0"``), so that reading puts every
            pair there and writing turns it about the normal into that position; None for a full parameterisation.
        check: the first (row, problem) of inputs that no direction pair has, or None.
    """

    columns: tuple[str, ...]
    to_angles: Callable
    from_angles: Callable
    fixed_azimuth: str | None = None
    check: Callable | None = None


PARAM_IN = {
    "SPHERICAL_TL_PL_TV_PV": InputParam(("theta_l", "phi_l", "theta_v", "phi_v"), _spherical_in, _spherical_out),
    "CARTESIAN": InputParam(("V.x", "V.y", "V.z", "L.x", "L.y", "L.z"), _cartesian_in, _cartesian_out,
                            check=_cartesian_check),
    "ISOTROPIC_TL_TV_PROJ_DPHI": InputParam(("theta_l", "theta_v*cos(dphi)", "theta_v*sin(dphi)"), _projected_in,
                                            _projected_out, fixed_azimuth="φi = 0"),
    "RUSIN_TH_TD_PD": InputParam(("theta_h", "theta_d", "phi_d"), _rusin_in, _rusin_out,
                                 fixed_azimuth="φh = 0"),
}


@dataclasses.dataclass(frozen=True)
class OutputParam:
    """One ALTA output parameterisation.

    Fields:
        channels: the fixed channel names (three colour components), or None for any number of outputs.
        cosine: whether the stored value is f_r · cosθv.
    """

    channels: tuple[str, ...] | None = None
    cosine: bool = False


PARAM_OUT = {
    "INV_STERADIAN": OutputParam(),
    "INV_STERADIAN_COSINE_FACTOR": OutputParam(cosine=True),
    "RGB_COLOR": OutputParam(("R", "G", "B")),
    "XYZ_COLOR": OutputParam(("X", "Y", "Z")),
}


# ---------------------------------------------------------------------------------------------------- sniffing
def _header_key(line: bytes | str):
    """The key of an ALTA header line ('#' directly followed by a word), else None."""
    body = line[1:]
    if not line.startswith(b"#" if isinstance(line, bytes) else "#") or not body or body[:1].isspace():
        return None
    return body.split()[0]


def looks_like_alta(head: bytes) -> bool:
    """Whether the first bytes of a file are an ALTA header: leading '#' lines (blank lines aside) with a ``#DIM``."""
    for line in head.splitlines():
        line = line.strip()
        if not line:
            continue
        if not line.startswith(b"#"):
            return False
        if _header_key(line) == b"DIM":
            return True
    return False


# ----------------------------------------------------------------------------------------------------- reading
@dataclasses.dataclass
class _Header:
    entries: dict  # key -> (value, line) for the structural keys
    others: dict  # other '#KEY value' entries: key -> value (a list when repeated)
    comments: list


def _decode(path: Path, data: bytes) -> str:
    if re.search(rb"^[ \t]*#FORMAT[ \t]+binary", data[:_HEADER_BYTES], re.MULTILINE):
        raise FormatError(path, "ALTA binary data (#FORMAT binary) is not read by brdffit; convert it to ALTA text "
                                "data (e.g. with ALTA's data2data) first")
    return decode_text(path, data, "ALTA text data")


def _split(path: Path, text: str) -> tuple[_Header, list[str], list[int]]:
    header = _Header({}, {}, [])
    rows, lines = [], []
    in_header = True
    for lineno, line in enumerate(text.splitlines(), start=1):
        line = line.strip()
        if not line:
            continue
        if not line.startswith("#"):
            in_header = False
            rows.append(line)
            lines.append(lineno)
            continue
        key = _header_key(line) if in_header else None
        if key is None:
            header.comments.append(line)
            continue
        value = line[1 + len(key):].strip()
        if key == "ALTA" or key.startswith("ALTA_HEADER"):  # '#ALTA HEADER BEGIN' ... '#ALTA END HEADER' markers
            in_header = not value.startswith("END") and key != "ALTA_HEADER_END"
        elif key in _STRUCTURE:
            if key in header.entries:
                raise FormatError(path, f"a second #{key} line (the first is on line {header.entries[key][1]})",
                                  line=lineno)
            header.entries[key] = (value, lineno)
        elif key in header.others:
            previous = header.others[key]
            header.others[key] = [*previous, value] if isinstance(previous, list) else [previous, value]
        else:
            header.others[key] = value
    return header, rows, lines


def _dim(path: Path, header: _Header) -> tuple[int, int]:
    if "DIM" not in header.entries:
        raise FormatError(path, "no #DIM line: ALTA data starts with a header '#DIM <inputs> <outputs>'")
    value, line = header.entries["DIM"]
    parts = value.split()
    if len(parts) != 2 or not all(p.isdigit() and int(p) > 0 for p in parts):
        raise FormatError(path, f"#DIM needs two positive integers (number of inputs, number of outputs), got "
                                f"{value!r}", line=line)
    return int(parts[0]), int(parts[1])


def _params(path: Path, header: _Header, n_in: int, n_out: int) -> tuple[str, str, bool]:
    if "PARAM_IN" not in header.entries:
        raise FormatError(path, f"no #PARAM_IN line: the input columns need a parameterisation, one of "
                                f"{', '.join(PARAM_IN)}")
    name_in, line = header.entries["PARAM_IN"]
    if name_in not in PARAM_IN:
        raise FormatError(path, f"#PARAM_IN {name_in!r} is not a parameterisation brdffit reads; it reads "
                                f"{', '.join(PARAM_IN)}", line=line)
    expected = len(PARAM_IN[name_in].columns)
    if n_in != expected:
        raise FormatError(path, f"#DIM declares {n_in} inputs but #PARAM_IN {name_in} has {expected} "
                                f"({', '.join(PARAM_IN[name_in].columns)})", line=header.entries["DIM"][1])
    declared = "PARAM_OUT" in header.entries
    name_out, line = header.entries.get("PARAM_OUT", (_DEFAULT_OUT, None))
    if name_out not in PARAM_OUT:
        raise FormatError(path, f"#PARAM_OUT {name_out!r} is not an output brdffit reads; it reads "
                                f"{', '.join(PARAM_OUT)}", line=line)
    fixed = PARAM_OUT[name_out].channels
    if fixed is not None and n_out != len(fixed):
        raise FormatError(path, f"#DIM declares {n_out} outputs but #PARAM_OUT {name_out} has {len(fixed)} "
                                f"({', '.join(fixed)})", line=header.entries["DIM"][1])
    return name_in, name_out, declared


def _vs(path: Path, header: _Header, n_out: int) -> int:
    value, line = header.entries.get("VS", ("0", None))
    parts = value.split()
    if not parts or len(parts) not in (1, n_out) or any(p not in ("0", "1", "2") for p in parts) \
            or len(set(parts)) != 1:
        raise FormatError(path, f"#VS needs 0, 1 or 2 (no error bars, a radius, a distance below and above), once "
                                f"or repeated for each of the {n_out} outputs, got {value!r}", line=line)
    return int(parts[0])


def _numbers(path: Path, rows: list[str], lines: list[int], width: int, label: Callable[[int], str],
             expected: str) -> np.ndarray:
    """The (rows, width) numbers of the data rows; a row of another width or a cell that is not a number is an error.

    Rows of plain ASCII numbers (the common case) are parsed by NumPy's C reader into the array alone; the rows are
    split into cells (some 60 bytes a cell: 7.7 times the file's size for an 80 MB file) only to find and name
    what is wrong, one row at a time.
    """
    text_ok = all(row.isascii() for row in rows) and not any("_" in row for row in rows)
    if text_ok:  # float() reads "1_000" and non-ASCII digits, NumPy's reader does not: those go cell by cell
        try:
            block = np.loadtxt(rows, comments=None, dtype=float, ndmin=2)
        except ValueError:  # a row of another width or a cell that is not a number: found below
            block = None
        if block is not None and block.shape == (len(rows), width):
            return block
    for r, row in enumerate(rows):
        count = len(row.split())
        if count != width:
            hint = " (truncated?)" if count < width and r == len(rows) - 1 else ""
            raise FormatError(path, f"{count} numbers where {expected}{hint}", line=lines[r])
    out = np.empty((len(rows), width))
    for r, text in enumerate(rows):
        row = text.split()
        try:
            out[r] = [float(c) for c in row]
        except ValueError:
            k = next(k for k, c in enumerate(row) if not _is_number(c))
            raise FormatError(path, f"cannot read {row[k][:40]!r} as a number ({label(k)})", line=lines[r],
                              column=k + 1) from None
    return out


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _channel_names(path: Path, header: _Header, name_out: str, n_out: int, channels) -> tuple[str, ...] | None:
    if channels is not None:
        channels = (channels,) if isinstance(channels, str) else tuple(channels)
        if len(channels) != n_out:
            raise ValueError(f"channels: {len(channels)} names for {n_out} outputs")
        return channels
    stored = header.others.get(_CHANNELS_KEY)
    if isinstance(stored, str):
        try:
            names = json.loads(stored)
        except json.JSONDecodeError as err:
            raise FormatError(path, f"#{_CHANNELS_KEY} is not a JSON list of names: {err}") from None
        if not (isinstance(names, list) and len(names) == n_out and all(isinstance(s, str) for s in names)):
            raise FormatError(path, f"#{_CHANNELS_KEY} must list {n_out} names (one per output), got {stored!r}")
        return tuple(names)
    return PARAM_OUT[name_out].channels


@memory_guarded("reading the ALTA data")
def read_alta(path, *, channels: Sequence[str] | None = None) -> Measurements:
    """Read an ALTA text data file (module docstring: header, parameterisations, error bars).

    Arguments:
        path: the file (``.alta``, ``.dat``, ``.txt``, ...).
        channels: names for the outputs (default: ``R, G, B`` / ``X, Y, Z`` for colours, the names a
            ``#BRDFFIT_CHANNELS`` line gives, else the `Measurements` defaults).

    Returns:
        `Measurements` in brdffit's convention, σ from ``#VS`` error bars. ``meta["format"]`` is ``"alta"``,
        ``meta["alta"]`` the header (``param_in``, ``param_out``, ``dim``, ``vs``, ``header``: the other
        ``#KEY value`` entries such as ``URL``, ``CMD``, ``SAMPLE``; ``comments``), ``meta["read"]`` what the reading
        did (rows, incidences, rows missing because V lies at or below the horizon, ...).

    Raises:
        FileNotFoundError: no such file.
        FormatError: an empty or binary file, a Git LFS pointer, a missing or malformed ``#DIM`` / ``#VS``, a
            parameterisation brdffit does not read or that disagrees with ``#DIM``, a row with the wrong number of
            columns (with its line), a cell that is not a number (with its line and column), a CARTESIAN vector
            that is not a unit vector.
        MeasurementError: directions out of range (θ > π/2: below the surface) or values that break the rules of
            `Measurements` (negative f_r, σ <= 0), naming the file line.
    """
    path = Path(path)
    header, rows, lines = _split(path, _decode(path, read_file_bytes(path)))
    n_in, n_out = _dim(path, header)
    name_in, name_out, declared = _params(path, header, n_in, n_out)
    vs = _vs(path, header, n_out)
    if not rows:
        raise FormatError(path, "a header but no data rows")
    param, out = PARAM_IN[name_in], PARAM_OUT[name_out]
    names = _channel_names(path, header, name_out, n_out, channels)

    def label(k: int) -> str:
        if k < n_in:
            return f"input {param.columns[k]}"
        if k < n_in + n_out:
            j, what = k - n_in, "output"
        else:
            j, bar = divmod(k - n_in - n_out, vs)
            what = f"{('radius', 'distance below', 'distance above')[vs - 1 + bar]} of output"
        return f"{what} {names[j] if names else j + 1}"

    bars = {0: "", 1: ", then a radius per output", 2: ", then a distance below and one above per output"}[vs]
    expected = (f"#DIM {n_in} {n_out} with #VS {vs} makes {n_in + n_out * (1 + vs)}: {n_in} inputs "
                f"({', '.join(param.columns)}), {n_out} output{'s' if n_out > 1 else ''}{bars}")
    data = _numbers(path, rows, lines, n_in + n_out * (1 + vs), label, expected)

    x, values = data[:, :n_in], data[:, n_in:n_in + n_out]
    if param.check is not None:
        problem = param.check(x)
        if problem is not None:
            raise FormatError(path, problem[1], line=lines[problem[0]])
    theta_i, phi_i, theta_o, phi_o = param.to_angles(x)
    sigma = None
    if vs == 1:
        sigma = data[:, n_in + n_out:].copy()
    elif vs == 2:
        sigma = 0.5 * (data[:, n_in + n_out::2] + data[:, n_in + n_out + 1::2])

    read = {"rows": len(rows)}
    if not declared:
        read["values"] = f"{_DEFAULT_OUT}, f_r in 1/sr (the file has no #PARAM_OUT line)"
    if out.cosine:
        horizon = ~(theta_o < math.pi / 2 - THETA_TOLERANCE)  # NaN angles too: Measurements reports them
        cosine = np.cos(theta_o[~horizon])[:, None]
        values[horizon] = np.nan
        values[~horizon] /= cosine
        if sigma is not None:
            sigma[horizon] = np.nan
            sigma[~horizon] /= cosine
        read["missing (outgoing direction at or below the horizon)"] = int(horizon.sum())
    if vs:
        read["sigma"] = "the #VS 1 radius" if vs == 1 else "half the #VS 2 interval (distance below + above) / 2"
    if param.fixed_azimuth:
        read["azimuth"] = f"{param.fixed_azimuth} (an isotropic parameterisation)"

    meta = {"source": str(path), "format": "alta",
            "alta": {"param_in": name_in, "param_out": name_out, "dim": [n_in, n_out], "vs": vs,
                     "header": {k: v for k, v in header.others.items() if k != _CHANNELS_KEY},
                     "comments": [c.lstrip("#").strip() for c in header.comments]},
            "read": read}
    try:
        m = Measurements(theta_i, phi_i, theta_o, phi_o, values, sigma=sigma, channels=names, meta=meta)
    except MeasurementError as err:
        raise err.with_file(path, np.asarray(lines) if err.row is not None else None) from None
    incidences = np.unique(np.round(np.stack([m.theta_i, m.phi_i], axis=1), 9), axis=0)
    read["incidences"] = int(len(incidences))
    try:
        return m.replace(meta={**m.meta, "read": read}).check_informative()
    except MeasurementError as err:
        raise err.with_file(path) from None


# ----------------------------------------------------------------------------------------------------- writing
def _auto_output(m: Measurements) -> str:
    for name, out in PARAM_OUT.items():
        if out.channels is not None and m.channels == out.channels:
            return name
    return _DEFAULT_OUT


def write_alta(measurements: Measurements, path, *, param_in: str = "SPHERICAL_TL_PL_TV_PV",
               param_out: str | None = None) -> None:
    """Write measurements as an ALTA text data file, atomically.

    Arguments:
        measurements: the `Measurements`.
        path: the file (``.alta`` by convention).
        param_in: the input parameterisation (`PARAM_IN`); an isotropic one (``ISOTROPIC_TL_TV_PROJ_DPHI``,
            ``RUSIN_TH_TD_PD``) keeps each pair's relative geometry and drops its azimuth about the normal.
        param_out: ``INV_STERADIAN``, ``INV_STERADIAN_COSINE_FACTOR`` (f_r · cosθo is written), ``RGB_COLOR`` or
            ``XYZ_COLOR`` (three channels); default ``RGB_COLOR`` / ``XYZ_COLOR`` when the channels are named
            ``R, G, B`` / ``X, Y, Z``, else ``INV_STERADIAN`` with one output per channel.

    Every number is written with Python's shortest round-trip repr, so `read_alta` gives back the very same values
    (and σ); σ becomes ``#VS 1`` radii. Channel names other than the output's own are kept in a
    ``#BRDFFIT_CHANNELS`` header line (ALTA keeps such lines as unused header entries), and the ``meta["alta"]``
    header entries of a file read before (``URL``, ``SAMPLE``, ...) are written back. Weights and the other meta are
    not part of the format. ALTA has no missing-value marker: rows whose every value is missing are left out.

    Raises:
        ValueError: an unknown parameterisation, a colour output for other than three channels, or a row with some
            but not all of its values missing.
    """
    if not isinstance(measurements, Measurements):
        raise TypeError(f"expected brdffit.Measurements, got {type(measurements).__name__}")
    if param_in not in PARAM_IN:
        raise ValueError(f"param_in must be one of {', '.join(PARAM_IN)}, got {param_in!r}")
    m = measurements
    name_out = _auto_output(m) if param_out is None else param_out
    if name_out not in PARAM_OUT:
        raise ValueError(f"param_out must be one of {', '.join(PARAM_OUT)}, got {param_out!r}")
    out = PARAM_OUT[name_out]
    if out.channels is not None and m.n_channels != len(out.channels):
        raise ValueError(f"{name_out} needs {len(out.channels)} channels, the measurements have {m.n_channels}")
    present = m.valid
    partial = np.flatnonzero(present.any(axis=1) & ~present.all(axis=1))
    if partial.size:
        raise ValueError(f"row {int(partial[0])} has some channels missing: ALTA data has no missing-value marker; "
                         "select channels (m.select_channels) or drop such rows (m.take) first")
    m = m.take(present.all(axis=1))
    if not m.n:
        raise ValueError("nothing to write: every value is missing")

    values = m.values
    sigma = m.sigma
    if out.cosine:
        cosine = np.cos(m.theta_o)[:, None]
        values = values * cosine
        sigma = None if sigma is None else sigma * cosine
    columns = [PARAM_IN[param_in].from_angles(m), values] + ([] if sigma is None else [sigma])
    table = np.concatenate(columns, axis=1)

    lines = []
    alta = m.meta.get("alta")
    provenance = alta.get("header") if isinstance(alta, dict) else None
    for key, value in (provenance if isinstance(provenance, dict) else {}).items():
        for v in value if isinstance(value, list) else [value]:
            if re.fullmatch(r"[A-Za-z]\w*", key) and key not in (*_STRUCTURE, _CHANNELS_KEY, "FORMAT") \
                    and isinstance(v, str) and "\n" not in v and "\r" not in v:
                lines.append(f"#{key} {v}")
    lines += [f"#DIM {len(PARAM_IN[param_in].columns)} {m.n_channels}", f"#PARAM_IN {param_in}",
              f"#PARAM_OUT {name_out}", f"#VS {0 if sigma is None else 1}"]
    if m.channels != (out.channels or _default_channels(m.n_channels)):  # what read_alta would name them
        lines.append(f"#{_CHANNELS_KEY} {json.dumps(list(m.channels))}")
    lines += [" ".join(map(repr, row)) for row in table.tolist()]
    path = Path(path)
    with atomic_path(path, suffix=path.suffix or ".tmp") as tmp:
        tmp.write_text("\n".join(lines) + "\n", encoding="utf-8")
