"""Advisory locks for brdffit's read-modify-write of its own files, so that concurrent commands lose no record.

Three records are written by read-modify-write, and two processes doing it at once would lose one's work: the
``exports.json`` that each ``brdffit export --fit`` adds a record to, a ``result.h5`` that `update_hdf5` copies
whole to replace one group, and the posterior chain that emcee's backend appends steps to in place. Each such
write holds `locked` on the file for its read and its write; a reader that must not see a write half done holds
it shared.

The lock is an ``flock(2)`` on the folder that holds the file, not on the file: an HDF5 file is replaced by a new
file (`atomic_path`), so a lock on the old one would guard nothing, and libhdf5 takes its own ``flock`` on the files
it opens (a second one on the same file makes its open fail). A lock file beside the data would be a file in a
`brdffit fit` output folder that brdffit's own checks refuse. A folder's lock therefore covers every file in it;
brdffit holds it for milliseconds (one chain step, one copy of a result file), never for a whole fit or chain.
A folder can itself be replaced (``brdffit fit --force`` swaps the output folder for a new one): the lock is taken
on the folder the path names once it is held, and taken again where the path has moved on meanwhile.

The locks are advisory: they order brdffit's processes (and its threads: a process holds one lock per folder, and
its other threads wait for it), not other programs. Where a folder cannot be opened or locked (no permission to
read it, a file system without ``flock``, a system without ``fcntl``) the write goes on without a lock, as before.
"""

from __future__ import annotations

import contextlib
import errno
import os
import threading
import time
from pathlib import Path

try:
    import fcntl
except ImportError:  # not a POSIX system: no locks
    fcntl = None

__all__ = ["locked", "LockTimeout", "LOCK_TIMEOUT_S"]

# How long a process waits for a folder's lock before it gives up. brdffit holds a lock for milliseconds (a chain
# step) to seconds (copying a large result.h5); a holder that keeps it this long is stopped or hung.
LOCK_TIMEOUT_S = 120.0


class LockTimeout(TimeoutError, ValueError):
    """Another process held a folder's lock for longer than the wait allows. A ``TimeoutError`` (an ``OSError``,
    as an unwritable folder is) and a ``ValueError`` (the CLI's "exit 2, one line")."""


class _Held:
    """The lock of one folder in this process: the thread that holds it, how often, and the descriptor."""

    def __init__(self):
        self.thread_lock = threading.RLock()
        self.count = 0
        self.exclusive = False
        self.fd: int | None = None


_HELD: dict = {}  # (st_dev, st_ino) of a folder -> _Held
_REGISTRY = threading.Lock()


def _entry(key) -> _Held:
    with _REGISTRY:
        return _HELD.setdefault(key, _Held())


def _folder(path) -> Path:
    parent = Path(path).parent
    return parent if str(parent) else Path(".")


def _open_folder(folder: Path) -> int | None:
    flags = os.O_RDONLY | getattr(os, "O_DIRECTORY", 0) | getattr(os, "O_CLOEXEC", 0)
    try:
        return os.open(folder, flags)
    except (PermissionError, FileNotFoundError, NotADirectoryError):
        return None  # no lock where none can be taken; a missing folder fails where the file is written


def _flock(fd: int, shared: bool, deadline: float, folder: Path) -> bool:
    """Take the lock on ``fd``, waiting until ``deadline``; False where the file system has no ``flock``."""
    mode = (fcntl.LOCK_SH if shared else fcntl.LOCK_EX) | fcntl.LOCK_NB
    pause = 0.001
    while True:
        try:
            fcntl.flock(fd, mode)
            return True
        except BlockingIOError:
            pass
        except OSError as err:
            if err.errno in (errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOSYS, errno.EINVAL):
                return False
            raise
        if time.monotonic() >= deadline:
            raise LockTimeout(f"{folder}: another process has held the lock on this folder for more than "
                              f"{LOCK_TIMEOUT_S:g} s (brdffit holds it for seconds at most); is a brdffit process "
                              "stopped or hung? Try again once it has ended")
        time.sleep(pause)
        pause = min(2 * pause, 0.05)


@contextlib.contextmanager
def locked(path, *, shared: bool = False, timeout: float | None = None):
    """Hold the lock of the folder that holds ``path`` for the duration of the ``with`` block.

    Reentrant in a thread: a block inside another on a path of the same folder holds the lock already (a shared
    block inside an exclusive one is fine; an exclusive one inside a shared one is a RuntimeError, since two
    processes upgrading their shared locks at once would wait for each other forever).

    Arguments:
        path: the file to be read or written (it need not exist yet); its folder must exist.
        shared: a reader's lock, which other readers may hold at the same time; by default a writer's, which no
            one else holds meanwhile.
        timeout: seconds to wait for another process's lock (default `LOCK_TIMEOUT_S`).

    Raises:
        LockTimeout: the lock was not free within ``timeout``.
    """
    if fcntl is None:
        yield
        return
    folder = _folder(path)
    deadline = time.monotonic() + (LOCK_TIMEOUT_S if timeout is None else float(timeout))
    while True:
        fd = _open_folder(folder)
        if fd is None:
            yield
            return
        info = os.fstat(fd)
        key = (info.st_dev, info.st_ino)
        held = _entry(key)
        held.thread_lock.acquire()  # another thread of this process holding it: wait for it
        if held.count:  # this thread holds it already
            os.close(fd)
            try:
                if held.exclusive or shared:
                    held.count += 1
                    try:
                        yield
                    finally:
                        held.count -= 1
                    return
                raise RuntimeError(f"{folder}: an exclusive lock asked for inside a shared one")
            finally:
                held.thread_lock.release()
        try:
            if not _flock(fd, shared, deadline, folder):
                os.close(fd)
                fd = None
                yield
                return
            try:
                now = os.stat(folder)
            except FileNotFoundError:
                now = None
            if now is None or (now.st_dev, now.st_ino) != key:  # the folder was replaced meanwhile: lock the new one
                os.close(fd)  # releases the lock
                fd = None
                continue
            held.fd, held.count, held.exclusive = fd, 1, not shared
            try:
                yield
            finally:
                held.fd, held.count, held.exclusive = None, 0, False
            return
        finally:
            if fd is not None:
                os.close(fd)
            held.thread_lock.release()
