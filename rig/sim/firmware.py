"""The light-controller firmware, simulated behind a pseudo-terminal.

:class:`SimulatedLightFirmware` speaks "psrig light protocol 1" (see ``rig/lights.py`` and
``rig/firmware/psrig_lights/psrig_lights.ino``, which it mirrors) on the master side of a pty;
the real :class:`rig.lights.SerialLightController` opens the slave side with pyserial as it would
open ``/dev/ttyACM0``. So the tests exercise the very driver a lab rig uses.

Light indices on the wire are 0-based, as everywhere in psrig: ``ON 0`` lights the first LED.

Faults can be injected to test the host's recovery; each applies to the next received command
(or the next ``count`` commands):

``drop_reply``
    the command is carried out but its reply is never sent (a lost reply);
``garble``
    the command is carried out but its reply arrives corrupted (line noise);
``err``
    the command is not carried out and ``ERR 1 unknown command`` comes back, as when a command
    is corrupted on its way to the board;
``interlock``
    ``ON`` is refused with ``ERR 3`` (the enclosure's door interlock is open);
``disconnect``
    the board vanishes (USB cable pulled): the pty is hung up and every light goes dark.
"""

import os
import select
import termios
import threading
import time
import tty
from collections import deque

from rig.sim.clock import SimClock

__all__ = ["SimulatedLightFirmware", "FAULT_KINDS", "PROTOCOL_ID"]

PROTOCOL_ID = "PSRIG-LIGHTS 1"
FAULT_KINDS = ("drop_reply", "garble", "err", "interlock", "disconnect")
MAX_LINE = 64  # the sketch's line buffer; longer lines are rejected, not overflowed
TIMELINE_LENGTH = 4096  # light changes kept for exposures to integrate over
_POLL = 0.01  # seconds between watchdog checks


class SimulatedLightFirmware:
    """The light controller's firmware on a pseudo-terminal, in its own thread.

    Parameters
    ----------
    count : int
        Number of lights (indices 0 .. count-1 on the wire).
    watchdog : float
        Seconds without any command after which every light is switched off (5 s on the board).
    boot_delay : float
        Seconds after :meth:`start` during which the board is still booting and discards input,
        as an Arduino's bootloader does after the reset the port's opening triggers.
    faults : dict, optional
        ``{kind: count}`` faults to inject from the start, kinds in :data:`FAULT_KINDS`.
    ident : str, optional
        Reply to ``ID?`` instead of ``PSRIG-LIGHTS 1 <count>`` (to test a wrong device).
    clock : rig.sim.clock.SimClock, optional
        The firmware's time (watchdog, boot delay, the light timeline); default real time. A
        simulated camera sharing it integrates what was lit over its exposures
        (:meth:`light_weights`).

    Attributes
    ----------
    history : list of str
        Every command line received, in order (without the line ending).
    watchdog_trips : int
        How many times the watchdog switched a light off.
    """

    def __init__(self, count=32, *, watchdog=5.0, boot_delay=0.0, faults=None, ident=None,
                 clock=None):
        if int(count) < 1:
            raise ValueError(f"count must be at least 1, got {count}")
        self.clock = clock or SimClock()
        self.count = int(count)
        self.watchdog = float(watchdog)
        self.boot_delay = float(boot_delay)
        self.ident = ident if ident is not None else f"{PROTOCOL_ID} {self.count}"
        self.history = []
        self.watchdog_trips = 0
        self._levels = [255] * self.count
        self._lit = None
        # (simulated time, light lit or None, its level): every change, oldest first; bounded,
        # since an exposure only looks back over its own duration
        self._timeline = deque([(float("-inf"), None, 0)], maxlen=TIMELINE_LENGTH)
        self._faults = {}
        self._lock = threading.RLock()
        self._master = self._slave = None
        self._thread = None
        self._stop = threading.Event()
        self._port = None
        for kind, n in (faults or {}).items():
            self.inject(kind, n)

    # -- public state -------------------------------------------------------------------------

    @property
    def lit(self):
        """Index of the light currently on, or None when all are off."""
        return self._lit

    @property
    def levels(self):
        """Brightness level (0-255) of each light, a copy (list of ``count`` ints)."""
        return list(self._levels)

    @property
    def port(self):
        """Path of the pty slave to open as a serial port, or None before :meth:`start`."""
        return self._port

    @property
    def connected(self):
        """True while the pty is up (false after :meth:`stop` or a ``disconnect`` fault)."""
        return self._master is not None

    def light_weights(self, start, end):
        """What was lit between simulated times ``start`` and ``end``: ``{light: weight}``.

        A light's weight is the share of the interval it was lit times its level / 255; an
        instant (``end <= start``) gives the state at ``start``. Lights off contribute nothing,
        so a light cut by the watchdog half way through gives 0.5.
        """
        with self._lock:
            self._check_watchdog()
            changes = list(self._timeline)
        weights = {}
        span = end - start
        for (t, lit, level), nxt in zip(changes, changes[1:] + [(float("inf"), None, 0)]):
            if lit is None or level == 0:
                continue
            if span <= 0:
                share = 1.0 if t <= start < nxt[0] else 0.0
            else:
                share = max(0.0, min(end, nxt[0]) - max(start, t)) / span
            if share > 0:
                weights[lit] = weights.get(lit, 0.0) + share * level / 255.0
        return weights

    def _set_lit(self, index, when=None):
        """Switch to ``index`` (None: all off) and note the change in the timeline."""
        self._lit = index
        level = 0 if index is None else self._levels[index]
        self._timeline.append((self.clock.now() if when is None else when, index, level))

    def inject(self, kind, count=1):
        """Make the next ``count`` commands suffer fault ``kind`` (one of :data:`FAULT_KINDS`)."""
        if kind not in FAULT_KINDS:
            raise ValueError(f"unknown fault {kind!r}; expected one of {', '.join(FAULT_KINDS)}")
        with self._lock:
            self._faults[kind] = self._faults.get(kind, 0) + int(count)

    def pending_faults(self):
        """``{kind: count}`` of injected faults not yet consumed."""
        with self._lock:
            return {k: n for k, n in self._faults.items() if n > 0}

    # -- life cycle ---------------------------------------------------------------------------

    def start(self):
        """Open the pty, start the firmware thread and return the slave's path (e.g. ``/dev/pts/5``)."""
        if self._thread is not None and self._thread.is_alive():
            return self._port
        self._master, self._slave = os.openpty()
        # Raw mode before anyone opens the port: otherwise the line discipline would echo the
        # host's commands back to it and turn "\n" into "\r\n".
        tty.setraw(self._slave, termios.TCSANOW)
        self._port = os.ttyname(self._slave)
        self._stop.clear()
        self._boot_until = self.clock.now() + self.boot_delay
        self._last_command = self.clock.now()
        self._thread = threading.Thread(target=self._run, name=f"light-firmware {self._port}",
                                        daemon=True)
        self._thread.start()
        return self._port

    def stop(self):
        """Switch everything off, stop the thread and close the pty (idempotent)."""
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)
        self._thread = None
        self._hang_up()

    def __enter__(self):
        self.start()
        return self

    def __exit__(self, *exc):
        self.stop()
        return False

    def _hang_up(self):
        # State first, then the fds: whoever sees the hang-up must also see it dark and gone.
        with self._lock:
            self._set_lit(None)
        fds, self._master, self._slave = (self._master, self._slave), None, None
        for fd in fds:
            if fd is not None:
                try:
                    os.close(fd)
                except OSError:
                    pass

    # -- firmware loop ------------------------------------------------------------------------

    def _run(self):
        buffer, overflow = b"", False
        while not self._stop.is_set() and self._master is not None:
            master = self._master
            try:
                ready, _, _ = select.select([master], [], [], _POLL)
                data = os.read(master, 1024) if ready else b""
            except (OSError, ValueError):
                data = b""  # no slave open right now: nothing to read
                time.sleep(_POLL)
            with self._lock:
                self._check_watchdog()
            if not data or self.clock.now() < self._boot_until:
                continue
            buffer += data
            while b"\n" in buffer and self._master is not None:
                line, buffer = buffer.split(b"\n", 1)
                if overflow:  # the tail of an over-long line, already answered
                    overflow = False
                    continue
                self._receive(line)
            if len(buffer) > MAX_LINE and not overflow:
                self._send("ERR 1 line too long")
            if len(buffer) > MAX_LINE:
                buffer, overflow = b"", True

    def _check_watchdog(self):
        # Called with the lock held. The light goes out exactly ``watchdog`` after the last
        # command, as the sketch's millis() comparison does, however late this poll runs.
        if (self.watchdog > 0 and self._lit is not None
                and self.clock.now() - self._last_command > self.watchdog):
            self._set_lit(None, when=self._last_command + self.watchdog)
            self.watchdog_trips += 1

    def _take_fault(self, kind):
        with self._lock:
            if self._faults.get(kind, 0) > 0:
                self._faults[kind] -= 1
                return True
        return False

    def _receive(self, raw):
        text = raw.decode("ascii", errors="replace").strip()
        if not text:
            return
        self.history.append(text)
        with self._lock:
            self._check_watchdog()  # a trip due before this command happened before it
            self._last_command = self.clock.now()
        if self._take_fault("disconnect"):
            self._hang_up()
            return
        if self._take_fault("err"):
            self._send("ERR 1 unknown command")
            return
        with self._lock:
            reply = self.execute(text)
        if self._take_fault("drop_reply"):
            return
        if self._take_fault("garble"):
            self._send_bytes(_garble(reply.encode("ascii")))
            return
        self._send(reply)

    def _send(self, line):
        self._send_bytes(line.encode("ascii") + b"\n")

    def _send_bytes(self, data):
        try:
            os.write(self._master, data)
        except (OSError, TypeError):
            pass  # hung up meanwhile: the reply is lost, as on a pulled cable

    # -- the protocol -------------------------------------------------------------------------

    def execute(self, text):
        """Carry out one command line and return the reply line (without ``\\n``)."""
        words = text.split()
        name, args = words[0], words[1:]
        if name == "ID?" and not args:
            return self.ident
        if name == "STATE?" and not args:
            return f"STATE {'-' if self._lit is None else self._lit}"
        if name == "OFF" and not args:
            self._set_lit(None)
            return "OK OFF"
        if name == "ON" and len(args) == 1:
            index = self._index(args[0])
            if index is None:
                return f"ERR 2 bad index {args[0]}"
            if self._take_fault("interlock"):
                self._set_lit(None)
                return "ERR 3 interlock open"
            self._set_lit(index)
            return f"OK ON {index}"
        if name == "LEVEL" and len(args) == 2:
            index = self._index(args[0])
            if index is None:
                return f"ERR 2 bad index {args[0]}"
            if not (args[1].isdigit() and len(args[1]) <= 3 and int(args[1]) <= 255):
                return f"ERR 1 bad level {args[1]}"
            self._levels[index] = int(args[1])
            if self._lit == index:  # the lit light dims at once, as the sketch's applyLight
                self._set_lit(index)
            return f"OK LEVEL {index} {int(args[1])}"
        return "ERR 1 unknown command"

    def _index(self, word):
        # At most 4 digits, as the sketch's parser reads.
        if word.isdigit() and len(word) <= 4 and int(word) < self.count:
            return int(word)
        return None


def _garble(data):
    """Corrupt a reply as line noise does: flipped bits, a stray byte, the line end kept."""
    noisy = bytes(b ^ 0x21 if i % 2 else b for i, b in enumerate(data))
    return b"\xfe" + noisy + b"\n"
