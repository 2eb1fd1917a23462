"""A progress line on stderr for long work (model selection, multistart fits, MCMC), with no extra dependency."""

from __future__ import annotations

import sys
import time

__all__ = ["Progress"]


class Progress:
    """One line on stderr, redrawn in place on a terminal and written once per update otherwise (logs, pipes).

    ``Progress("select", 10)`` then ``update(3, "lambert+ggx")`` shows ``select 3/10 (30%) 12 s  lambert+ggx``.
    A disabled `Progress` prints nothing, so callers need no branches.

    Arguments:
        label: what is progressing.
        total: the number of units of work.
        enabled: print at all.
        unit: the units' name, shown after the counts (e.g. ``"steps"``).
        stream: where to write (default ``sys.stderr``).
    """

    def __init__(self, label: str, total: int, *, enabled: bool = True, unit: str = "", stream=None):
        self.label, self.total, self.enabled, self.unit = label, max(int(total), 1), enabled, unit
        self.stream = sys.stderr if stream is None else stream
        self.start = time.perf_counter()
        self._percent = -1

    @property
    def _interactive(self) -> bool:
        return bool(getattr(self.stream, "isatty", lambda: False)())

    def update(self, done: int, detail: str = "") -> None:
        """Show that ``done`` units are finished; on a non-terminal only whole-percent changes or new details are
        written, so a long MCMC run does not flood a log.

        Arguments:
            done: units finished so far.
            detail: what is being worked on now.
        """
        if not self.enabled:
            return
        percent = int(100 * done / self.total)
        if percent == self._percent and not detail:
            return
        self._percent = percent
        unit = f" {self.unit}" if self.unit else ""
        text = f"{self.label} {done}/{self.total}{unit} ({percent}%) {time.perf_counter() - self.start:.0f} s"
        if detail:
            text += f"  {detail}"
        if self._interactive:
            print(f"\r\033[K{text}", end="", file=self.stream, flush=True)
        elif detail or percent % 10 == 0:
            print(text, file=self.stream, flush=True)

    def close(self, detail: str = "") -> None:
        """Finish the line with the total time (and ``detail``)."""
        if not self.enabled:
            return
        text = f"{self.label} done in {time.perf_counter() - self.start:.1f} s"
        if detail:
            text += f"  {detail}"
        if self._interactive:
            print(f"\r\033[K{text}", file=self.stream, flush=True)
        else:
            print(text, file=self.stream, flush=True)
