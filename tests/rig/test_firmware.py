"""The simulated light firmware itself, spoken to with raw protocol lines over its pty."""

import time

import pytest
import serial

from rig.sim.firmware import FAULT_KINDS, SimulatedLightFirmware


@pytest.fixture
def lights_wire(lights_firmware):
    """A raw pyserial port on the firmware's pty: ``ask(line) -> reply``."""
    with serial.Serial(lights_firmware.port, 115200, timeout=0.5) as port:
        def ask(line, ending=b"\n"):
            port.write(line.encode("ascii") + ending)
            return port.readline().decode("ascii", errors="replace")
        ask.port = port
        yield ask


def test_protocol_replies(lights_firmware, lights_wire):
    assert lights_wire("ID?") == "PSRIG-LIGHTS 1 8\n"
    assert lights_wire("STATE?") == "STATE -\n"
    assert lights_wire("ON 0") == "OK ON 0\n"
    assert lights_firmware.lit == 0
    assert lights_wire("ON 7") == "OK ON 7\n"
    assert lights_firmware.lit == 7  # exactly one lit
    assert lights_wire("STATE?") == "STATE 7\n"
    assert lights_wire("LEVEL 7 0") == "OK LEVEL 7 0\n"
    assert lights_firmware.levels[7] == 0
    assert lights_wire("OFF") == "OK OFF\n"
    assert lights_firmware.lit is None
    assert lights_firmware.history == ["ID?", "STATE?", "ON 0", "ON 7", "STATE?", "LEVEL 7 0", "OFF"]


@pytest.mark.parametrize("line, reply", [
    ("ON 8", "ERR 2 bad index 8"),
    ("ON -1", "ERR 2 bad index -1"),
    ("ON x", "ERR 2 bad index x"),
    ("LEVEL 9 10", "ERR 2 bad index 9"),
    ("LEVEL 1 256", "ERR 1 bad level 256"),
    ("LEVEL 1", "ERR 1 unknown command"),
    ("on 1", "ERR 1 unknown command"),
    ("FLASH", "ERR 1 unknown command"),
    ("OFF 3", "ERR 1 unknown command"),
])
def test_errors(lights_firmware, lights_wire, line, reply):
    lights_wire("ON 1")
    assert lights_wire(line) == reply + "\n"
    assert lights_firmware.lit == 1  # a refused command changes nothing


def test_crlf_and_blank_lines(lights_firmware, lights_wire):
    assert lights_wire("ON 2", ending=b"\r\n") == "OK ON 2\n"
    lights_wire.port.write(b"\n\n")
    assert lights_wire("STATE?") == "STATE 2\n"
    assert lights_firmware.history == ["ON 2", "STATE?"]


def test_overlong_line_rejected(lights_firmware, lights_wire):
    lights_wire.port.write(b"X" * 100)
    assert lights_wire.port.readline() == b"ERR 1 line too long\n"
    lights_wire.port.write(b"Y" * 100 + b"\n")  # the rest of the line is skipped, unanswered
    assert lights_wire("ID?").startswith("PSRIG-LIGHTS")
    assert "X" not in "".join(lights_firmware.history)


def test_faults_one_by_one(lights_firmware, lights_wire):
    lights_firmware.inject("drop_reply")
    assert lights_wire("ON 3") == ""  # timed out
    assert lights_firmware.lit == 3  # carried out all the same
    lights_firmware.inject("garble")
    reply = lights_wire("ON 4")
    assert reply.endswith("\n") and reply != "OK ON 4\n"
    assert lights_firmware.lit == 4
    lights_firmware.inject("err")
    assert lights_wire("ON 5") == "ERR 1 unknown command\n"
    assert lights_firmware.lit == 4  # not carried out
    lights_firmware.inject("interlock")
    assert lights_wire("ON 5") == "ERR 3 interlock open\n"
    assert lights_firmware.lit is None
    assert lights_wire("ON 5") == "OK ON 5\n"
    assert lights_firmware.pending_faults() == {}


def test_fault_counts_and_constructor_faults():
    with SimulatedLightFirmware(2, faults={"drop_reply": 2}) as firmware:
        with serial.Serial(firmware.port, timeout=0.2) as port:
            for expected in (b"", b"", b"OK OFF\n"):
                port.write(b"OFF\n")
                assert port.readline() == expected
    with pytest.raises(ValueError, match="unknown fault 'smoke'"):
        SimulatedLightFirmware(2).inject("smoke")
    assert set(FAULT_KINDS) == {"drop_reply", "garble", "err", "interlock", "disconnect",
                                "flood", "huge_number"}


def test_disconnect_hangs_up(lights_firmware, lights_wire):
    lights_wire("ON 1")
    lights_firmware.inject("disconnect")
    lights_wire.port.write(b"STATE?\n")
    with pytest.raises(serial.SerialException):
        lights_wire.port.readline()
    assert lights_firmware.lit is None and not lights_firmware.connected


def test_watchdog_counts_any_command():
    with SimulatedLightFirmware(3, watchdog=0.5) as firmware:
        with serial.Serial(firmware.port, timeout=0.5) as port:
            port.write(b"ON 2\n")
            port.readline()
            for _ in range(4):  # keep-alive: a STATE? every 0.2 s, 0.8 s in all
                time.sleep(0.2)
                port.write(b"STATE?\n")
                assert port.readline() == b"STATE 2\n"
            time.sleep(0.8)
            assert firmware.lit is None and firmware.watchdog_trips == 1
            port.write(b"STATE?\n")
            assert port.readline() == b"STATE -\n"


def test_boot_delay_swallows_input():
    with SimulatedLightFirmware(3, boot_delay=0.3) as firmware:
        with serial.Serial(firmware.port, timeout=0.1) as port:
            port.write(b"ID?\n")
            assert port.readline() == b""
            time.sleep(0.3)
            port.write(b"ID?\n")
            assert port.readline() == b"PSRIG-LIGHTS 1 3\n"


def test_stop_is_idempotent_and_darkens():
    firmware = SimulatedLightFirmware(3)
    assert firmware.port is None and not firmware.connected
    port_name = firmware.start()
    assert port_name.startswith("/dev/") and firmware.start() == port_name
    with serial.Serial(port_name, timeout=0.5) as port:
        port.write(b"ON 1\n")
        assert port.readline() == b"OK ON 1\n"
    assert firmware.lit == 1
    firmware.stop()
    firmware.stop()
    assert firmware.lit is None and not firmware.connected


def test_bad_count():
    with pytest.raises(ValueError, match="count"):
        SimulatedLightFirmware(0)
