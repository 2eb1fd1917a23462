"""Readers and writers: files in, `brdffit.Measurements` out, and back (docs/formats.md).

`load(path, **options)` and `save(measurements, path, **options)` pick the format from the file's content and
extension; the format modules can also be used directly:

- `table` — CSV / TSV / whitespace tables from instruments, and brdffit's canonical CSV layout;
- `merl` — the MERL binary BRDF tables (Matusik et al. 2003): read, look up, convert, and write from any model;
- `hdf5` — brdffit's own HDF5 files (measurements, later fits and posteriors);
- `alta` — the text data files of the ALTA BRDF library (``#DIM``, ``#PARAM_IN``, ... header; read and write);
- `astm` — ASTM E1392 BRDF data (keyword header, ``VARS`` line, one sample per row; read and write);
- `rgl` — RGL-EPFL ``.bsdf`` measured BRDFs (Dupuy & Jakob 2018): read, look up, convert to samples;
- `tabulated` — how a tabulated file (MERL, RGL-EPFL) becomes the samples a fit is given: its lookup at direction
  pairs uniform in solid angle, or its grid.

A file that cannot be read as its format raises `FormatError` naming the file and the problem (line and column
where relevant); numbers that break the rules of `Measurements` raise `brdffit.MeasurementError` naming the file.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path

from ..measurements import Measurements
from ._common import FormatError, check_not_lfs_pointer, read_head
from .alta import looks_like_alta, read_alta, write_alta
from .astm import looks_like_astm, read_astm, write_astm
from .hdf5 import is_hdf5, read_hdf5, read_hdf5_group, update_hdf5, write_hdf5
from .merl import MerlTable, looks_like_merl, read_merl, write_merl
from .rgl import RglTable, looks_like_rgl, read_rgl
from .table import read_table, write_table

__all__ = ["load", "save", "detect_format", "Format", "FORMATS", "FormatError", "read_table", "write_table",
           "read_merl", "write_merl", "MerlTable", "read_hdf5", "write_hdf5", "update_hdf5", "read_hdf5_group",
           "read_alta", "write_alta", "read_astm", "write_astm", "read_rgl", "RglTable"]


@dataclasses.dataclass(frozen=True)
class Format:
    """A file format brdffit reads (and perhaps writes), declared once: `load`, `save`, `detect_format` and the
    batch sources read it.

    Attributes:
        name: the ``format=`` name.
        description: one line for help texts and docs.
        extensions: the file extensions (lower case, with the dot) that name it when the content does not.
        read: ``read(path, **options) -> Measurements``; its options are the format's (docs/formats.md).
        sniff: ``sniff(head) -> bool`` on a file's first bytes, where the content tells the format; None for text
            tables, which have no signature.
        write: ``write(measurements, path, **options)``; None where brdffit does not write the format.
        unwritable: why it is not written, and what to do instead (the error of `save`).
    """

    name: str
    description: str
    extensions: tuple[str, ...]
    read: Callable[..., Measurements]
    sniff: Callable[[bytes], bool] | None = None
    write: Callable | None = None
    unwritable: str = ""


# In the order `detect_format` tries the signatures: HDF5, MERL and RGL-EPFL have magic bytes; ALTA's and ASTM
# E1392's headers are text (a .dat / .txt file is recognised by its #DIM or its VARS line).
FORMATS = {f.name: f for f in (
    Format("hdf5", "brdffit's HDF5 files (measurements, fits, posteriors)", (".h5", ".hdf5", ".he5"),
           read_hdf5, is_hdf5, write_hdf5),
    Format("merl", "MERL binary BRDF tables (Matusik et al. 2003)", (".binary", ".merl"),
           lambda path, **options: read_merl(path).to_measurements(**options), looks_like_merl,
           unwritable="a MERL table tabulates a BRDF on a fixed half/difference grid, not scattered samples; fit a "
                      "model and call brdffit.io.write_merl(model, path), or save as .csv or .h5"),
    Format("rgl", "RGL-EPFL .bsdf measured BRDFs (Dupuy & Jakob 2018)", (".bsdf",),
           lambda path, **options: read_rgl(path).to_measurements(**options), looks_like_rgl,
           unwritable="brdffit reads RGL-EPFL .bsdf files but does not write them; save as .csv or .h5"),
    Format("alta", "ALTA text data (#DIM, #PARAM_IN, ... header)", (".alta",), read_alta, looks_like_alta,
           write_alta),
    Format("astm", "ASTM E1392 BRDF data (keyword header, VARS line; Cornell's and instruments' spectral files)",
           (".astm",), read_astm, looks_like_astm, write_astm),
    Format("table", "CSV / TSV / whitespace tables, and brdffit's canonical CSV", (".csv", ".tsv", ".txt", ".dat",
                                                                                 ".tab"),
           read_table, None, write_table),
)}


def _by_extension(path: Path) -> Format | None:
    ext = path.suffix.lower()
    return next((f for f in FORMATS.values() if ext in f.extensions), None)


def _named(format: str) -> Format:  # noqa: A002 - the natural name
    if format not in FORMATS:
        raise ValueError(f"unknown format {format!r}; use one of {', '.join(FORMATS)}")
    return FORMATS[format]


def detect_format(path, head: bytes | None = None) -> str:
    """The format of a file (a name in `FORMATS`): its first bytes where a format has a signature, else its
    extension, else ``"table"`` for text.

    Raises:
        FileNotFoundError: no such file. FormatError: not a regular file, a Git LFS pointer, or content and extension
            that name no format brdffit reads.
    """
    path = Path(path)
    if head is None:
        head = read_head(path, 4096)  # an ALTA header may put #DIM after a few #URL / #CMD lines
    check_not_lfs_pointer(path, head)
    sniffed = next((f for f in FORMATS.values() if f.sniff is not None and f.sniff(head)), None) \
        or _by_extension(path)
    if sniffed is not None:
        return sniffed.name
    if b"\0" not in head:
        return "table"  # text of an unknown extension: try it as a table
    raise FormatError(path, f"cannot tell the format: extension {path.suffix.lower() or '(none)'!r} is not one of "
                            f"{', '.join(e for f in FORMATS.values() for e in f.extensions)} and the content is "
                            "neither HDF5, MERL, RGL-EPFL nor text")


def load(path, *, format: str | None = None, **options) -> Measurements:  # noqa: A002 - the natural name
    """Read measurements from a file.

    Arguments:
        path: a table (``.csv``, ``.tsv``, ``.txt``), a MERL binary (``.binary``, ``.merl``) or a brdffit HDF5 file
            (``.h5``, ``.hdf5``), ALTA text data (``.alta``, or a ``.dat`` / ``.txt`` with an ALTA header), ASTM
            E1392 data (``.astm``, or a text file with a ``VARS`` line). The
            content decides where it is unambiguous (HDF5 signature, MERL header, ALTA ``#DIM`` header), or an
            RGL-EPFL ``.bsdf`` file (recognised by its ``tensor_file`` magic).
        format: force ``"table"``, ``"merl"``, ``"hdf5"``, ``"alta"``, ``"astm"`` or ``"rgl"``.
        **options: passed to the reader: `read_table` (``columns``, ``values``, ``sigma``, ``where``,
            ``channel_column``, ``degrees``, ...), `MerlTable.to_measurements` (``sampling``, ``pairs``, ``seed``,
            ``max_theta``, ``subsample``), `read_hdf5` (``group``), `read_alta` (``channels``), `read_astm`
            (``degrees``) or
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
    return _named(format).read(path, **options)


def save(measurements: Measurements, path, *, format: str | None = None, **options) -> None:  # noqa: A002
    """Write measurements to a file, atomically (a temporary file beside it, renamed into place).

    Arguments:
        measurements: the `Measurements`.
        path: ``.csv`` / ``.tsv`` / ``.txt`` (the canonical table layout), ``.h5`` / ``.hdf5``, ``.alta`` or
            ``.astm``.
        format: force ``"table"``, ``"hdf5"``, ``"alta"`` or ``"astm"``.
        **options: passed to `write_table`, `write_hdf5` or `write_alta` (``param_in``, ``param_out``).

    Raises:
        ValueError: an unknown extension, or a MERL path: a MERL file tabulates a BRDF on a fixed grid and cannot be
            made from scattered samples; use ``brdffit.io.write_merl(model, path)`` with a (fitted) model instead.
    """
    path = Path(path)
    if format is None:
        found = _by_extension(path)
        if found is None:
            writable = [e for f in FORMATS.values() if f.write is not None for e in f.extensions]
            raise ValueError(f"{path}: cannot tell the format from extension {path.suffix.lower() or '(none)'!r}; "
                             f"use one of {', '.join(writable)} or pass format=")
        format = found.name
    target = _named(format)
    if target.write is None:
        raise ValueError(f"{path}: measurements cannot be saved as {target.name}: {target.unwritable}")
    target.write(measurements, path, **options)
