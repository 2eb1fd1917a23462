"""A helper process that draws the report's figures beside the process that computes them.

matplotlib's Agg renderer holds Python's lock while it draws, so two threads draw no faster than one; a report's
figures took most of a second of a fit's command on one core while the other one waited. A `DrawingWorker` is a
second Python process (``python -m brdffit.report.worker``, started with the fit so that its imports of NumPy and
matplotlib are done by the time the report begins) that draws the `brdffit.report.drawing.Drawing` objects it is
given and writes their PNGs, while the caller draws others. It never loads JAX: a `Drawing` holds arrays, strings
and numbers only.

The worker holds one figure at a time: the caller's `send` queues a drawing, the worker is given the next one when
it has answered the last, and `finish` draws in the caller whatever is still queued, then waits for the one figure
the worker is drawing. A worker slowed down (a loaded machine) therefore delays the report by at most one figure.
It runs at its caller's priority: at a lower one (niceness 10, so that its imports would take only what the fit
leaves idle), a machine loaded by two other processes left it a tenth of a core and the report took 4-7 s instead
of 1.3 s, for no gain measured on an idle machine (docs/benchmarks.md).

The protocol is pickled frames on the child's standard input and output: ``(path, drawing)`` in, ``(path, None)``
or ``(path, error text)`` out. Whatever goes wrong (the process does not start, dies, answers an error or not at
all within `REPLY_SECONDS`), the caller draws that figure itself: the worker only ever saves time. Closing its
input ends the process; so does the caller's exit, which closes the pipe.
"""

from __future__ import annotations

import collections
import pickle
import queue
import subprocess
import sys
import threading

__all__ = ["DrawingWorker", "REPLY_SECONDS"]

# The longest wait for one figure's answer before the caller draws it itself (a figure takes well under a second).
REPLY_SECONDS = 60.0


class DrawingWorker:
    """The helper process (module doc): `start` it early, `send` it drawings, `finish` to collect them.

    A context manager: leaving it closes the process (`close`)."""

    def __init__(self, process: subprocess.Popen | None):
        self._process = process
        self._changed = threading.Condition()  # guards the state below; notified when the worker frees or fails
        self._queued: collections.deque = collections.deque()  # (path, drawing) not given to the worker yet
        self._drawing = None  # the (path, drawing) the worker holds, or None
        self._failed = process is None  # no process, or it answered an error or ended: it is given nothing more
        self._given = 0  # figures given to the worker so far
        self._outbox: queue.Queue = queue.Queue()
        if process is not None:
            threading.Thread(target=self._write, name="brdffit drawing worker: send", daemon=True).start()
            threading.Thread(target=self._read, name="brdffit drawing worker: receive", daemon=True).start()

    @classmethod
    def start(cls) -> "DrawingWorker":
        """A worker whose process is starting now (its imports run while the caller goes on); one without a process
        (every figure then drawn by the caller) where it cannot be started."""
        try:
            process = subprocess.Popen([sys.executable, "-m", "brdffit.report.worker"], stdin=subprocess.PIPE,
                                       stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
        except (OSError, ValueError):  # no interpreter to start (an embedded Python), or no process left
            process = None
        return cls(process)

    @property
    def given(self) -> int:
        """How many figures the worker has been given to draw."""
        return self._given

    def send(self, path, drawing) -> None:
        """Queue ``drawing`` to be drawn into ``path`` (a file path) by the worker, or by `finish` if the worker has
        not taken it by then. The arrays are pickled and written by a thread of this process, so that a large figure
        does not hold the caller."""
        with self._changed:
            self._queued.append((str(path), drawing))
            self._give()

    def finish(self) -> None:
        """Draw here every drawing still queued, then wait for the one the worker holds (drawn here too if the
        worker fails on it or does not finish it within `REPLY_SECONDS`)."""
        while True:
            with self._changed:
                if self._queued:
                    path, drawing = self._queued.popleft()
                else:
                    if not self._changed.wait_for(lambda: self._drawing is None or self._failed,
                                                  timeout=REPLY_SECONDS):
                        self._failed = True
                    held, self._drawing = self._drawing, None  # None unless the worker failed on it
                    break
            drawing(path)
        if held is not None:
            held[1](held[0])

    def close(self) -> None:
        """End the process (its input closed; killed if it has not exited within a few seconds)."""
        if self._process is None:
            return
        self._outbox.put(None)
        try:
            self._process.wait(timeout=5.0)
        except subprocess.TimeoutExpired:
            self._process.kill()
            self._process.wait()
        self._process = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    def _give(self) -> None:
        """Give the worker the next queued drawing if it holds none (called holding ``_changed``)."""
        if self._failed or self._drawing is not None or not self._queued:
            return
        self._drawing = self._queued.popleft()
        self._given += 1
        self._outbox.put(self._drawing)

    def _write(self) -> None:
        stream = self._process.stdin
        try:
            while (job := self._outbox.get()) is not None:
                pickle.dump(job, stream, protocol=pickle.HIGHEST_PROTOCOL)
                stream.flush()
        except (OSError, ValueError, pickle.PicklingError):
            pass  # the process is gone: `finish` draws what it has not answered
        finally:
            try:
                stream.close()
            except OSError:
                pass

    def _read(self) -> None:
        """Take the worker's answers: a figure drawn frees the worker for the next queued one; an error, an answer
        for another figure or the end of its output marks it failed (`finish` draws the figure it held)."""
        stream = self._process.stdout
        try:
            while True:
                path, error = pickle.load(stream)
                with self._changed:
                    if error is not None or self._drawing is None or path != self._drawing[0]:
                        self._failed = True
                    else:
                        self._drawing = None
                        self._give()
                    self._changed.notify_all()
                    if self._failed:
                        return
        except (EOFError, OSError, pickle.UnpicklingError, ValueError):
            with self._changed:
                self._failed = True
                self._changed.notify_all()


def _serve(source, sink) -> None:
    """Draw every ``(path, drawing)`` read from ``source`` and answer on ``sink`` until ``source`` ends."""
    while True:
        try:
            path, drawing = pickle.load(source)
        except EOFError:
            return
        try:
            drawing(path)
            error = None
        except Exception as exc:  # noqa: BLE001 - answered: the caller draws this figure itself
            error = f"{type(exc).__name__}: {exc}"
        pickle.dump((path, error), sink, protocol=pickle.HIGHEST_PROTOCOL)
        sink.flush()


if __name__ == "__main__":
    import importlib
    import os

    importlib.import_module("brdffit.report.drawing")  # matplotlib loaded now, before the first figure arrives
    _serve(sys.stdin.buffer, sys.stdout.buffer)
    os._exit(0)  # every answer is flushed; freeing matplotlib's objects one by one would only delay the exit
