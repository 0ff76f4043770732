"""A batch's progress line on stderr: tables done, fits stored, fits/s, ETA.

On a terminal the line redraws in place; otherwise (a log file, CI) it prints a
plain line at most every ``interval_s`` seconds, so logs stay short. While a batch
runs (:meth:`ProgressLine.ticking`) the line is also redrawn between results: a first
table that compiles for a minute showed one unchanging line, as if the batch hung.
"""

from __future__ import annotations

import contextlib
import sys
import threading
import time


def format_duration(seconds: float) -> str:
    if seconds != seconds or seconds == float("inf"):  # NaN or inf: nothing measured yet
        return "?"
    s = int(round(seconds))
    if s < 60:
        return f"{s}s"
    if s < 3600:
        return f"{s // 60}m{s % 60:02d}s"
    return f"{s // 3600}h{s % 3600 // 60:02d}m"


class ProgressLine:
    """Counts tables and fits as they finish and draws the line."""

    def __init__(self, total_tables: int, *, skipped: int = 0, stream=None,
                 interval_s: float = 30.0, enabled: bool = True):
        self.total = total_tables
        self.skipped = skipped
        self.stream = stream if stream is not None else sys.stderr
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.interval_s = interval_s if not self.tty else 0.2
        self.enabled = enabled
        self.tables = 0
        self.fits = 0
        self.failed_tables = 0
        self.t0 = time.monotonic()
        self._last_draw = float("-inf")
        self._last_counts: tuple | None = None  # what the last line in a log said
        # results and the ticker (:meth:`ticking`) draw from two threads
        self._lock = threading.Lock()

    def _counts(self) -> tuple:
        return self.tables, self.fits, self.failed_tables

    def update(self, *, fits: int, failed: bool, tables: int = 1) -> None:
        """``fits`` more fits; ``tables`` more tables finished (0 while a table's
        other fits are still running), ``failed`` if the table had a failure."""
        self.tables += tables
        self.fits += fits
        self.failed_tables += failed
        self.draw()

    def line(self) -> str:
        elapsed = time.monotonic() - self.t0
        rate = self.fits / elapsed if elapsed > 0 else 0.0
        per_table = elapsed / self.tables if self.tables else float("nan")
        eta = per_table * (self.total - self.tables)
        width = 24
        filled = int(width * self.tables / self.total) if self.total else width
        # the fits stored so far beside the tables: a table counts once all its fits are
        # in, and a slow first table read "0/8 tables" with fits already stored
        parts = [f"[{'#' * filled}{'.' * (width - filled)}] {self.tables}/{self.total} tables",
                 f"{self.fits} fit{'' if self.fits == 1 else 's'} stored",
                 f"{rate:.2f} fits/s", f"elapsed {format_duration(elapsed)}",
                 f"ETA {format_duration(eta) if self.tables < self.total else '0s'}"]
        if self.failed_tables:
            parts.append(f"{self.failed_tables} failed")
        if self.skipped:
            parts.append(f"{self.skipped} already done")
        return "  ".join(parts)

    def draw(self, force: bool = False) -> None:
        if not self.enabled:
            return
        with self._lock:
            now = time.monotonic()
            if (not force and now - self._last_draw < self.interval_s
                    and self.tables < self.total):
                return
            self._last_draw = now
            if self.tty:
                self.stream.write("\r\x1b[2K" + self.line())
            else:
                self._last_counts = self._counts()
                self.stream.write(self.line() + "\n")
            self.stream.flush()

    @contextlib.contextmanager
    def ticking(self, every_s: float = 1.0):
        """Within it, the line is redrawn every ``every_s`` seconds (at most every
        ``interval_s`` in a log) whether or not a result came: its elapsed time moves
        while the first fits compile, and a log shows the batch alive."""
        if not self.enabled:
            yield self
            return
        stop = threading.Event()

        def tick():
            while not stop.wait(every_s):
                self.draw()

        ticker = threading.Thread(target=tick, name="brdffit-progress", daemon=True)
        ticker.start()
        try:
            yield self
        finally:
            stop.set()
            ticker.join()

    def say(self, text: str) -> None:
        """One line of its own (a wait before the first count: reaching a scheduler)."""
        if self.enabled:
            with self._lock:
                self.stream.write(text + "\n")
                self.stream.flush()

    def finish(self) -> None:
        """The last line: in a log (not a TTY) the count where the batch ended, done or
        interrupted (an interrupted one printed none since the last 30 s)."""
        if not self.enabled:
            return
        with self._lock:
            if self.tty:
                self.stream.write("\n")
            elif self._last_counts != self._counts():
                self.stream.write(self.line() + "\n")
            self.stream.flush()
