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
damages an existing file. Arrays are stored bit for bit, so a round trip is exact. An update (`update_hdf5`) holds
the folder's lock (`brdffit.io.locking`) from its read to its rename, and a read holds it shared, so that concurrent
processes lose no group and read no chain step half written.

Reading an untrusted file is bounded (`inspect_hdf5`): before the file is opened here, a forked child process opens
it, reads every attribute and dataset and checks that each dataset's declared size is below `MAX_DATASET_BYTES`;
external links, external raw storage and virtual datasets (data of other files) are refused. Measurement datasets
must also be backed by the bytes the file stores (not fill values). The child is killed after `INSPECT_TIMEOUT_S`:
damaged metadata can make libhdf5 loop forever (zeroed global-heap objects hang ``H5Aread``), in C code that no
Python signal interrupts. Several files (a batch of a database fit) are inspected in one child, which stops at the
first file it refuses (`inspect_hdf5_many`), and a database fit's files are read by that child from what its
inspection read, never opened here (`read_hdf5_many`). The signature may follow a user block (at byte 512, 1024,
2048, ... as HDF5 places it).
"""

from __future__ import annotations

import contextlib
import errno
import gc
import json
import math
import os
import pickle
import select
import signal
import time
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from ..measurements import MeasurementError, Measurements
from ._common import (FormatError, atomic_path, check_not_lfs_pointer, memory_guarded, out_of_memory, parse_meta_json,
                      read_head)
from .locking import LOCK_TIMEOUT_S, locked

__all__ = ["FORMAT_VERSION", "MEASUREMENTS_GROUP", "read_hdf5", "read_meta", "write_hdf5", "update_hdf5",
           "read_hdf5_group",
           "write_measurements_group", "read_measurements_group", "is_hdf5", "inspect_hdf5", "inspect_hdf5_many",
           "open_hdf5", "open_h5_waiting", "read_hdf5_many",
           "MAX_DATASET_BYTES", "MAX_ATTRIBUTE_BYTES", "INSPECT_TIMEOUT_S"]

FORMAT_VERSION = "1"
MEASUREMENTS_GROUP = "measurements"
HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"
HEAD_BYTES = 1 << 16  # the signature is looked for in this many first bytes (user blocks up to 32 KiB)

# Limits on what a file may declare (a dataset's shape times its item size is allocated in full when it is read).
MAX_DATASET_BYTES = 1 << 30
MAX_ATTRIBUTE_BYTES = 1 << 24
MAX_OBJECTS = 100_000  # groups and datasets visited: a bound on link cycles (a group hard-linked into itself)
# Deflate cannot expand data more than 1032:1 (zlib's technical details, "maximum compression factor"), so a
# filtered dataset declaring more than this times its stored bytes is filled with fill values, not data.
MAX_FILTER_RATIO = 1032
INSPECT_TIMEOUT_S = 10.0  # seconds the inspecting child may take (a normal file takes milliseconds)

_ANGLES = ("theta_i", "phi_i", "theta_o", "phi_o")
# The datasets of a /measurements group (`read_measurements_group`).
_MEASUREMENT_DATASETS = (*_ANGLES, "values", "sigma", "weights")


def _h5py():
    import h5py

    return h5py


def _signature_offset(head: bytes) -> int | None:
    """Where the HDF5 signature is: at 0, or after a user block at 512, 1024, 2048, ... (HDF5 format spec, III.A)."""
    offset = 0
    while offset + len(HDF5_SIGNATURE) <= len(head):
        if head.startswith(HDF5_SIGNATURE, offset):
            return offset
        offset = 512 if offset == 0 else 2 * offset
    return None


def is_hdf5(head: bytes) -> bool:
    """Whether the first bytes of a file carry the HDF5 signature (at offset 0 or after a user block)."""
    return _signature_offset(head) is not None


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


def _attribute(path, obj, name: str, where: str):
    """An attribute's value; an unreadable one (an unknown string encoding, damaged bytes) is a FormatError."""
    try:
        return obj.attrs[name]
    except (OSError, RuntimeError, KeyError, TypeError, ValueError) as err:
        raise FormatError(path, f"attribute {name!r} of {where} cannot be read: {err}") from None


def _check_attribute(path, obj, name: str, where: str):
    """Read one attribute, refusing one that declares more than `MAX_ATTRIBUTE_BYTES` or cannot be decoded;
    returns its value."""
    try:
        attribute = obj.attrs.get_id(name)
        size = math.prod(attribute.shape or ()) * attribute.dtype.itemsize
    except (OSError, RuntimeError, KeyError, TypeError, ValueError) as err:
        raise FormatError(path, f"attribute {name!r} of {where} cannot be read: {err}") from None
    if size > MAX_ATTRIBUTE_BYTES:
        raise FormatError(path, f"attribute {name!r} of {where} declares {size:,} bytes, more than the "
                                f"{MAX_ATTRIBUTE_BYTES:,} brdffit reads")
    return _attribute(path, obj, name, where)


class _Dataset(NamedTuple):
    """What the checks and the readers need of a dataset: where its data are, its type and shape, and its contents
    (``read``: a function that reads them, or a value already read by the inspection)."""

    virtual: bool
    external: list
    kind: str
    itemsize: int
    shape: tuple
    storage: int
    filtered: bool
    read: Any

    @classmethod
    def of_id(cls, dataset_id) -> "_Dataset":
        """The facts of a dataset from its low-level identifier (``dataset.id``; `_visit` opens only the identifier:
        the high-level `h5py.Dataset` and its file object cost as much a lookup as the reading itself), its
        contents read when asked (``read()``)."""
        h5py = _h5py()
        plist = dataset_id.get_create_plist()
        dtype = dataset_id.dtype
        return cls(plist.get_layout() == h5py.h5d.VIRTUAL,
                   [plist.get_external(i) for i in range(plist.get_external_count())], dtype.kind, dtype.itemsize,
                   dataset_id.shape or (), dataset_id.get_storage_size(), plist.get_nfilters() > 0,
                   lambda: _contents_of_id(dataset_id))

    @property
    def declared(self) -> int:
        """The bytes the dataset declares."""
        return math.prod(self.shape) * self.itemsize


def _contents_of_id(dataset_id):
    """A dataset's contents: a plain numeric array read with the low-level call, anything else as h5py reads it."""
    h5py = _h5py()
    dtype = dataset_id.dtype
    simple = dataset_id.get_space().get_simple_extent_type() in (h5py.h5s.SIMPLE, h5py.h5s.SCALAR)
    if not simple or dtype.kind not in "fiu" or dtype.fields is not None or dtype.subdtype is not None:
        return h5py.Dataset(dataset_id)[()]
    out = np.empty(dataset_id.shape, dtype=dtype)
    if out.size:
        dataset_id.read(h5py.h5s.ALL, h5py.h5s.ALL, out)
    return out[()] if out.ndim == 0 else out


def _stored(dataset: _Dataset) -> bool:
    """Whether the file stores a dataset's declared bytes (compressed: at most 1032 times fewer), not fill values."""
    return dataset.declared <= (MAX_FILTER_RATIO * dataset.storage if dataset.filtered else dataset.storage)


def _check_dataset(path, dataset: _Dataset, where: str, stored_only: bool = True) -> None:
    """Refuse a dataset that reads another file's data or declares more than `MAX_DATASET_BYTES`, and with
    ``stored_only`` (measured data) one that declares more than the file stores of it. (A chain that emcee grew to
    its planned length holds unwritten rows legitimately.)"""
    if dataset.virtual:
        raise FormatError(path, f"{where} is a virtual dataset (its data are in other files); brdffit reads data "
                                "from this file only")
    if dataset.external:
        raise FormatError(path, f"{where} keeps its data in external file(s) {[e[0] for e in dataset.external]}; "
                                "brdffit reads data from this file only")
    if dataset.declared > MAX_DATASET_BYTES:
        raise FormatError(path, f"{where} declares shape {dataset.shape} ({dataset.declared:,} bytes), more than "
                                f"the {MAX_DATASET_BYTES:,} bytes brdffit reads from one dataset")
    if stored_only and not _stored(dataset):
        raise FormatError(path, f"{where} declares shape {dataset.shape} ({dataset.declared:,} bytes) but the file "
                                f"stores {dataset.storage:,} bytes of it (unwritten rows read as fill values); not "
                                "measured data")


class _Contents(NamedTuple):
    """A group as the inspection read it (`_visit`): its name, its members (name -> `_Dataset` with its contents
    read, or None for a member that is not a dataset) and its attributes (name -> value). `read_measurements_group`
    reads it as it reads an h5py group."""

    name: str
    members: dict
    attrs: dict


def _opened_for_inspection(path):
    """``path`` opened read-only without file locking (in the inspecting child), or a FormatError."""
    try:
        return _h5py().File(path, "r", locking=False)
    except OSError as err:
        raise FormatError(path, f"cannot be opened as HDF5 (truncated or damaged?): {err}") from None


def _inspect(path) -> None:
    """Open ``path`` and read all of it, raising FormatError on what `inspect_hdf5` refuses (runs in the child)."""
    with _opened_for_inspection(path) as f:
        _visit(f, path)


def _visit(f, path, capture=()) -> dict:
    """Check every group, dataset and attribute of the open file ``f`` and read them; the contents of the groups
    named in ``capture`` (``"/measurements"``, ...) are kept.

    Returns:
        Group name -> `_Contents` of the captured groups found.
    """
    h5py = _h5py()
    captured = {}
    pending, visited = [("/", f)], 0
    while pending:
        where, group = pending.pop()
        attrs = {key: _check_attribute(path, group, key, where) for key in group.attrs}
        if not isinstance(group, h5py.Group):
            continue
        kept = {} if where in capture else None
        if kept is not None:
            captured[where] = _Contents(where, kept, attrs)
        for name in group:
            full = f"{where.rstrip('/')}/{name if isinstance(name, str) else repr(name)}"
            link = group.get(name, getlink=True)
            if isinstance(link, h5py.ExternalLink):
                raise FormatError(path, f"{full} is an external link to {link.filename}:{link.path}; brdffit "
                                        "reads data from this file only")
            if isinstance(link, h5py.SoftLink):
                continue  # its target is visited through its hard link
            visited += 1
            if visited > MAX_OBJECTS:
                raise FormatError(path, f"more than {MAX_OBJECTS:,} groups and datasets (a link cycle?)")
            # What `group[name]` opens, without the high-level objects for a dataset (`_Dataset.of_id`).
            oid = h5py.h5o.open(group.id, group._e(name))
            kind = h5py.h5i.get_type(oid)
            if kept is not None:
                kept[name] = None
            if kind == h5py.h5i.DATASET:
                dataset = _Dataset.of_id(oid)
                _check_dataset(path, dataset, full, stored_only=False)
                if _stored(dataset):  # fill values are no data to test libhdf5 on (and could fill memory)
                    value = dataset.read()
                    if kept is not None:
                        kept[name] = dataset._replace(read=lambda value=value: value)
                elif kept is not None:
                    kept[name] = dataset._replace(read=None)  # refused by read_measurements_group's check
                if h5py.h5a.get_num_attrs(oid):  # its attributes are checked as a group's are
                    pending.append((full, h5py.Dataset(oid)))
            elif kind == h5py.h5i.GROUP:
                pending.append((full, h5py.Group(oid)))
            elif kind == h5py.h5i.DATATYPE:
                pending.append((full, h5py.Datatype(oid)))
            else:
                raise FormatError(path, f"{full} is an HDF5 object of unknown type")
    return captured


def _write_all(fd: int, data: bytes) -> None:
    while data:
        data = data[os.write(fd, data):]


def _child_inspects(paths: list, write_end: int, reader=None) -> None:
    """The child of `_inspect_run`: a record per file (a status byte, a 4-byte length and the problem's text, an
    8-byte length and the pickled result of ``reader``) until the first refused file; never returns into the
    caller."""
    try:
        for path in paths:
            message, payload, refused = b"", b"", True
            try:
                if reader is None:
                    _inspect(path)
                else:
                    with _opened_for_inspection(path) as f:
                        capture, read = reader
                        captured = _visit(f, path, capture(path))
                        _check_brdffit_root(path, f)
                        result = read(f, path, captured)
                    payload = pickle.dumps(result, protocol=pickle.HIGHEST_PROTOCOL)
                refused = False
            except FormatError as err:
                message = err.problem.encode("utf-8", "replace")[:4096]
            except MemoryError:  # the child has the parent's limits: say which one the file's contents reached
                message = out_of_memory("reading its HDF5 data").encode("utf-8", "replace")
            except BaseException as err:  # noqa: BLE001 - whatever libhdf5 raises, the parent reports it
                message = f"cannot be read as HDF5 (truncated or damaged?): {err}".encode("utf-8", "replace")[:4096]
            _write_all(write_end, bytes([refused]) + len(message).to_bytes(4, "big") + message
                       + len(payload).to_bytes(8, "big") + payload)
            if refused:  # a file that libhdf5 failed on may have left it in any state: the next files get a new child
                break
    finally:
        os._exit(0)


def _read_record(fd: int, buffer: bytearray, deadline: float) -> tuple[bool, str, bytes] | None:
    """The next record of the child (refused, problem, payload), None at the deadline; EOFError when the child
    ended."""
    while True:
        if len(buffer) >= 5:
            size = int.from_bytes(buffer[1:5], "big")
            if len(buffer) >= 13 + size:
                length = int.from_bytes(buffer[5 + size:13 + size], "big")
                if len(buffer) >= 13 + size + length:
                    refused, message = bool(buffer[0]), bytes(buffer[5:5 + size]).decode("utf-8", "replace")
                    payload = bytes(buffer[13 + size:13 + size + length])
                    del buffer[:13 + size + length]
                    return refused, message, payload
        left = deadline - time.monotonic()
        if left <= 0 or not select.select([fd], [], [], left)[0]:
            return None
        chunk = os.read(fd, 1 << 20)
        if not chunk:
            raise EOFError
        buffer += chunk


def _inspect_run(paths: list, timeout: float, reader=None) -> list:
    """Inspect ``paths`` in turn in one forked child, until the first refused one: for each file it got to, the
    `FormatError` that refuses it, or (it passed) None, or with ``reader`` the reader's result; each file given
    ``timeout`` seconds."""
    read_end, write_end = os.pipe()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # JAX warns of fork(); the child runs no JAX, only libhdf5
        pid = os.fork()
    if pid == 0:
        os.close(read_end)
        # The child shares the parent's memory until it writes to it; a collection of the garbage collector would
        # visit (and so copy) every page of the parent's objects: a sizeable share of a batch's inspection with JAX
        # loaded.
        gc.disable()
        _child_inspects(paths, write_end, reader)
    os.close(write_end)
    outcomes, buffer, reaped = [], bytearray(), False
    try:
        for path in paths:
            try:
                record = _read_record(read_end, buffer, time.monotonic() + timeout)
            except EOFError:  # the child died without a word on this file
                _, status = os.waitpid(pid, 0)
                reaped = True
                signal_number = os.WTERMSIG(status) if os.WIFSIGNALED(status) else None
                outcomes.append(FormatError(path, f"libhdf5 crashed (signal {signal_number}) reading it: a damaged "
                                                  "HDF5 file" if signal_number is not None else
                                                  "cannot be read as HDF5: its inspection ended without an answer"))
                break
            if record is None:
                outcomes.append(FormatError(path, f"reading its HDF5 metadata did not finish within {timeout:g} s "
                                                  "(damaged metadata makes libhdf5 loop); the file is refused"))
                break
            refused, message, payload = record
            if refused:
                outcomes.append(FormatError(path, message))
                break
            outcomes.append(pickle.loads(payload) if reader is not None else None)
    finally:  # also when the wait itself is interrupted (Ctrl-C): the child must not outlive it
        os.close(read_end)
        if not reaped:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
    return outcomes


def _inspect_all(paths: list, timeout: float | None, reader=None) -> list:
    """`_inspect_run` until every file has its outcome, a new child after each refused file."""
    timeout = INSPECT_TIMEOUT_S if timeout is None else float(timeout)
    outcomes: list = []
    while len(outcomes) < len(paths):
        outcomes += _inspect_run(paths[len(outcomes):], timeout, reader)
    return outcomes


def inspect_hdf5_many(paths, timeout: float | None = None) -> list:
    """Check HDF5 files in forked child processes that read all of each file, ``timeout`` seconds a file.

    One child inspects the files in turn, so a batch of good files costs one fork (a fork of a process with JAX
    loaded costs more than the inspection of a small file). A child stops at the first file it refuses (or
    that does not finish in time, or crashes libhdf5), and the files after it go to a new child: every file is
    inspected by a child that has run libhdf5 only on files that passed. What is refused: see `inspect_hdf5`.

    Arguments:
        paths: the files.
        timeout: seconds each file may take (default `INSPECT_TIMEOUT_S`).

    Returns:
        For each file in order, None (it passed) or the `FormatError` that names it and the reason.
    """
    return _inspect_all(list(paths), timeout)


def inspect_hdf5(path, timeout: float | None = None) -> None:
    """Check an HDF5 file in a forked child process that reads all of it, killed after ``timeout`` seconds.

    What the child refuses (`_inspect`): a file libhdf5 cannot open, an unreadable attribute (e.g. an unknown string
    encoding), an attribute or dataset declaring more than `MAX_ATTRIBUTE_BYTES` / `MAX_DATASET_BYTES`, external
    links, external storage, virtual datasets (`read_measurements_group` also refuses unstored measurement rows).
    A child that does not finish in time, or that libhdf5 crashes, makes the file refused too; the parent never
    runs libhdf5 on such a file. Costs a fork of the process and a read of the file (`inspect_hdf5_many` inspects
    several files with one fork).

    Arguments:
        path: the file.
        timeout: seconds (default `INSPECT_TIMEOUT_S`).

    Raises:
        FormatError: naming the file and the reason.
    """
    problem = inspect_hdf5_many([path], timeout)[0]
    if problem is not None:
        raise problem


def _check_root(path, f) -> None:
    if "format_version" not in f.attrs:
        raise FormatError(path, "an HDF5 file but not one brdffit wrote (no 'format_version' attribute on /); "
                                "convert it with a table (CSV) or build Measurements from its arrays")
    version = _attr_text(_attribute(path, f, "format_version", "/"))
    if version != FORMAT_VERSION:
        raise FormatError(path, f"format_version {version!r} is not one this brdffit reads "
                                f"(it reads {FORMAT_VERSION!r}); update brdffit")


def _check_head(path: Path) -> None:
    """A regular file (`brdffit.io._common.open_regular`) with the HDF5 signature, or a FormatError."""
    head = read_head(path, HEAD_BYTES)
    check_not_lfs_pointer(path, head)
    if not head:
        raise FormatError(path, "the file is empty (expected an HDF5 file)")
    if not is_hdf5(head):
        raise FormatError(path, "not an HDF5 file (no HDF5 signature at the start or after a user block)")


def is_lock_conflict(err: OSError) -> bool:
    """Whether an h5py open failed because another process has the file open for writing (libhdf5's own lock)."""
    return err.errno in (errno.EAGAIN, errno.EWOULDBLOCK) or "unable to lock file" in str(err)


def open_h5_waiting(path, mode: str = "r", timeout: float | None = None):
    """``h5py.File(path, mode)``, waiting while another process holds libhdf5's lock on the file.

    libhdf5 locks a file while it is open (shared to read, exclusive to write) and fails at once where another
    process's lock is in the way; brdffit's processes hold a file open for milliseconds (a chain step, a read), so
    the open is tried again until ``timeout`` (default `brdffit.io.locking.LOCK_TIMEOUT_S`) has passed.

    Raises:
        OSError: what h5py raises, other than the lock's failure, or the lock's failure after ``timeout``.
    """
    deadline = time.monotonic() + (LOCK_TIMEOUT_S if timeout is None else float(timeout))
    pause = 0.001
    while True:
        try:
            return _h5py().File(path, mode)
        except OSError as err:
            if not is_lock_conflict(err) or time.monotonic() >= deadline:
                raise
        time.sleep(pause)
        pause = min(2 * pause, 0.05)


def _open_inspected(path: Path):
    """Open a file that has just passed `inspect_hdf5` and check brdffit's ``format_version``."""
    try:
        f = open_h5_waiting(path, "r")
    except OSError as err:
        raise FormatError(path, f"cannot be opened as HDF5 (truncated or damaged?): {err}") from None
    try:
        _check_brdffit_root(path, f)
    except BaseException:
        f.close()
        raise
    return f


def _check_brdffit_root(path, f) -> None:
    """`_check_root`, with an unreadable root a FormatError that says so."""
    try:
        _check_root(path, f)
    except (OSError, RuntimeError, KeyError) as err:
        raise FormatError(path, f"cannot read the root attributes (truncated or damaged?): {err}") from None


def open_hdf5(path):
    """Open an existing brdffit HDF5 file read-only, or raise a FormatError that says why not.

    The file must be a regular file (`brdffit.io._common.open_regular`) with the HDF5 signature that passes
    `inspect_hdf5`, with brdffit's ``format_version``. The caller closes the returned ``h5py.File``.
    """
    path = Path(path)
    with locked(path, shared=True):  # no chain step half written (posterior.StepBackend writes in place)
        _check_head(path)
        inspect_hdf5(path)
        return _open_inspected(path)


def read_hdf5_many(paths, capture, read, timeout: float | None = None):
    """Read several brdffit HDF5 files in the children that inspect them: this process never opens them.

    In the child, each file that passes the head check is opened and inspected as `inspect_hdf5` does, keeping the
    contents of the groups ``capture(path)`` names; then its ``format_version`` is checked and ``read(f, path,
    captured)`` runs, and what it returns comes back pickled. Reading each file once, in the inspection, spares a
    database task a second reading of every file in this process. ``read``
    must catch what it reports itself; whatever else it raises refuses the file. The files are inspected in one
    child until one is refused (`inspect_hdf5_many`).

    Arguments:
        paths: the files.
        capture: ``path -> group names`` (``"/measurements"``, ...) whose datasets and attributes to keep.
        read: ``(f, path, captured) -> result``: the open ``h5py.File`` (for the file's structure), the path and
            group name -> `_Contents` of the captured groups found (`read_measurements_group` reads one) to a
            picklable result.
        timeout: seconds each file may take (default `INSPECT_TIMEOUT_S`).

    Yields:
        ``(path, outcome)`` for each path in order: the reader's result, or the exception (`FormatError`,
        `FileNotFoundError`) that says why the file is refused.
    """
    paths = [Path(p) for p in paths]
    problems: dict = {}
    for path in paths:
        try:
            _check_head(path)
        except (FormatError, OSError) as err:
            problems[path] = err
    passing = [path for path in paths if path not in problems]
    outcomes = dict(zip(passing, _inspect_all(passing, timeout, (capture, read))))
    for path in paths:
        yield path, problems.get(path, outcomes.get(path))


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
    for name in _MEASUREMENT_DATASETS:
        arr = getattr(measurements, name)
        if arr is not None:
            group.create_dataset(name, data=np.asarray(arr, dtype=np.float64), compression=compression)
    group.attrs["channels"] = json.dumps(list(measurements.channels))
    group.attrs["meta"] = json.dumps(measurements.meta, sort_keys=True, allow_nan=True)


def read_measurements_group(group, path=None) -> Measurements:
    """Read a group written by `write_measurements_group` back into `Measurements` (exactly).

    Arguments:
        group: an open h5py group, or the `_Contents` the inspection kept of one (`read_hdf5_many`).
        path: the file, for the messages.

    Raises:
        FormatError: a missing or malformed dataset or attribute (naming ``path`` and the dataset).
        MeasurementError: arrays that break the rules of `Measurements` (naming ``path``).
    """
    if not isinstance(group, _Contents):
        group = _contents_of(group, path)
    where = group.name
    arrays: dict[str, Any] = {}
    for name in _MEASUREMENT_DATASETS:
        if name not in group.members:
            if name in ("sigma", "weights"):
                arrays[name] = None
                continue
            raise FormatError(path, f"dataset {where}/{name} is missing")
        dataset = group.members[name]
        if dataset is None or dataset.kind not in "fiu":
            raise FormatError(path, f"{where}/{name} is not a numeric dataset")
        _check_dataset(path, dataset, f"{where}/{name}")
        arrays[name] = np.asarray(dataset.read(), dtype=np.float64)
    try:
        channels = (parse_meta_json(path, _attr_text(group.attrs["channels"]), f"attribute {where}.channels")
                    if "channels" in group.attrs else None)
    except UnicodeDecodeError as err:
        raise FormatError(path, f"attribute channels of {where} is not UTF-8 text: {err}") from None
    if channels is not None and (not isinstance(channels, list) or not all(isinstance(c, str) for c in channels)):
        raise FormatError(path, f"attribute {where}.channels must be a JSON list of strings")
    meta = _meta_object(path, group.attrs["meta"], where) if "meta" in group.attrs else {}
    try:
        return Measurements(**arrays, channels=channels, meta=meta).check_informative()
    except MeasurementError as err:
        raise err.with_file(f"{path} ({where})" if path else where) from None


def _contents_of(group, path) -> _Contents:
    """An h5py group as `_Contents` whose members and attributes are looked up and read when asked, in the order
    `read_measurements_group` asks (a dataset's contents by its ``read()``)."""
    h5py = _h5py()

    def member(name):
        obj = group[name]
        return _Dataset.of_id(obj.id) if isinstance(obj, h5py.Dataset) else None

    return _Contents(group.name, _Lazy(lambda name: name in group, member),
                     _Lazy(lambda name: name in group.attrs, lambda name: _attribute(path, group, name, group.name)))


class _Lazy:
    """A read-only mapping of ``contains(name)`` and ``get(name)``."""

    def __init__(self, contains, get):
        self._contains, self._get = contains, get

    def __contains__(self, name) -> bool:
        return self._contains(name)

    def __getitem__(self, name):
        return self._get(name)


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


def read_meta(path, group: str = MEASUREMENTS_GROUP) -> dict:
    """The metadata of measurements in a brdffit HDF5 file (``Measurements.meta``) without reading their arrays:
    a results file's ``/measurements`` can hold millions of samples, and `brdffit export` needs only the
    wavelengths of their channels.

    Arguments:
        path: the file.
        group: the group holding the measurements (default ``/measurements``).

    Returns:
        The meta dict ({} where the group has none).

    Raises:
        FormatError: as `read_hdf5` (a missing group, a damaged or oversized attribute, metadata that is not a JSON
            object).
    """
    def meta(g):
        return _meta_object(path, _check_attribute(path, g, "meta", g.name), g.name) if "meta" in g.attrs else {}

    return read_hdf5_group(path, group, meta)


def _meta_object(path, raw, where: str) -> dict:
    """A measurements group's ``meta`` attribute (its value as read) as the JSON object it must be."""
    try:
        value = parse_meta_json(path, _attr_text(raw), f"attribute {where}.meta")
    except UnicodeDecodeError as err:
        raise FormatError(path, f"attribute meta of {where} is not UTF-8 text: {err}") from None
    if not isinstance(value, dict):
        raise FormatError(path, f"attribute {where}.meta must be a JSON object")
    return value


@memory_guarded("reading the HDF5 file")
def read_hdf5_group(path, group_name: str, read_fn: Callable[[Any], Any]):
    """Open a brdffit HDF5 file read-only, check its format version, and return ``read_fn(file[group_name])``.

    `read_hdf5` (the measurements) and `brdffit.distributed.table.read_results` (a results table) read through
    this.
    """
    h5py = _h5py()
    name = group_name.strip("/")
    with locked(path, shared=True), open_hdf5(path) as f:
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

    The whole copy holds the lock of the file's folder (`brdffit.io.locking.locked`), so that two processes
    updating one file (two `FitResult.save`, a posterior's summary while another posterior appends chain steps)
    each keep what the other wrote.

    Raises:
        FormatError: ``path`` exists but is not a brdffit HDF5 file.
        brdffit.io.locking.LockTimeout: another process held the lock for `LOCK_TIMEOUT_S`.
    """
    parts = [p for p in str(group_name).split("/") if p]
    if not parts:
        raise ValueError(f"group_name must name a group below the root, got {group_name!r}")
    path = Path(path)
    with locked(path):  # another process's update meanwhile would be lost (this one copies the file it read)
        return _update_locked(path, parts, write_fn)


def _update_locked(path: Path, parts: list, write_fn):
    h5py = _h5py()
    source = open_hdf5(path) if path.exists() else None
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
