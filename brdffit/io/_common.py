"""What every reader and writer shares: the file error, the Git LFS check, opening only regular files of a bounded
size and reading them into memory of their size, the message for running out of memory, bounded metadata JSON, and
atomic replacement of a file."""

from __future__ import annotations

import contextlib
import errno
import functools
import json
import os
import re
import stat
import tempfile
from glob import escape as glob_escape
from pathlib import Path

__all__ = ["FormatError", "atomic_path", "decode_text", "remove_abandoned", "check_not_lfs_pointer", "LFS_PREFIX",
           "MAX_FILE_BYTES", "open_regular", "read_file_bytes", "read_head", "parse_meta_json", "MAX_META_CHARS",
           "MAX_META_DEPTH", "memory_guard", "memory_guarded", "memory_limit", "out_of_memory"]

LFS_PREFIX = b"version https://git-lfs"

# The largest input file a reader takes (a MERL table is 35 MB, an RGL-EPFL file well under 100 MB): anything larger
# is refused before it is read, so that a huge or endless input never exhausts memory.
MAX_FILE_BYTES = 2 << 30
# Bounds of a JSON metadata text (a table's "# brdffit-meta:" line, an HDF5 file's meta attribute): its length in
# characters and the nesting depth of its lists and objects (json's recursive decoder would overflow the stack far
# deeper, and a deep structure is no metadata a person wrote).
MAX_META_CHARS = 1 << 20
MAX_META_DEPTH = 32


class FormatError(ValueError):
    """A file that cannot be read as the format it claims: the message names the file and what is wrong.

    Attributes:
        path: the file.
        line, column: where the problem is (1-based line of a text file, column name or number), when known.
    """

    def __init__(self, path, problem: str, line: int | None = None, column=None):
        self.path = None if path is None else str(path)
        self.problem, self.line, self.column = problem, line, column
        where = []
        if line is not None:
            where.append(f"line {line}")
        if column is not None:
            where.append(f"column {column}")
        prefix = f"{self.path}: " if self.path else ""
        super().__init__(prefix + (", ".join(where) + ": " if where else "") + problem)

    def __reduce__(self):
        return (FormatError, (self.path, self.problem, self.line, self.column))


def check_not_lfs_pointer(path, head: bytes) -> None:
    """Raise a `FormatError` when ``head`` (the first bytes of a file) is a Git LFS pointer instead of data."""
    if head.lstrip().startswith(LFS_PREFIX):
        raise FormatError(path, "this is a Git LFS pointer file, not the data; fetch the real file with "
                                "'git lfs pull' (or download it) and try again")


_KINDS = ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
          (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))


def _not_found(path: Path) -> FileNotFoundError:
    if path.is_symlink():
        return FileNotFoundError(f"{path}: a symbolic link to {os.readlink(path)!r}, which does not exist")
    return FileNotFoundError(f"{path}: no such file")


def open_regular(path):
    """Open a file for reading in binary mode, refusing anything that is not a regular file of a bounded size.

    The file is opened without blocking (O_NONBLOCK: a FIFO with no writer would otherwise block forever) and its
    type is read from the open descriptor (fstat), so what is checked is what is read.

    Arguments:
        path: the file.

    Returns:
        A binary file object (the caller closes it).

    Raises:
        FileNotFoundError: no such file (or a symbolic link to a missing file).
        FormatError: a directory, FIFO, device or socket; a symbolic link loop; a file larger than
            `MAX_FILE_BYTES`; a file that cannot be opened (permissions).
    """
    path = Path(path)
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except FileNotFoundError:
        raise _not_found(path) from None
    except OSError as err:
        if err.errno == errno.ELOOP:
            raise FormatError(path, "a symbolic link loop (the link leads, through links, back to itself)") from None
        raise FormatError(path, f"cannot be opened: {err.strerror}") from None
    try:
        info = os.fstat(fd)
        for is_kind, kind in _KINDS:
            if is_kind(info.st_mode):
                raise FormatError(path, f"{kind}, not a regular file; brdffit reads measurements from regular "
                                        "files only")
        if not stat.S_ISREG(info.st_mode):
            raise FormatError(path, "not a regular file; brdffit reads measurements from regular files only")
        if info.st_size > MAX_FILE_BYTES:
            raise FormatError(path, f"{info.st_size:,} bytes: larger than the {MAX_FILE_BYTES:,} bytes a reader "
                                    "takes")
        os.set_blocking(fd, True)
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def read_head(path, size: int) -> bytes:
    """The first ``size`` bytes of a regular file (see `open_regular` for what is refused)."""
    with open_regular(path) as fh:
        return fh.read(size)


def read_file_bytes(path) -> bytes:
    """The bytes of a data file; a missing file, anything but a regular file of at most `MAX_FILE_BYTES`, or a Git
    LFS pointer is an error that names the file.

    Arguments:
        path: the file.

    Returns:
        Its content.

    Raises:
        FileNotFoundError: "<path>: no such file". FormatError: not a regular file, too large (`open_regular`), a
            Git LFS pointer, or larger than the memory limit allows (`memory_guard`: the message names the limit).
    """
    path = Path(path)
    with open_regular(path) as fh:
        size = os.fstat(fh.fileno()).st_size
        with memory_guard(path, f"reading its {size:,} bytes"):
            data = _read_sized(fh, size)
    if len(data) > MAX_FILE_BYTES:
        raise FormatError(path, f"larger than the {MAX_FILE_BYTES:,} bytes a reader takes")
    check_not_lfs_pointer(path, data[:64])
    return data


_GROWN_CHUNK = 1 << 24  # what is read at a time of a file that grew after its size was taken


def _read_sized(fh, size: int) -> bytes:
    """The bytes of an open file whose size was ``size`` (fstat), read into a buffer of that size.

    ``fh.read(n)`` allocates ``n`` bytes before it reads, so the request is the file's size (plus one byte, to see
    whether it grew), never the 2 GiB bound: a 4 KB table under ``ulimit -v`` 2 GiB once failed with MemoryError
    here. A file that grew since is read on in 16 MiB pieces, up to one byte past `MAX_FILE_BYTES`.
    """
    data = fh.read(min(size, MAX_FILE_BYTES) + 1)
    if len(data) <= size:
        return data
    parts, total = [data], len(data)
    while total <= MAX_FILE_BYTES:
        chunk = fh.read(min(_GROWN_CHUNK, MAX_FILE_BYTES + 1 - total))
        if not chunk:
            break
        parts.append(chunk)
        total += len(chunk)
    return b"".join(parts)


def _limit_words(value: int) -> str:
    return f"{value / (1 << 30):.3g} GiB" if value >= 1 << 30 else f"{value / (1 << 20):.3g} MiB"


def memory_limit() -> str:
    """The memory limit this process runs under, in words, for a message about running out of memory.

    Returns:
        The smaller of the address-space limit (``RLIMIT_AS``, what ``ulimit -v`` sets) and the data-segment limit
        (``RLIMIT_DATA``, ``ulimit -d``) where one is set, e.g. ``"the address-space limit (ulimit -v) of 2 GiB"``;
        else the machine's memory (``"the memory available to the process"``).
    """
    try:
        import resource
    except ImportError:  # not a POSIX system
        return "the memory available to the process"
    limits = []
    for name, what, flag in (("RLIMIT_AS", "address-space", "-v"), ("RLIMIT_DATA", "data-segment", "-d")):
        number = getattr(resource, name, None)
        if number is None:
            continue
        soft = resource.getrlimit(number)[0]
        if soft != resource.RLIM_INFINITY:
            limits.append((soft, f"the {what} limit (ulimit {flag}) of {_limit_words(soft)}"))
    return min(limits)[1] if limits else "the memory available to the process"


def out_of_memory(what: str | None = None) -> str:
    """The one-line message for a MemoryError: what ran out and the limit it reached (`memory_limit`)."""
    doing = f" {what}" if what else ""
    return (f"out of memory{doing}: more memory is needed than {memory_limit()} allows; raise the limit or give "
            "a smaller input")


@contextlib.contextmanager
def memory_guard(path, what: str):
    """Turn a MemoryError raised inside into a `FormatError` that names the file and the memory limit.

    Arguments:
        path: the file being read (named by the message).
        what: what was being done, e.g. ``"reading the file"``, ``"parsing the table"``.
    """
    try:
        yield
    except MemoryError:
        raise FormatError(path, out_of_memory(what)) from None


def memory_guarded(what: str):
    """Decorate a reader ``f(path, ...)`` so that a MemoryError in it is a `FormatError` (`memory_guard`)."""
    def decorate(reader):
        @functools.wraps(reader)
        def guarded(path, *args, **kwargs):
            with memory_guard(path, what):
                return reader(path, *args, **kwargs)
        return guarded
    return decorate


_JSON_STRING = re.compile(r'"(?:[^"\\]|\\.)*"')
_BRACKETS = re.compile(r"[\[\]{}]")


def parse_meta_json(path, text: str, what: str):
    """Decode a metadata JSON text after bounding its size and nesting depth.

    Arguments:
        path: the file it came from (named by errors).
        text: the JSON text.
        what: where in the file it is (e.g. "the '# brdffit-meta:' line"), for the messages.

    Returns:
        The decoded value.

    Raises:
        FormatError: longer than `MAX_META_CHARS`, nested deeper than `MAX_META_DEPTH`, or not valid JSON.
    """
    if len(text) > MAX_META_CHARS:
        raise FormatError(path, f"{what} holds {len(text):,} characters of metadata; at most {MAX_META_CHARS:,} are "
                                "read")
    depth = deepest = 0
    for char in _BRACKETS.findall(_JSON_STRING.sub('""', text)):  # brackets inside strings do not nest
        if char in "[{":
            depth += 1
            deepest = max(deepest, depth)
        elif char in "]}":
            depth -= 1
    if deepest > MAX_META_DEPTH:
        raise FormatError(path, f"{what} nests its metadata {deepest} levels deep; at most {MAX_META_DEPTH} are "
                                "read")
    try:
        return json.loads(text)
    except (json.JSONDecodeError, RecursionError) as err:
        raise FormatError(path, f"{what} is not valid JSON: {err}") from None


def decode_text(path, data: bytes, kind: str) -> str:
    """The text of a text format's file, or a `FormatError`: empty, binary (a NUL byte), not UTF-8.

    Arguments:
        path: the file (for the message).
        data: its bytes.
        kind: what the file should be, for the message (``"a text table"``, ``"ALTA text data"``).

    Returns:
        The decoded text (a UTF-8 byte-order mark dropped).
    """
    if not data.strip():
        raise FormatError(path, "the file is empty")
    nul = data.find(b"\0")
    if nul >= 0:
        raise FormatError(path, f"binary data (a NUL byte at offset {nul}), not {kind}")
    try:
        with memory_guard(path, "decoding its text"):
            return data.decode("utf-8-sig")
    except UnicodeDecodeError as err:
        raise FormatError(path, f"not UTF-8 text (byte {err.object[err.start]:#04x} at offset {err.start})") from None


def _file_mode(path: Path) -> int:
    try:
        return path.stat().st_mode & 0o777  # keep an existing file's permissions
    except OSError:
        umask = os.umask(0o022)
        os.umask(umask)
        return 0o666 & ~umask  # what open() would have given a new file


def remove_abandoned(directory: Path, prefix: str, remove=None) -> None:
    """Delete what a killed writer left: the entries ``<prefix><pid>-*`` of ``directory`` whose process is gone.

    Arguments:
        directory: where the temporary entries lie.
        prefix: their names' start, before the writer's process id.
        remove: how to delete one (default: unlink a file; `shutil.rmtree` for a staging folder).
    """
    if not directory.is_dir():
        return
    for entry in directory.glob(glob_escape(prefix) + "*"):
        pid = entry.name[len(prefix):].split("-", 1)[0]
        if not pid.isdigit():
            continue
        try:
            os.kill(int(pid), 0)
        except ProcessLookupError:
            with contextlib.suppress(OSError):
                (remove or os.unlink)(entry)
        except PermissionError:
            pass  # another user's live process


@contextlib.contextmanager
def atomic_path(path, suffix: str | None = None):
    """Yield a temporary path beside ``path``; on success rename it onto ``path`` (os.replace), else delete it.

    An existing file at ``path`` is therefore never left half-written: it is either untouched or fully replaced.
    The temporary name carries the writer's process id (``.<name>.<pid>-<random><suffix>``), so that the next write
    of ``path`` deletes what a killed writer left behind.
    """
    path = Path(path)
    directory = path.parent if str(path.parent) else Path(".")
    prefix = f".{path.name}."
    remove_abandoned(directory, prefix)
    fd, tmp = tempfile.mkstemp(prefix=f"{prefix}{os.getpid()}-", suffix=suffix or ".tmp", dir=directory)
    os.close(fd)
    try:
        os.chmod(tmp, _file_mode(path))
        yield Path(tmp)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
