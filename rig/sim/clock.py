"""Simulated time: the clock the simulated devices share.

A simulated rig's devices (light firmware, camera) read time from one :class:`SimClock`, which
runs ``scale`` simulated seconds per real second. At scale 40 an 8 s exposure and the firmware's
5 s watchdog take 0.2 s and 0.125 s of real time, so tests of long exposures stay fast while the
host drivers, which run in real time, meet the same proportions a real rig has. The host side
learns the scale from the simulated driver it talks to (``SimLightController.time_scale``), never
from the device.
"""

import time

__all__ = ["SimClock"]


class SimClock:
    """Simulated seconds since the clock was made, running ``scale`` times faster than real time.

    Parameters
    ----------
    scale : float
        Simulated seconds per real second (> 0; 1 is real time).
    """

    def __init__(self, scale=1.0):
        scale = float(scale)
        if not scale > 0:
            raise ValueError(f"time scale must be > 0, got {scale}")
        self.scale = scale
        self._origin = time.monotonic()

    def __repr__(self):
        return f"SimClock(scale={self.scale:g})"

    def now(self):
        """Simulated seconds since the clock was made (float)."""
        return (time.monotonic() - self._origin) * self.scale

    def real(self, seconds):
        """Real seconds that ``seconds`` of simulated time take."""
        return float(seconds) / self.scale

    def sleep(self, seconds):
        """Let ``seconds`` of simulated time pass (sleeps ``seconds / scale`` real seconds)."""
        if seconds > 0:
            time.sleep(self.real(seconds))
