"""What every reader and writer shares: the file error, the Git LFS check and atomic replacement of a file."""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path

__all__ = ["FormatError", "atomic_path", "check_not_lfs_pointer", "LFS_PREFIX"]

LFS_PREFIX = b"version https://git-lfs"


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


def read_file_bytes(path) -> bytes:
    """The bytes of a data file; a missing file or a Git LFS pointer is an error that names the file.

    Arguments:
        path: the file.

    Returns:
        Its content.

    Raises:
        FileNotFoundError: "<path>: no such file". FormatError: the file is a Git LFS pointer.
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise FileNotFoundError(f"{path}: no such file") from None
    check_not_lfs_pointer(path, data[:64])
    return data


def _file_mode(path: Path) -> int:
    try:
        return path.stat().st_mode & 0o777  # keep an existing file's permissions
    except OSError:
        umask = os.umask(0o022)
        os.umask(umask)
        return 0o666 & ~umask  # what open() would have given a new file


@contextlib.contextmanager
def atomic_path(path, suffix: str | None = None):
    """Yield a temporary path beside ``path``; on success rename it onto ``path`` (os.replace), else delete it.

    An existing file at ``path`` is therefore never left half-written: it is either untouched or fully replaced.
    """
    path = Path(path)
    directory = path.parent if str(path.parent) else Path(".")
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix or ".tmp", dir=directory)
    os.close(fd)
    try:
        os.chmod(tmp, _file_mode(path))
        yield Path(tmp)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
