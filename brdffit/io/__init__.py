"""Readers and writers: files in, `brdffit.Measurements` out, and back (docs/formats.md).

`load(path, **options)` and `save(measurements, path, **options)` pick the format from the file's content and
extension; the format modules can also be used directly:

- `table` — CSV / TSV / whitespace tables from instruments, and brdffit's canonical CSV layout;
- `merl` — the MERL binary BRDF tables (Matusik et al. 2003): read, look up, convert, and write from any model;
- `hdf5` — brdffit's own HDF5 files (measurements, later fits and posteriors);
- `alta` — the text data files of the ALTA BRDF library (``#DIM``, ``#PARAM_IN``, ... header; read and write);
- `rgl` — RGL-EPFL ``.bsdf`` measured BRDFs (Dupuy & Jakob 2018): read, look up, convert to samples;
- `tabulated` — how a tabulated file (MERL, RGL-EPFL) becomes the samples a fit is given: its lookup at direction
  pairs uniform in solid angle, or its grid.

A file that cannot be read as its format raises `FormatError` naming the file and the problem (line and column
where relevant); numbers that break the rules of `Measurements` raise `brdffit.MeasurementError` naming the file.
"""

from __future__ import annotations

from pathlib import Path

from ..measurements import Measurements
from ._common import FormatError, check_not_lfs_pointer, read_head
from .alta import read_alta, write_alta
from .hdf5 import read_hdf5, read_hdf5_group, update_hdf5, write_hdf5
from .merl import MerlTable, read_merl, write_merl
from .rgl import RglTable, read_rgl
from .table import read_table, write_table

__all__ = ["load", "save", "detect_format", "FormatError", "read_table", "write_table", "read_merl", "write_merl",
           "MerlTable", "read_hdf5", "write_hdf5", "update_hdf5", "read_hdf5_group", "read_alta", "write_alta",
           "read_rgl", "RglTable", "FORMATS"]

# Extensions of each format (lower case, with the dot).
FORMATS = {
    "table": (".csv", ".tsv", ".txt", ".dat", ".tab"),
    "merl": (".binary", ".merl"),
    "hdf5": (".h5", ".hdf5", ".he5"),
    "alta": (".alta",),  # ALTA text data in a .dat / .txt file is recognised by its header (_sniff)
    "rgl": (".bsdf",),
}


def _sniff(head: bytes) -> str | None:
    from .alta import looks_like_alta
    from .hdf5 import is_hdf5
    from .merl import looks_like_merl
    from .rgl import looks_like_rgl

    if is_hdf5(head):
        return "hdf5"
    if looks_like_merl(head):
        return "merl"
    if looks_like_rgl(head):
        return "rgl"
    if looks_like_alta(head):
        return "alta"
    return None


def detect_format(path, head: bytes | None = None) -> str:
    """The format of a file (``"table"``, ``"merl"``, ``"hdf5"``, ``"alta"``, ``"rgl"``): its first bytes, else its
    extension.

    Raises:
        FileNotFoundError: no such file. FormatError: not a regular file, a Git LFS pointer, or content and extension
            that name no format brdffit reads.
    """
    path = Path(path)
    if head is None:
        head = read_head(path, 4096)  # an ALTA header may put #DIM after a few #URL / #CMD lines
    check_not_lfs_pointer(path, head)
    sniffed = _sniff(head)
    if sniffed:
        return sniffed
    ext = path.suffix.lower()
    for name, extensions in FORMATS.items():
        if ext in extensions:
            return name
    if b"\0" not in head:
        return "table"  # text of an unknown extension: try it as a table
    raise FormatError(path, f"cannot tell the format: extension {ext or '(none)'!r} is not one of "
                            f"{', '.join(e for exts in FORMATS.values() for e in exts)} and the content is neither "
                            "HDF5, MERL, RGL-EPFL nor text")


def load(path, *, format: str | None = None, **options) -> Measurements:  # noqa: A002 - the natural name
    """Read measurements from a file.

    Arguments:
        path: a table (``.csv``, ``.tsv``, ``.txt``), a MERL binary (``.binary``, ``.merl``) or a brdffit HDF5 file
            (``.h5``, ``.hdf5``), ALTA text data (``.alta``, or a ``.dat`` / ``.txt`` with an ALTA header). The
            content decides where it is unambiguous (HDF5 signature, MERL header, ALTA ``#DIM`` header), or an
            RGL-EPFL ``.bsdf`` file (recognised by its ``tensor_file`` magic).
        format: force ``"table"``, ``"merl"``, ``"hdf5"``, ``"alta"`` or ``"rgl"``.
        **options: passed to the reader: `read_table` (``columns``, ``values``, ``sigma``, ``where``,
            ``channel_column``, ``degrees``, ...), `MerlTable.to_measurements` (``sampling``, ``pairs``, ``seed``,
            ``max_theta``, ``subsample``), `read_hdf5` (``group``), `read_alta` (``channels``) or
            `RglTable.to_measurements` (``sampling``, ``pairs``, ``seed``, ``max_theta``, ``negative``). A tabulated
            file (MERL, RGL-EPFL) is read by default as its own interpolation at quasi-random direction pairs
            uniform in solid angle (`brdffit.io.tabulated`); ``sampling="grid"`` gives its nodes.

    Returns:
        `brdffit.Measurements`.

    Example (the NIST PTFE file, 532 nm)::

        brdffit.io.load("../shared/data/nist-ptfe/PTFE.data.csv",
                        columns={"theta_i": "thetai", "phi_i": "phi", "theta_o": "thetar", "phi_o": "phir"},
                        values="f_r11", where={"lambda": 0.532})
    """
    path = Path(path)
    if format is None:
        format = detect_format(path)  # refuses a missing path and anything but a regular file (_common.open_regular)
    if format == "table":
        return read_table(path, **options)
    if format == "merl":
        return read_merl(path).to_measurements(**options)
    if format == "hdf5":
        return read_hdf5(path, **options)
    if format == "alta":
        return read_alta(path, **options)
    if format == "rgl":
        return read_rgl(path).to_measurements(**options)
    raise ValueError(f"unknown format {format!r}; use one of {', '.join(FORMATS)}")


def save(measurements: Measurements, path, *, format: str | None = None, **options) -> None:  # noqa: A002
    """Write measurements to a file, atomically (a temporary file beside it, renamed into place).

    Arguments:
        measurements: the `Measurements`.
        path: ``.csv`` / ``.tsv`` / ``.txt`` (the canonical table layout), ``.h5`` / ``.hdf5`` or ``.alta``.
        format: force ``"table"``, ``"hdf5"`` or ``"alta"``.
        **options: passed to `write_table`, `write_hdf5` or `write_alta` (``param_in``, ``param_out``).

    Raises:
        ValueError: an unknown extension, or a MERL path: a MERL file tabulates a BRDF on a fixed grid and cannot be
            made from scattered samples; use ``brdffit.io.write_merl(model, path)`` with a (fitted) model instead.
    """
    path = Path(path)
    if format is None:
        ext = path.suffix.lower()
        format = next((name for name, exts in FORMATS.items() if ext in exts), None)
        if format is None:
            raise ValueError(f"{path}: cannot tell the format from extension {ext or '(none)'!r}; use one of "
                             f"{', '.join(FORMATS['table'] + FORMATS['hdf5'])} or pass format=")
    if format == "table":
        write_table(measurements, path, **options)
    elif format == "hdf5":
        write_hdf5(measurements, path, **options)
    elif format == "alta":
        write_alta(measurements, path, **options)
    elif format == "merl":
        raise ValueError(f"{path}: measurements cannot be saved as a MERL table (it tabulates a BRDF on a fixed "
                         "half/difference grid, not scattered samples); fit a model and call "
                         "brdffit.io.write_merl(model, path), or save as .csv or .h5")
    elif format == "rgl":
        raise ValueError(f"{path}: brdffit reads RGL-EPFL .bsdf files but does not write them; save as .csv or .h5")
    else:
        raise ValueError(f"unknown format {format!r}; use one of {', '.join(FORMATS)}")
