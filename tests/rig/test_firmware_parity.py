"""The Arduino sketch and the simulated firmware answer one command table identically.

The sketch (rig/firmware/psrig_lights/psrig_lights.ino, unmodified) is compiled for this machine
against a stub of the Arduino API (tests/rig/arduino_stub/) and a harness that feeds it records
(raw bytes, clock moves, a look at which light is lit). The simulated firmware gets the same
records through :meth:`SimulatedLightFirmware.feed` with a hand-moved clock, and the byte
records also through its pseudo-terminal. Skipped when no C++ compiler is found.
"""

import shutil
import subprocess
import time
from pathlib import Path

import pytest
import serial

from rig.sim.firmware import SimulatedLightFirmware

HERE = Path(__file__).resolve().parent
SKETCH = HERE.parents[1] / "rig" / "firmware" / "psrig_lights" / "psrig_lights.ino"
STUB = HERE / "arduino_stub"


class HandClock:
    """A clock that moves only when told (simulated seconds)."""

    scale = 1.0

    def __init__(self):
        self.t = 0.0

    def now(self):
        return self.t


def S(data):
    """A record of raw bytes arriving on the serial line."""
    return ("S", data.encode("latin-1") if isinstance(data, str) else data)


def T(ms):
    """A record moving the clock to ``ms`` milliseconds."""
    return ("T", ms)


LIT = ("L", None)

TABLE = [
    S("ID?\n"), S("STATE?\n"), S("ON 0\n"), S("ON 31\n"), S("STATE?\n"), S("ON 03\n"),
    S("LEVEL 3 100\n"), S("LEVEL 3 256\n"), S("LEVEL 3 0100\n"), S("LEVEL 31 0\n"),
    S("LEVEL 32 1\n"), S("LEVEL 3\n"), S("LEVEL 1 2 3\n"), S("ON 32\n"), S("ON 00001\n"),
    S("ON -1\n"), S("ON x\n"), S("ON\n"), S("ON 1 2\n"), S("on 1\n"), S("FLASH\n"),
    S("ID? now\n"), S("OFF\n"), S("STATE?\n"), S("OFF 1\n"),
    # over-long lines: the 65th character answers at once, the rest of the line is dropped
    S("ON 1" + " " * 70 + "\n"), S("X" * 65 + "\n"), S("X" * 64 + "\n"), S("ON 2" + " " * 60 + "\n"),
    S("Z" * 40), S("Z" * 40 + "\n"), S("Y" * 100), S("ID?\n"), S("STATE?\n"),
    # line ends, blanks, tabs, NULs and bytes above 127
    S("ON 2\r\n"), S("O\rN 3\n"), S("\n\n"), S(" \t \n"), S("ON\t5\n"), S("LEVEL  5   200\n"),
    S("ON 6\x00junk\n"), S("\x00ON 7\n"), S("ON \xe9\n"), S("ON \xc2\xb2\n"), S("LEVEL 5 2\xb2\n"),
    S("STATE?\nON 4\nSTATE?\n"), LIT,
    # the 5 s watchdog: strictly more than 5000 ms after the last command
    T(1000), S("ON 4\n"), T(6000), LIT, T(6001), LIT,
    # STATE? keeps a light on for as long as it keeps coming
    T(7000), S("ON 4\n"), T(11000), S("STATE?\n"), T(15000), S("STATE?\n"), T(19000), LIT,
    T(20001), LIT,
    # a line of blanks counts as a command; an over-long line does not
    T(21000), S("ON 6\n"), T(25000), S(" \t\n"), T(29500), LIT, S("X" * 70 + "\n"),
    T(30001), LIT, S("STATE?\n"),
]


@pytest.fixture(scope="module")
def sketch_binary(tmp_path_factory):
    """The sketch built with the stub core and the harness (skipped without a C++ compiler)."""
    compiler = shutil.which("g++") or shutil.which("clang++") or shutil.which("c++")
    if compiler is None:
        pytest.skip("no C++ compiler (g++, clang++) to build the Arduino sketch with")
    folder = tmp_path_factory.mktemp("sketch")
    shutil.copy(SKETCH, folder / "sketch.inc")
    binary = folder / "psrig_lights"
    build = subprocess.run([compiler, "-std=c++11", "-Wall", "-I", str(STUB), "-I", str(folder),
                            "-o", str(binary), str(STUB / "harness.cpp")],
                           capture_output=True, text=True, timeout=120)
    assert build.returncode == 0, build.stderr
    return binary


def run_sketch(binary, table):
    """Replies of the compiled sketch, one string per record."""
    lines = []
    for kind, value in table:
        lines.append({"S": lambda v: "S " + v.hex(), "T": lambda v: f"T {v}",
                      "L": lambda v: "L"}[kind](value))
    out = subprocess.run([str(binary)], input=("\n".join(lines) + "\n").encode(), capture_output=True,
                         timeout=30, check=True).stdout.decode("latin-1")
    replies = out.split("#END\n")
    assert replies[-1] == ""
    return replies[:-1]


def run_simulator(table):
    """Replies of the simulated firmware (fed by hand, clock moved by hand), per record."""
    clock = HandClock()
    firmware = SimulatedLightFirmware(32, watchdog=5.0, clock=clock)
    replies = []
    for kind, value in table:
        if kind == "S":
            reply = firmware.feed(value).decode("latin-1")
        elif kind == "T":
            clock.t = value / 1000.0
            reply = ""
        else:
            reply = f"#LIT {-1 if firmware.lit is None else firmware.lit}\n"
        firmware.poll()  # the sketch's loop() checks its watchdog after each read
        replies.append(reply)
    return replies


def test_table_is_large_enough():
    assert sum(kind == "S" for kind, _ in TABLE) >= 30


def test_sketch_and_simulator_answer_alike(sketch_binary):
    sketch, simulated = run_sketch(sketch_binary, TABLE), run_simulator(TABLE)
    for record, want, got in zip(TABLE, sketch, simulated):
        assert got == want, f"record {record!r}: sketch {want!r}, simulator {got!r}"
    assert len(sketch) == len(simulated) == len(TABLE)
    assert "ERR 1 line too long\n" in sketch[TABLE.index(S("ON 1" + " " * 70 + "\n"))]


def test_the_simulator_behind_its_pty_answers_as_the_sketch(sketch_binary):
    """The byte records through the firmware thread and a real serial port (clock records
    left out: they need the hand clock)."""
    records = [r for r in TABLE if r[0] == "S"]
    want = "".join(run_sketch(sketch_binary, records)).encode("latin-1")
    got = b""
    with SimulatedLightFirmware(32, watchdog=5.0) as firmware:
        with serial.Serial(firmware.port, 115200, timeout=0.05) as port:
            for _, data in records:
                port.write(data)
                time.sleep(0.002)  # the sketch's harness also reads record by record
            deadline = time.monotonic() + 5.0
            while len(got) < len(want) and time.monotonic() < deadline:
                got += port.read(4096)
            got += port.read(4096)  # and nothing more
    assert got == want


def test_simulator_replies_without_a_compiler():
    """The cases the sketch and the simulator used to disagree on, checked on the simulator
    alone so they hold where no compiler is installed."""
    firmware = SimulatedLightFirmware(32, watchdog=5.0, clock=HandClock())
    assert firmware.feed(b"ON 1" + b" " * 70 + b"\n") == b"ERR 1 line too long\n"
    assert firmware.lit is None
    assert firmware.feed(b"X" * 65 + b"\n") == b"ERR 1 line too long\n"
    assert firmware.feed(b"X" * 64 + b"\n") == b"ERR 1 unknown command\n"
    assert firmware.feed(b"ON \xc2\xb2\n") == b"ERR 2 bad index \xc2\xb2\n"
