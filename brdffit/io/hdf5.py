"""brdffit's own HDF5 files: measurements now, fit results and posterior chains beside them later.

Schema (format_version "1"; docs/formats.md is the reference)::

    /                       attrs: format_version = "1", creator = "brdffit <version>"
    /measurements           attrs: channels (JSON list of str), meta (JSON object)
        theta_i, phi_i,     (N,) float64, radians, the library's convention (docs/conventions.md)
        theta_o, phi_o
        values              (N, C) float64, f_r in 1/sr, NaN = missing
        sigma               (N, C) float64, optional
        weights             (N,) float64, optional
    /fits/<name>            reserved for fit results (written with `update_hdf5`)
    /posteriors/<name>      reserved for posterior chains (written with `update_hdf5`)

Every write goes to a temporary file in the target's directory that is renamed into place, so a failed write never
damages an existing file. Arrays are stored bit for bit, so a round trip is exact.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ..measurements import MeasurementError, Measurements
from ._common import FormatError, atomic_path, check_not_lfs_pointer

__all__ = ["FORMAT_VERSION", "MEASUREMENTS_GROUP", "read_hdf5", "write_hdf5", "update_hdf5", "read_hdf5_group",
           "write_measurements_group", "read_measurements_group", "is_hdf5"]

FORMAT_VERSION = "1"
MEASUREMENTS_GROUP = "measurements"
HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"

_ANGLES = ("theta_i", "phi_i", "theta_o", "phi_o")


def _h5py():
    import h5py

    return h5py


def is_hdf5(head: bytes) -> bool:
    """Whether the first bytes of a file carry the HDF5 signature (at offset 0, as our files have it)."""
    return head.startswith(HDF5_SIGNATURE)


def _creator() -> str:
    from .. import __version__

    return f"brdffit {__version__}"


def _stamp_root(f) -> None:
    f.attrs["format_version"] = FORMAT_VERSION
    f.attrs["creator"] = _creator()


def _attr_text(value) -> str:
    if isinstance(value, bytes):
        return value.decode("utf-8")
    if isinstance(value, np.ndarray) and value.shape == ():
        return _attr_text(value[()])
    return str(value)


def _check_root(path, f) -> None:
    if "format_version" not in f.attrs:
        raise FormatError(path, "an HDF5 file but not one brdffit wrote (no 'format_version' attribute on /); "
                                "convert it with a table (CSV) or build Measurements from its arrays")
    version = _attr_text(f.attrs["format_version"])
    if version != FORMAT_VERSION:
        raise FormatError(path, f"format_version {version!r} is not one this brdffit reads "
                                f"(it reads {FORMAT_VERSION!r}); update brdffit")


def _open_checked(path):
    """Open an existing brdffit HDF5 file read-only, or raise a FormatError that says why not."""
    h5py = _h5py()
    path = Path(path)
    try:
        with open(path, "rb") as fh:
            head = fh.read(64)
    except FileNotFoundError:
        raise FileNotFoundError(f"{path}: no such file") from None
    check_not_lfs_pointer(path, head)
    if not head:
        raise FormatError(path, "the file is empty (expected an HDF5 file)")
    if not is_hdf5(head):
        raise FormatError(path, "not an HDF5 file (no HDF5 signature at the start)")
    try:
        f = h5py.File(path, "r")
    except OSError as err:
        raise FormatError(path, f"cannot be opened as HDF5 (truncated or damaged?): {err}") from None
    try:
        _check_root(path, f)
    except (OSError, RuntimeError, KeyError) as err:
        f.close()
        raise FormatError(path, f"cannot read the root attributes (truncated or damaged?): {err}") from None
    except BaseException:
        f.close()
        raise
    return f


# ------------------------------------------------------------------------------------------------- measurements
def write_measurements_group(group, measurements: Measurements, *, compression: str | None = None) -> None:
    """Write ``measurements`` into an open, empty h5py group (the layout of ``/measurements``).

    Arguments:
        group: an h5py Group.
        measurements: the `Measurements`.
        compression: passed to ``create_dataset`` (e.g. ``"gzip"``); None stores the arrays uncompressed.
    """
    if not isinstance(measurements, Measurements):
        raise TypeError(f"expected brdffit.Measurements, got {type(measurements).__name__}")
    for name in (*_ANGLES, "values", "sigma", "weights"):
        arr = getattr(measurements, name)
        if arr is not None:
            group.create_dataset(name, data=np.asarray(arr, dtype=np.float64), compression=compression)
    group.attrs["channels"] = json.dumps(list(measurements.channels))
    group.attrs["meta"] = json.dumps(measurements.meta, sort_keys=True, allow_nan=True)


def read_measurements_group(group, path=None) -> Measurements:
    """Read a group written by `write_measurements_group` back into `Measurements` (exactly).

    Raises:
        FormatError: a missing or malformed dataset or attribute (naming ``path`` and the dataset).
        MeasurementError: arrays that break the rules of `Measurements` (naming ``path``).
    """
    h5py = _h5py()
    where = f"{group.name}"
    arrays: dict[str, Any] = {}
    for name in (*_ANGLES, "values", "sigma", "weights"):
        if name not in group:
            if name in ("sigma", "weights"):
                arrays[name] = None
                continue
            raise FormatError(path, f"dataset {where}/{name} is missing")
        obj = group[name]
        if not isinstance(obj, h5py.Dataset) or obj.dtype.kind not in "fiu":
            raise FormatError(path, f"{where}/{name} is not a numeric dataset")
        arrays[name] = np.asarray(obj[()], dtype=np.float64)
    try:
        channels = json.loads(_attr_text(group.attrs["channels"])) if "channels" in group.attrs else None
        meta = json.loads(_attr_text(group.attrs["meta"])) if "meta" in group.attrs else {}
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise FormatError(path, f"attribute channels or meta of {where} is not valid JSON: {err}") from None
    if channels is not None and (not isinstance(channels, list) or not all(isinstance(c, str) for c in channels)):
        raise FormatError(path, f"attribute {where}.channels must be a JSON list of strings")
    if not isinstance(meta, dict):
        raise FormatError(path, f"attribute {where}.meta must be a JSON object")
    try:
        return Measurements(**arrays, channels=channels, meta=meta)
    except MeasurementError as err:
        raise err.with_file(f"{path} ({where})" if path else where) from None


def read_hdf5(path, group: str = MEASUREMENTS_GROUP) -> Measurements:
    """Read measurements from a brdffit HDF5 file.

    Arguments:
        path: the file.
        group: the group holding the measurements (default ``/measurements``).

    Returns:
        The `Measurements`, identical to those written.

    Raises:
        FormatError: not an HDF5 file, not a brdffit file, a newer format version, a missing group or dataset.
        MeasurementError: stored arrays that break the rules of `Measurements`.
    """
    return read_hdf5_group(path, group, lambda g: read_measurements_group(g, path))


def read_hdf5_group(path, group_name: str, read_fn: Callable[[Any], Any]):
    """Open a brdffit HDF5 file read-only, check its format version, and return ``read_fn(file[group_name])``.

    Later issues read ``/fits/<name>`` and ``/posteriors/<name>`` through this.
    """
    h5py = _h5py()
    name = group_name.strip("/")
    with _open_checked(path) as f:
        try:
            if name not in f or not isinstance(f[name], h5py.Group):
                groups = []
                f.visit(lambda n: groups.append(n) if isinstance(f[n], h5py.Group) else None)
                # A damaged file can hand back a name as undecodable bytes: show it as such, never fail on it.
                names = [g if isinstance(g, str) else repr(g) for g in groups]
                raise FormatError(path, f"no group /{name} (groups: {', '.join('/' + g for g in names) or 'none'})")
            return read_fn(f[name])
        except (FormatError, MeasurementError):
            raise
        except (OSError, RuntimeError, KeyError, ValueError) as err:
            raise FormatError(path, f"cannot read /{name} (truncated or damaged?): {err}") from None


def write_hdf5(measurements: Measurements, path, *, keep_other_groups: bool = False,
               compression: str | None = None) -> None:
    """Write measurements to ``path`` as ``/measurements`` of a brdffit HDF5 file (atomically).

    Arguments:
        measurements: the `Measurements`.
        path: the file (``.h5`` or ``.hdf5`` by convention).
        keep_other_groups: if the file exists, keep its other groups (``/fits``, ``/posteriors``) and replace only
            ``/measurements``; by default a fresh file replaces it.
        compression: passed to h5py (e.g. ``"gzip"``); None stores the arrays uncompressed.
    """
    if not isinstance(measurements, Measurements):
        raise TypeError(f"expected brdffit.Measurements, got {type(measurements).__name__}")
    if keep_other_groups and Path(path).exists():
        update_hdf5(path, MEASUREMENTS_GROUP,
                    lambda g: write_measurements_group(g, measurements, compression=compression))
        return
    h5py = _h5py()
    with atomic_path(path, suffix=".h5") as tmp:
        with h5py.File(tmp, "w") as f:
            _stamp_root(f)
            write_measurements_group(f.create_group(MEASUREMENTS_GROUP), measurements, compression=compression)


def _copy_except(src, dst, skip: list[str]) -> None:
    for key, value in src.attrs.items():
        dst.attrs[key] = value
    h5py = _h5py()
    for name in src:
        if skip and name == skip[0]:
            if len(skip) > 1 and isinstance(src[name], h5py.Group):
                _copy_except(src[name], dst.create_group(name), skip[1:])
            continue
        src.copy(src[name], dst, name=name)


def update_hdf5(path, group_name: str, write_fn: Callable[[Any], Any]):
    """Add or replace one group of a brdffit HDF5 file without risking the file.

    The existing file (if any) is copied, all but ``group_name``, into a temporary file in the same directory; a
    fresh, empty group ``group_name`` is created there (with its parents) and handed to ``write_fn``; the temporary
    file then replaces the original (os.replace). If ``write_fn`` raises, the original is untouched.

    Arguments:
        path: the file; created if it does not exist.
        group_name: e.g. ``"fits/lambert+ggx"`` or ``"posteriors/run1"`` ("/" separates levels; a leading "/" is
            ignored).
        write_fn: called with the new h5py Group; its return value is returned.

    Raises:
        FormatError: ``path`` exists but is not a brdffit HDF5 file.
    """
    h5py = _h5py()
    parts = [p for p in str(group_name).split("/") if p]
    if not parts:
        raise ValueError(f"group_name must name a group below the root, got {group_name!r}")
    path = Path(path)
    source = _open_checked(path) if path.exists() else None
    try:
        with atomic_path(path, suffix=".h5") as tmp:
            with h5py.File(tmp, "w") as f:
                if source is not None:
                    _copy_except(source, f, parts)
                    source.close()
                _stamp_root(f)
                group = f.require_group("/".join(parts[:-1])) if len(parts) > 1 else f
                result = write_fn(group.create_group(parts[-1]))
    finally:
        if source is not None and source.id.valid:
            source.close()
    return result
