"""Progress of long work (frames, pixels, iterations) on stderr: a tqdm bar on a terminal,
plain periodic lines in a log.

A bar redraws itself with carriage returns, which a terminal shows as one moving line and a
log file keeps as one endless line. So the bar is drawn only when stderr is a terminal;
otherwise a line such as ``normals: 32768/94365 px (35 %), 12 s`` is written every
:data:`LINE_INTERVAL` seconds (none for work shorter than that), and a last one when such work
ends. ``PSRIG_PROGRESS`` overrides the choice: ``off`` (``psrig run -q``), ``bar``, ``lines``
or ``auto`` (the default); being an environment variable, it reaches worker processes too.
"""

import os
import sys
import time

__all__ = ["progress", "progress_mode", "LineProgress", "LINE_INTERVAL", "MODES"]

#: seconds between two plain progress lines
LINE_INTERVAL = 10.0
MODES = ("auto", "off", "bar", "lines")


def progress_mode(stream=None):
    """'off', 'bar' or 'lines': what :func:`progress` draws on ``stream`` (default stderr)."""
    mode = os.environ.get("PSRIG_PROGRESS", "auto").strip().lower() or "auto"
    if mode not in MODES:
        mode = "auto"  # a typo in the environment must not stop the work
    if mode != "auto":
        return mode
    stream = sys.stderr if stream is None else stream
    try:
        return "bar" if stream.isatty() else "lines"
    except (AttributeError, ValueError):  # closed or replaced streams
        return "lines"


def progress(iterable=None, *, total=None, desc=None, unit="it", disable=None):
    """A progress display on stderr (see the module's docstring).

    Parameters
    ----------
    iterable : iterable, optional
        Wrapped and iterated, counting one per item.
    total : int, optional
        Expected count (``len(iterable)`` when it has one).
    desc, unit : str
        What is counted: ``desc: n/total unit``.
    disable : bool, optional
        True: show nothing whatever the mode.

    Returns
    -------
    An object with tqdm's ``update(n)``, ``total``, ``refresh()``, ``close()``, iteration and
    the context-manager protocol.
    """
    mode = "off" if disable else progress_mode()
    if mode == "bar":
        from tqdm import tqdm

        return tqdm(iterable, total=total, desc=desc, unit=unit, leave=False, dynamic_ncols=True)
    return LineProgress(iterable, total=total, desc=desc, unit=unit, silent=mode == "off")


class LineProgress:
    """Plain progress lines: one every :data:`LINE_INTERVAL` seconds, and a last one at the end
    when any was written; nothing at all when ``silent``."""

    def __init__(self, iterable=None, *, total=None, desc=None, unit="it", silent=False, stream=None):
        self.iterable = iterable
        if total is None and iterable is not None and hasattr(iterable, "__len__"):
            total = len(iterable)
        self.total, self.desc, self.unit, self.silent = total, desc or "progress", unit, silent
        self.stream = stream
        self.n = 0
        self.start = self.last = time.monotonic()
        self.written = False
        self.closed = False

    def __iter__(self):
        for item in self.iterable:
            yield item
            self.update(1)
        self.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    def update(self, n=1):
        """Count ``n`` more; write a line when the interval has passed."""
        self.n += n
        now = time.monotonic()
        if now - self.last >= LINE_INTERVAL:
            self.last = now
            self._write(now)

    def refresh(self):
        """tqdm's redraw: nothing to redraw in a log."""

    def close(self):
        """End the work: a last line when any was written (a log then shows it finished)."""
        if not self.closed and self.written:
            self._write(time.monotonic(), done=True)
        self.closed = True

    def line(self, now=None, done=False):
        """The text of one progress line."""
        elapsed = (time.monotonic() if now is None else now) - self.start
        count = f"{self.n}/{self.total}" if self.total else f"{self.n}"
        share = f" ({100 * self.n / self.total:.0f} %)" if self.total else ""
        return f"{self.desc}: {count} {self.unit}{share}, {elapsed:.0f} s" + (", done" if done else "")

    def _write(self, now, done=False):
        if self.silent:
            return
        stream = self.stream or sys.stderr
        print(self.line(now, done), file=stream, flush=True)
        self.written = True
