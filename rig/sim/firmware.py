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
    the board vanishes (USB cable pulled): the pty is hung up and every light goes dark;
``flood``
    the command is carried out, then instead of its reply the board sends bytes without a line
    end, 512 at a time, until the next command arrives (a crashed board or a wrong baud rate);
``huge_number``
    the command is carried out and its reply carries a 4,300-digit number.

The line handling (:meth:`SimulatedLightFirmware.feed`) follows the sketch byte for byte; a test
runs one command table through both (tests/rig/test_firmware_parity.py).
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
FAULT_KINDS = ("drop_reply", "garble", "err", "interlock", "disconnect", "flood", "huge_number")
MAX_LINE = 64  # the sketch's line buffer; longer lines are rejected, not overflowed
HUGE_DIGITS = 4300  # Python's int() refuses longer decimal strings (3.11+)
HUGE_NUMBER_REPLY = {b"PSRIG-LIGHTS": b"PSRIG-LIGHTS 1 ", b"OK": b"OK ON ", b"STATE": b"STATE "}
FLOOD_CHUNK = b"7" * 512  # bytes per firmware poll of a newline-less flood
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
        self._line, self._overflow, self._flooding = bytearray(), False, False
        self._last_command = self.clock.now()  # as the sketch's setup(): the watchdog starts now
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
        while not self._stop.is_set() and self._master is not None:
            master = self._master
            try:
                ready, _, _ = select.select([master], [], [], _POLL)
                data = os.read(master, 1024) if ready else b""
            except (OSError, ValueError):
                data = b""  # no slave open right now: nothing to read
                time.sleep(_POLL)
            self.poll()
            if data and self.clock.now() >= self._boot_until:
                self._flooding = False  # a new command ends a flood, as a reset board would
                self._send_bytes(self.feed(data))
            if self._flooding:
                self._send_bytes(FLOOD_CHUNK, wait=False)

    def feed(self, data):
        """Take bytes arriving on the serial line, exactly as the sketch's ``readSerial()``
        does; returns the bytes the board sends back.

        ``\r`` is ignored; ``\n`` ends a line; a line ends at its first NUL (a C string); an
        empty line is ignored (it does not count for the watchdog); the 65th character of a
        line answers ``ERR 1 line too long`` and the rest of that line is dropped unanswered.
        """
        out = []
        for byte in bytes(data):
            if self._master is None and self._port is not None:
                break  # hung up (disconnect fault): the rest is lost
            if byte == 0x0D:
                continue
            if byte == 0x0A:
                line, skip = bytes(self._line).split(b"\0", 1)[0], self._overflow
                self._line.clear()
                self._overflow = False
                if not skip and line:
                    out.append(self._receive(line))
            elif self._overflow:
                pass  # the rest of an over-long line
            elif len(self._line) < MAX_LINE:
                self._line.append(byte)
            else:
                out.append(b"ERR 1 line too long\n")
                self._overflow = True
                self._line.clear()
        return b"".join(out)

    def poll(self):
        """What the sketch's ``loop()`` does between reads: the watchdog check. The firmware
        thread calls it every 10 ms; a test driving :meth:`feed` by hand calls it itself."""
        with self._lock:
            self._check_watchdog()

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

    def _receive(self, line):
        """One command line (bytes, no line end): carry it out; the bytes to send back."""
        self.history.append(line.decode("latin-1").strip(" \t"))
        with self._lock:
            self._check_watchdog()  # a trip due before this command happened before it
            self._last_command = self.clock.now()
        if self._take_fault("disconnect"):
            self._hang_up()
            return b""
        if self._take_fault("err"):
            return b"ERR 1 unknown command\n"
        with self._lock:
            reply = self._execute(line)
        if reply is None:
            return b""  # blanks and tabs only: the sketch's strtok finds no command
        return self._faulty_reply(reply)

    def _faulty_reply(self, reply):
        """The reply line as sent, after any reply fault armed for it."""
        if self._take_fault("drop_reply"):
            return b""
        if self._take_fault("garble"):
            return _garble(reply)
        if self._take_fault("huge_number"):
            return HUGE_NUMBER_REPLY.get(reply.split(b" ", 1)[0], b"STATE ") + b"9" * HUGE_DIGITS + b"\n"
        if self._take_fault("flood"):
            self._flooding = True
            return FLOOD_CHUNK
        return reply + b"\n"

    def _send_bytes(self, data, wait=True):
        if not data:
            return
        try:
            if wait:
                os.write(self._master, data)
            else:  # a flood must not block the firmware when the host stops reading
                ready = select.select([], [self._master], [], 0)[1]
                if ready:
                    os.write(self._master, data)
        except (OSError, TypeError, ValueError):
            pass  # hung up meanwhile: the reply is lost, as on a pulled cable

    # -- the protocol -------------------------------------------------------------------------

    def _execute(self, line):
        """The sketch's ``execute()``: words split at blanks and tabs (strtok), at most four
        read; the reply line (bytes, no line end) or None."""
        words = [w for w in line.replace(b"\t", b" ").split(b" ") if w][:4] + [None] * 4
        name, arg1, arg2, extra = words[:4]
        if name is None:
            return None
        if name == b"ID?" and arg1 is None:
            return self.ident.encode("latin-1")
        if name == b"STATE?" and arg1 is None:
            return b"STATE " + (b"-" if self._lit is None else str(self._lit).encode())
        if name == b"OFF" and arg1 is None:
            self._set_lit(None)
            return b"OK OFF"
        if name == b"ON" and arg1 is not None and arg2 is None:
            return self._on(arg1)
        if name == b"LEVEL" and arg2 is not None and extra is None:
            return self._level(arg1, arg2)
        return b"ERR 1 unknown command"

    def _on(self, word):
        index = self._index(word)
        if index is None:
            return b"ERR 2 bad index " + word
        if self._take_fault("interlock"):
            self._set_lit(None)
            return b"ERR 3 interlock open"
        self._set_lit(index)
        return b"OK ON " + str(index).encode()

    def _level(self, word, value):
        index = self._index(word)
        if index is None:
            return b"ERR 2 bad index " + word
        if len(value) > 3 or not _digits(value) or int(value) > 255:
            return b"ERR 1 bad level " + value
        self._levels[index] = int(value)
        if self._lit == index:  # the lit light dims at once, as the sketch's applyLight
            self._set_lit(index)
        return b"OK LEVEL " + f"{index} {int(value)}".encode()

    def _index(self, word):
        # the sketch's parseIndex: 1 to 4 decimal digits, below the light count
        if len(word) <= 4 and _digits(word) and int(word) < self.count:
            return int(word)
        return None


def _digits(word):
    """True when ``word`` (bytes) is one or more ASCII digits (str.isdigit takes more)."""
    return bool(word) and all(0x30 <= b <= 0x39 for b in word)


def _garble(data):
    """Corrupt a reply as line noise does: flipped bits, a stray byte, the line end kept."""
    noisy = bytes(b ^ 0x21 if i % 2 else b for i, b in enumerate(data))
    return b"\xfe" + noisy + b"\n"
