"""Light controllers: the protocol every controller follows, and the serial driver.

"psrig light protocol 1" (ASCII lines ending in ``\\n``, 115200 baud 8N1)::

    ID?               -> PSRIG-LIGHTS 1 <count>
    ON <i>            -> OK ON <i>         exactly light i lit, all others off
    OFF               -> OK OFF
    LEVEL <i> <0-255> -> OK LEVEL <i> <v>
    STATE?            -> STATE <i or ->
    anything wrong    -> ERR <code> <text>  1 unknown command, 2 bad index, 3 interlock

Light indices on the wire are 0-based, as in all of psrig's Python code: ``ON 0`` lights the
first light. The firmware switches everything off when no command arrives for 5 s.

The host side (:class:`SerialLightController`) opens the port exclusively, waits for the board's
reset (opening the port pulses DTR, which resets an Arduino), checks ``ID?``, retries a command
once when its reply times out or arrives corrupted, and never assumes a light is on without its
``OK``. Used as a context manager it switches every light off on the way out, even when the
block raised.

Other controllers plug in by subclassing :class:`LightController` and registering a
:class:`rig.drivers.LightDriver` under the ``driver`` name that rigs.yaml uses (built in, or a
``psrig.lights`` entry point); :func:`rig.drivers.make_light_controller` builds them.
"""

import abc
import operator
import re
import threading
import time

import serial

from pipeline.core.errors import PsrigError

__all__ = [
    "LightError", "LightConnectionError", "LightTimeout", "LightProtocolError",
    "LightCommandError", "LightIndexError", "LightInterlockError",
    "LightController", "SerialLightController", "SimLightController",
    "PROTOCOL_VERSION",
]

PROTOCOL_VERSION = 1
MAX_REPLY = 128  # bytes: protocol replies are under 90; a longer line is noise or a flood
# numbers are bounded as the sketch's are (at most 4 digits): int() never meets a huge one
_ID_REPLY = re.compile(r"PSRIG-LIGHTS (\d{1,4}) (\d{1,4})")
_ERR_REPLY = re.compile(r"ERR (\d{1,3})(?: (.*))?")
_TOO_LONG = object()  # what _exchange returns for a reply line over MAX_REPLY bytes


class LightError(PsrigError):
    """A light controller failed; the message names the port, the command and the light."""


class LightConnectionError(LightError):
    """The port cannot be opened, is in use, or the controller vanished."""


class LightTimeout(LightError):
    """No (complete) reply within the timeout, even after the retries."""


class LightProtocolError(LightError):
    """A reply that does not follow the protocol (wrong device, corrupted line)."""


class LightCommandError(LightError):
    """The controller answered ``ERR <code> <text>``; ``code`` holds the code (None if local)."""

    def __init__(self, message, code=None):
        super().__init__(message)
        self.code = code


class LightIndexError(LightCommandError):
    """A light index outside 0 .. count-1 (``ERR 2``)."""


class LightInterlockError(LightCommandError):
    """The controller's safety interlock refused to light (``ERR 3``)."""


class LightController(abc.ABC):
    """A device that lights one light at a time.

    Attributes
    ----------
    count : int or None
        Number of lights, indices 0 .. count-1 (known after :meth:`open`).
    """

    count = None
    is_open = True  # drivers with a connection report whether it is still up
    watchdog = None  # seconds of silence after which the controller darkens itself; None: never

    @property
    def keepalive_interval(self):
        """Real seconds between keep-alives that hold a light through a long exposure, or None
        when this controller has no watchdog (nothing to keep alive) or cannot be kept alive."""
        return None

    def keep_alive(self):
        """Reset the controller's watchdog; returns the light it reports lit (None: all off)."""
        raise LightError(f"{self}: this light controller cannot be kept alive")

    @abc.abstractmethod
    def open(self):
        """Connect and identify the controller; returns self."""

    @abc.abstractmethod
    def close(self):
        """Disconnect (does not switch anything; use the context manager for that)."""

    @abc.abstractmethod
    def on(self, index):
        """Light exactly light ``index`` (0-based), all others off; returns once confirmed."""

    @abc.abstractmethod
    def off(self):
        """Switch every light off; returns once confirmed."""

    @abc.abstractmethod
    def set_level(self, index, level):
        """Set light ``index``'s brightness, ``level`` an int 0-255."""

    @abc.abstractmethod
    def state(self):
        """The light the controller reports lit (int), or None when all are off."""

    #: Lights that may be on (set of indices): every light sent ``ON`` since the last ``OFF``
    #: the controller acknowledged; None when unknown (a controller that does not track it).
    maybe_lit = None

    def describe_maybe_lit(self):
        """'light 4' / 'lights 4 and 5' that may still be on, or 'the lights' when unknown;
        '' when the last OFF was acknowledged."""
        lit = self.maybe_lit
        if lit is None:
            return "the lights"
        lit = sorted(lit)
        if not lit:
            return ""
        if len(lit) == 1:
            return f"light {lit[0]}"
        return f"lights {', '.join(map(str, lit[:-1]))} and {lit[-1]}"

    def check_index(self, index):
        """Return ``index`` as an int, or raise :class:`LightIndexError` when out of range."""
        try:
            index = operator.index(index)
        except TypeError:
            raise LightIndexError(f"{self}: light {index!r}: not an integer index") from None
        if index < 0 or (self.count is not None and index >= self.count):
            upper = "" if self.count is None else f" (this controller has {self.count} lights, 0-{self.count - 1})"
            raise LightIndexError(f"{self}: light {index}: index out of range{upper}")
        return index

    def __enter__(self):
        self.open()
        return self

    def __exit__(self, exc_type, exc, tb):
        # Lights must never stay on: OFF even when the block failed. An OFF failure must not
        # hide the block's own exception, but it is reported when the block succeeded.
        try:
            if self.is_open:  # a vanished controller cannot be told; its watchdog darkens it
                self.off()
        except LightError as off_error:
            if exc is None:
                raise
            exc.add_note(f"also, switching the lights off failed: {off_error}")
        finally:
            self.close()
        return False


class SerialLightController(LightController):
    """A light controller speaking "psrig light protocol 1" over a serial port (pyserial).

    Parameters
    ----------
    port : str
        Serial device, e.g. ``/dev/ttyACM0`` or ``COM3``.
    baudrate : int
        Line speed (the protocol's is 115200).
    timeout : float
        Seconds to wait for each reply line.
    write_timeout : float
        Seconds a write may block before it counts as a timeout.
    reset_delay : float
        Seconds to wait after opening for the board to come out of its reset.
    retries : int
        Extra attempts after a timed-out or corrupted reply (never after a definite ``ERR``).
    expected_count : int, optional
        Refuse a controller whose ``ID?`` reports another light count.
    watchdog : float or None
        The firmware's command watchdog, seconds (the protocol's is 5 s): during exposures
        capture sends a keep-alive (``STATE?``) every :attr:`keepalive_interval` seconds.
    """

    KEEPALIVE_SHARE = 0.2  # keep-alives per watchdog period: 5, so one lost reply is harmless
    KEEPALIVE_MAX = 1.0    # seconds: "STATE? about every second" at the protocol's 5 s

    def __init__(self, port, *, baudrate=115200, timeout=1.0, write_timeout=1.0,
                 reset_delay=2.0, retries=1, expected_count=None, watchdog=5.0):
        self.port = str(port)
        self.baudrate = int(baudrate)
        self.timeout = float(timeout)
        self.write_timeout = float(write_timeout)
        self.reset_delay = float(reset_delay)
        self.retries = int(retries)
        self.expected_count = None if expected_count is None else int(expected_count)
        self.watchdog = None if not watchdog else float(watchdog)
        self.count = None
        self.lit = None  # the light last confirmed on by its OK, or None
        self.maybe_lit = set()
        self._serial = None
        # capture's keep-alive thread and the main thread share the line: one exchange at a time
        self._line_lock = threading.RLock()

    def __repr__(self):
        return f"{type(self).__name__}({self.port!r})"

    def __str__(self):
        return self.port

    @property
    def is_open(self):
        """True while the port is open."""
        return self._serial is not None

    # -- connection ---------------------------------------------------------------------------

    def open(self):
        """Open the port exclusively, wait for the board's reset, and check ``ID?``."""
        if self._serial is not None:
            return self
        try:
            self._serial = serial.Serial(
                self.port, self.baudrate, bytesize=serial.EIGHTBITS, parity=serial.PARITY_NONE,
                stopbits=serial.STOPBITS_ONE, timeout=self.timeout,
                write_timeout=self.write_timeout, exclusive=True)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise LightConnectionError(f"{self.port}: cannot open the light controller: {exc}") from None
        try:
            time.sleep(self.reset_delay)
            self._identify()
        except BaseException:
            self.close()
            raise
        return self

    def close(self):
        """Close the port (idempotent)."""
        port, self._serial = self._serial, None
        self.lit = None
        if port is not None:
            try:
                port.close()
            except (serial.SerialException, OSError):
                pass  # already gone: nothing left to release

    def _identify(self):
        match = self._transact("ID?", _ID_REPLY, expect_text="PSRIG-LIGHTS 1 <count>")
        version, count = int(match[1]), int(match[2])
        if version != PROTOCOL_VERSION:
            raise LightProtocolError(
                f"{self.port}: the controller speaks psrig light protocol {version}, "
                f"this driver speaks {PROTOCOL_VERSION}")
        if self.expected_count is not None and count != self.expected_count:
            raise LightProtocolError(
                f"{self.port}: the controller reports {count} lights, the rig expects "
                f"{self.expected_count}")
        self.count = count

    # -- commands -----------------------------------------------------------------------------

    def on(self, index):
        """Light exactly light ``index``; raises unless the controller confirms with ``OK ON i``."""
        index = self.check_index(index)
        self.lit = None
        was_lit = index in self.maybe_lit
        self.maybe_lit.add(index)   # a command whose reply was lost may have been carried out
        try:
            self._transact(f"ON {index}", re.compile(rf"OK ON {index}"), light=index)
        except LightError as exc:
            # every attempt answered ERR: not carried out (the lights stay as they were)
            if not was_lit and (isinstance(exc, LightCommandError) or getattr(exc, "refused", False)):
                self.maybe_lit.discard(index)
            self._off_best_effort()
            raise
        self.lit = index
        self.maybe_lit = {index}

    def off(self):
        """Switch every light off (``OFF`` -> ``OK OFF``)."""
        self._transact("OFF", re.compile("OK OFF"))
        self.lit = None
        self.maybe_lit = set()

    def set_level(self, index, level):
        """Set light ``index``'s brightness to ``level`` (int 0-255)."""
        index = self.check_index(index)
        try:
            level = operator.index(level)
        except TypeError:
            level = None
        if level is None or not 0 <= level <= 255:
            raise LightCommandError(f"{self.port}: light {index}: level must be an integer 0-255")
        self._transact(f"LEVEL {index} {level}", re.compile(rf"OK LEVEL {index} {level}"),
                       light=index)

    def state(self):
        """The light the controller reports lit (``STATE?``), or None when all are off."""
        match = self._transact("STATE?", re.compile(r"STATE (\d{1,4}|-)"))
        return None if match[1] == "-" else int(match[1])

    @property
    def keepalive_interval(self):
        """Real seconds between keep-alives: a fifth of the watchdog, at most 1 s."""
        if self.watchdog is None:
            return None
        return min(self.KEEPALIVE_MAX, self.KEEPALIVE_SHARE * self.watchdog)

    def keep_alive(self):
        """``STATE?``: any line resets the firmware's watchdog; returns the light it reports."""
        return self.state()

    def identify(self):
        """Ask ``ID?`` again; returns (protocol version, light count)."""
        match = self._transact("ID?", _ID_REPLY, expect_text="PSRIG-LIGHTS 1 <count>")
        return int(match[1]), int(match[2])

    def _off_best_effort(self):
        # After a failed ON the light's state is unknown: try once to make sure it is dark.
        if self._serial is None:
            return
        try:
            self._transact("OFF", re.compile("OK OFF"), retries=0)
        except LightError:
            return
        self.maybe_lit = set()

    # -- the exchange -------------------------------------------------------------------------

    def _transact(self, command, pattern, *, light=None, retries=None, expect_text=None):
        """Send ``command``, return the reply's match of ``pattern``; retry on timeout/noise."""
        what = f"{self.port}: " + (f"light {light}: " if light is not None else "") + f"command {command!r}"
        if self._serial is None:
            raise LightConnectionError(f"{what}: the light controller is not open")
        attempts = 1 + (self.retries if retries is None else retries)
        problems, refused = [], 0   # refused: attempts answered ERR (a command not carried out)
        for _ in range(attempts):
            with self._line_lock:
                line = self._exchange(command, what)
            if line is None:
                problems.append(f"no reply within {self.timeout:g} s")
                continue
            if line is _TOO_LONG:
                problems.append(f"a reply of more than {MAX_REPLY} bytes without a line end "
                                "(a flood of noise, or a device that does not speak psrig light "
                                "protocol 1)")
                continue
            match = pattern.fullmatch(line)
            if match:
                return match
            problems.append(self._judge_reply(line, what, light, expect_text or pattern.pattern))
            refused += _ERR_REPLY.fullmatch(line) is not None
        kind = LightTimeout if all(p.startswith("no reply") for p in problems) else LightProtocolError
        error = kind(f"{what}: {'; then '.join(problems)} ({attempts} attempt{'s' * (attempts > 1)})")
        error.refused = refused == attempts
        raise error

    def _exchange(self, command, what):
        """One write + read; returns the reply line, or None on a (write or read) timeout."""
        try:
            self._serial.reset_input_buffer()  # a late reply to an earlier attempt is stale
            self._serial.write(command.encode("ascii") + b"\n")
            # read_until bounds both the length and the total time (pyserial's readline would
            # wait for a line end forever while bytes keep coming, its timeout being per read)
            raw = self._serial.read_until(b"\n", MAX_REPLY + 1)
            if len(raw) > MAX_REPLY and not raw.endswith(b"\n"):
                self._discard_line()
        except serial.SerialTimeoutException:
            return None
        except (serial.SerialException, OSError) as exc:
            self.close()
            raise LightConnectionError(f"{what}: the light controller disconnected ({exc})") from None
        if not raw.endswith(b"\n"):
            return _TOO_LONG if len(raw) > MAX_REPLY else None
        return raw.decode("ascii", errors="replace").strip()

    def _discard_line(self):
        """Read and drop the rest of an over-long reply, up to its line end or the timeout: a
        device still sending it would otherwise answer the next command with its tail."""
        deadline = time.monotonic() + (self.timeout or 0)
        while time.monotonic() < deadline:
            chunk = self._serial.read_until(b"\n", 1 << 16)
            if not chunk or chunk.endswith(b"\n"):   # the line's end, or the device fell quiet
                return

    def _judge_reply(self, line, what, light, expected):
        """Raise for a definite ``ERR``; describe a retryable bad reply."""
        err = _ERR_REPLY.fullmatch(line)
        if err is None:
            return f"unexpected reply {line!r} (expected {expected!r})"
        code = int(err[1])
        if code == 2:
            raise LightIndexError(f"{what}: the controller rejected light {light}: {line!r}", code)
        if code == 3:
            raise LightInterlockError(
                f"{what}: refused by the safety interlock (is the enclosure closed?): {line!r}", code)
        # ERR 1 for a command this driver spelled correctly means it was corrupted on the way.
        return f"the controller replied {line!r}"


class SimLightController(SerialLightController):
    """The serial driver connected to a :class:`rig.sim.firmware.SimulatedLightFirmware`.

    The firmware (started on :meth:`open` unless one is passed in already running) is reachable
    as :attr:`firmware`, so a simulated camera can read which light is lit.

    Parameters
    ----------
    count : int
        Number of simulated lights.
    firmware : SimulatedLightFirmware, optional
        Use this firmware instead of making one; it is started here if needed and stopped on
        :meth:`close` only if this controller started it.
    watchdog, boot_delay : float
        Passed to a firmware made here (simulated seconds).
    **options
        :class:`SerialLightController` options (timeout, retries, reset_delay ...).

    Attributes
    ----------
    time_scale : float
        Simulated seconds per real second of the firmware's clock: the keep-alive interval and
        the wait for the board's boot are divided by it.
    """

    def __init__(self, count=32, *, firmware=None, watchdog=5.0, boot_delay=0.0, **options):
        from rig.sim.firmware import SimulatedLightFirmware  # the sim stays out of real rigs' imports

        self.firmware = firmware or SimulatedLightFirmware(count, watchdog=watchdog,
                                                           boot_delay=boot_delay)
        self.time_scale = self.firmware.clock.scale
        options.setdefault("reset_delay", self.firmware.boot_delay / self.time_scale)
        options.setdefault("expected_count", count)
        options["watchdog"] = self.firmware.watchdog
        self._owns_firmware = False
        super().__init__(self.firmware.port or "(simulated, not started)", **options)

    @property
    def keepalive_interval(self):
        """The serial driver's interval in the firmware's time, converted to real seconds."""
        interval = super().keepalive_interval
        return None if interval is None else interval / self.time_scale

    def open(self):
        """Start the firmware if needed, then open its pty like a serial port."""
        if self.firmware.port is None or not self.firmware.connected:
            self.port = self.firmware.start()
            self._owns_firmware = True
        self.port = self.firmware.port
        return super().open()

    def close(self):
        """Close the port, and stop the firmware if this controller started it."""
        super().close()
        if self._owns_firmware:
            self.firmware.stop()
            self._owns_firmware = False
