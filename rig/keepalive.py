"""Holding a light through an exposure: keep-alives during it, a check of the light after it.

A light controller's firmware darkens every light when no command arrives for its watchdog
period (5 s in psrig light protocol 1), so a longer exposure would silently lose its light.
:class:`LightHold` sends the controller's keep-alive (``STATE?``) from a helper thread every
:attr:`rig.lights.LightController.keepalive_interval` seconds while the camera exposes, notes
every reply that names another light, and after the exposure asks the controller once more which
light is lit. :meth:`LightHold.problem` says what went wrong, or None when the light held.

The helper is bounded: it stops when the exposure ends, and by itself after ``max_seconds``.
"""

import threading
import time

from rig.lights import LightError

__all__ = ["LightHold", "lit_text"]


def lit_text(lit):
    """'light 3' or 'no light'."""
    return "no light" if lit is None else f"light {lit}"


class LightHold:
    """Context manager around one exposure of light ``expected`` (None: a dark frame).

    Parameters
    ----------
    lights : rig.lights.LightController
    expected : int or None
        The light that must stay lit (None: nothing to hold, nothing to check).
    max_seconds : float
        Real seconds after which the helper stops on its own (the exposure's longest wait).

    Attributes
    ----------
    lost : list of (float, int or None)
        (seconds into the exposure, light reported) of each keep-alive that found another
        light lit than ``expected``.
    errors : list of LightError
        Keep-alives that failed (the controller's own retries included).
    keepalives : int
        Keep-alives sent.
    after : int or None
        The light the controller reported lit after the exposure.
    """

    def __init__(self, lights, expected, max_seconds):
        self.lights, self.expected, self.max_seconds = lights, expected, float(max_seconds)
        self.lost, self.errors, self.keepalives, self.after = [], [], 0, expected
        self._stop = threading.Event()
        self._thread = None
        self._start = None

    def __enter__(self):
        self._start = time.monotonic()
        interval = self.lights.keepalive_interval
        if self.expected is not None and interval:
            self._thread = threading.Thread(target=self._run, args=(interval,), daemon=True,
                                            name="psrig light keep-alive")
            self._thread.start()
        return self

    def __exit__(self, exc_type, exc, tb):
        self._stop.set()
        if self._thread is not None:
            # a keep-alive in flight finishes within the controller's timeout and retries
            self._thread.join(timeout=self._join_timeout())
        if exc_type is None and self.expected is not None:
            self.after = self.lights.state()
        return False

    def _join_timeout(self):
        timeout = getattr(self.lights, "timeout", 1.0)
        return (1 + getattr(self.lights, "retries", 1)) * (timeout + 0.5)

    def _run(self, interval):
        while not self._stop.wait(interval):
            elapsed = time.monotonic() - self._start
            if elapsed > self.max_seconds:
                return
            try:
                lit = self.lights.keep_alive()
            except LightError as exc:
                self.errors.append(exc)
                return  # the check after the exposure decides; a dead line would only repeat
            self.keepalives += 1
            if lit != self.expected:
                self.lost.append((elapsed, lit))

    def problem(self):
        """Why the light did not hold through the exposure, or None when it did."""
        if self.expected is None:
            return None
        if self.lost:
            seconds, lit = self.lost[0]
            return (f"the light controller reported {lit_text(lit)} lit {seconds:.1f} s into the "
                    f"exposure instead of light {self.expected} (its watchdog or interlock cut "
                    f"the light)")
        if self.after != self.expected:
            return (f"after the exposure the light controller reported {lit_text(self.after)} "
                    f"lit instead of light {self.expected} (its watchdog or interlock cut the "
                    f"light during the exposure)")
        return None
