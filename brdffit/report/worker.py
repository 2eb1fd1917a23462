"""A helper process that draws the report's figures beside the process that computes them.

matplotlib's Agg renderer holds Python's lock while it draws, so two threads draw no faster than one; a report's
figures took most of a second of a fit's command on one core while the other one waited. A `DrawingWorker` is a
second Python process (``python -m brdffit.report.worker``, started with the fit so that its imports of NumPy and
matplotlib are done by the time the report begins) that draws the `brdffit.report.drawing.Drawing` objects it is
sent and writes their PNGs, while the caller draws others. It never loads JAX: a `Drawing` holds arrays, strings and
numbers only.

The protocol is pickled frames on the child's standard input and output: ``(path, drawing)`` in, ``(path, None)``
or ``(path, error text)`` out, in order. Whatever goes wrong (the process does not start, dies, answers an error or
not at all within `REPLY_SECONDS`), the caller draws that figure itself (`DrawingWorker.finish`): the worker only
ever saves time. Closing its input ends the process; so does the caller's exit, which closes the pipe.
"""

from __future__ import annotations

import pickle
import queue
import subprocess
import sys
import threading

__all__ = ["DrawingWorker", "REPLY_SECONDS", "NICENESS"]

# The longest wait for one figure's answer before the caller draws it itself (a figure takes well under a second).
REPLY_SECONDS = 60.0
# The worker's scheduling priority below its caller's (`os.nice`, where the system has it): its imports run while
# the fit keeps both cores busy, and should take only what the fit leaves idle; when the report is drawn, the fit's
# threads are done and the two processes share the cores alone.
NICENESS = 10


class DrawingWorker:
    """The helper process (module doc): `start` it early, `send` it drawings, `finish` to collect them.

    A context manager: leaving it closes the process (`close`)."""

    def __init__(self, process: subprocess.Popen | None):
        self._process = process
        self._sent: list = []  # (path, drawing) in the order sent
        self._outbox: queue.Queue = queue.Queue()
        self._replies: queue.Queue = queue.Queue()
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

    def send(self, path, drawing) -> None:
        """Have ``drawing`` drawn into ``path`` (a file path) by the worker; `finish` returns when it is written.
        The arrays are pickled and written by a thread of this process, so that a large figure does not hold the
        caller while the worker is still drawing the one before."""
        self._sent.append((str(path), drawing))
        self._outbox.put((str(path), drawing))

    def finish(self) -> list[str]:
        """Wait for every drawing sent; draw here each one the worker did not write. Returns their paths in the
        order sent."""
        done = []
        alive = self._process is not None
        for path, drawing in self._sent:
            error = "no worker"
            if alive:
                try:
                    answered, error = self._replies.get(timeout=REPLY_SECONDS)
                    error = error if answered == path else f"answer for {answered} instead"
                except queue.Empty:
                    error = "no answer"
            if error is not None:
                alive = False  # the order of its answers is lost: draw the rest here
                drawing(path)
            done.append(path)
        self._sent.clear()
        return done

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
        stream = self._process.stdout
        try:
            while True:
                self._replies.put(pickle.load(stream))
        except (EOFError, OSError, pickle.UnpicklingError, ValueError):
            pass


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

    if hasattr(os, "nice"):
        os.nice(NICENESS)
    importlib.import_module("brdffit.report.drawing")  # matplotlib loaded now, before the first figure arrives
    _serve(sys.stdin.buffer, sys.stdout.buffer)
    os._exit(0)  # every answer is flushed; freeing matplotlib's objects one by one would only delay the exit
