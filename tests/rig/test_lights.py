"""The real SerialLightController against the simulated firmware over a pty, every fault."""

import time

import pytest

from rig.lights import (
    LightCommandError, LightConnectionError, LightController, LightError,
    LightIndexError, LightInterlockError, LightProtocolError, LightTimeout,
    SerialLightController, SimLightController)
from rig.drivers import LIGHT_DRIVERS, make_light_controller
from rig.sim.firmware import SimulatedLightFirmware

LIGHTS_TIMEOUT = 0.4  # as in conftest.py (not imported: other folders have a conftest too)


def _controller(firmware, **options):
    options = {"timeout": LIGHTS_TIMEOUT, "write_timeout": LIGHTS_TIMEOUT,
               "reset_delay": 0.02, **options}
    return SerialLightController(firmware.port, **options)


def test_open_checks_id_and_reads_count(lights_firmware, lights_controller):
    assert lights_controller.count == lights_firmware.count == 8
    assert lights_firmware.history[0] == "ID?"
    assert lights_controller.identify() == (1, 8)


def test_on_lights_exactly_one_and_state_agrees(lights_firmware, lights_controller):
    for index in (0, 7, 3):
        lights_controller.on(index)
        assert lights_firmware.lit == index
        assert lights_controller.state() == index
        assert lights_controller.lit == index
    lights_controller.off()
    assert lights_firmware.lit is None
    assert lights_controller.state() is None
    assert lights_controller.lit is None


def test_set_level_reaches_the_firmware(lights_firmware, lights_controller):
    lights_controller.set_level(5, 17)
    expected = [255] * 8
    expected[5] = 17
    assert lights_firmware.levels == expected
    with pytest.raises(LightCommandError, match="light 5: level"):
        lights_controller.set_level(5, 256)


def test_numpy_index_accepted_and_host_rejects_out_of_range(lights_firmware, lights_controller):
    np = pytest.importorskip("numpy")
    lights_controller.on(np.int64(2))
    assert lights_firmware.lit == 2
    sent = len(lights_firmware.history)
    with pytest.raises(LightIndexError, match="light 8: index out of range"):
        lights_controller.on(8)
    with pytest.raises(LightIndexError, match="light -1"):
        lights_controller.on(-1)
    assert len(lights_firmware.history) == sent  # refused before reaching the wire


def test_dropped_reply_is_retried(lights_firmware, lights_controller):
    lights_firmware.inject("drop_reply")
    lights_controller.on(4)
    assert lights_firmware.lit == 4
    assert lights_firmware.history[-2:] == ["ON 4", "ON 4"]
    assert lights_controller.lit == 4


def test_two_dropped_replies_time_out_naming_light_and_command(lights_firmware, lights_controller):
    lights_firmware.inject("drop_reply", 2)
    with pytest.raises(LightTimeout) as info:
        lights_controller.on(6)
    message = str(info.value)
    assert lights_firmware.port in message and "light 6" in message and "'ON 6'" in message
    assert "2 attempts" in message
    # Never assumed lit without its OK, and switched off for safety.
    assert lights_controller.lit is None
    assert lights_firmware.lit is None
    assert lights_firmware.history[-1] == "OFF"


def test_garbled_reply_is_retried(lights_firmware, lights_controller):
    lights_firmware.inject("garble")
    lights_controller.on(1)
    assert lights_firmware.lit == 1 and lights_controller.lit == 1


def test_twice_garbled_reply_is_a_protocol_error(lights_firmware, lights_controller):
    lights_firmware.inject("garble", 2)
    with pytest.raises(LightProtocolError, match=r"light 2: command 'ON 2': unexpected reply"):
        lights_controller.on(2)
    assert lights_firmware.lit is None


def test_err_1_is_retried_then_reported(lights_firmware, lights_controller):
    lights_firmware.inject("err")
    lights_controller.set_level(3, 40)
    assert lights_firmware.levels[3] == 40
    lights_firmware.inject("err", 2)
    with pytest.raises(LightProtocolError, match=r"'LEVEL 3 41'.*ERR 1"):
        lights_controller.set_level(3, 41)
    assert lights_firmware.levels[3] == 40


def test_err_2_from_firmware_names_the_light(lights_firmware):
    # The host believes in 16 lights (no local range check can catch it): the board says no.
    with _controller(lights_firmware) as controller:
        controller.count = 16
        with pytest.raises(LightIndexError) as info:
            controller.on(12)
    assert info.value.code == 2
    assert "light 12" in str(info.value) and "ERR 2" in str(info.value)
    assert lights_firmware.history.count("ON 12") == 1  # a definite ERR is not retried


def test_err_3_interlock(lights_firmware, lights_controller):
    lights_controller.on(0)
    lights_firmware.inject("interlock")
    with pytest.raises(LightInterlockError, match="light 5.*interlock") as info:
        lights_controller.on(5)
    assert info.value.code == 3
    assert lights_firmware.lit is None and lights_controller.lit is None
    lights_controller.on(5)  # interlock closed again
    assert lights_firmware.lit == 5


def test_disconnect_is_a_clear_error(lights_firmware):
    controller = _controller(lights_firmware)
    with pytest.raises(LightConnectionError, match=r"light 3: command 'ON 3': .*disconnected"):
        with controller:
            controller.on(1)
            lights_firmware.inject("disconnect")
            controller.on(3)
    assert not controller.is_open
    assert lights_firmware.lit is None
    with pytest.raises(LightConnectionError, match="not open"):
        controller.on(1)


def test_off_on_exception_inside_with(lights_firmware):
    with pytest.raises(RuntimeError, match="camera exploded"):
        with _controller(lights_firmware) as controller:
            controller.on(2)
            assert lights_firmware.lit == 2
            raise RuntimeError("camera exploded")
    assert lights_firmware.lit is None
    assert lights_firmware.history[-1] == "OFF"
    assert not controller.is_open


def test_failed_off_at_exit_is_noted_not_hiding_the_error(lights_firmware):
    with pytest.raises(RuntimeError) as info:
        with _controller(lights_firmware) as controller:
            controller.on(2)
            lights_firmware.inject("drop_reply", 2)
            raise RuntimeError("first problem")
    assert "switching the lights off failed" in " ".join(info.value.__notes__)


def test_failed_off_at_clean_exit_raises(lights_firmware):
    with pytest.raises(LightTimeout, match="'OFF'"):
        with _controller(lights_firmware) as controller:
            controller.on(2)
            lights_firmware.inject("drop_reply", 2)
    assert not controller.is_open


def test_watchdog_switches_off():
    with SimulatedLightFirmware(4, watchdog=0.5) as firmware:
        with _controller(firmware) as controller:
            controller.on(1)
            time.sleep(0.1)
            assert firmware.lit == 1  # not yet
            time.sleep(0.8)
            assert firmware.lit is None
            assert controller.state() is None
            assert firmware.watchdog_trips == 1


def test_wrong_id_names_the_port():
    with SimulatedLightFirmware(4, ident="ACME-DIMMER v2.1") as firmware:
        with pytest.raises(LightProtocolError) as info:
            _controller(firmware).open()
    assert firmware.port in str(info.value) and "ACME-DIMMER" in str(info.value)


def test_other_protocol_version_and_count_refused():
    with SimulatedLightFirmware(4, ident="PSRIG-LIGHTS 2 4") as firmware:
        with pytest.raises(LightProtocolError, match="protocol 2"):
            _controller(firmware).open()
    with SimulatedLightFirmware(4) as firmware:
        with pytest.raises(LightProtocolError, match="reports 4 lights, the rig expects 32"):
            _controller(firmware, expected_count=32).open()


def test_boot_delay_needs_reset_delay():
    # Input during the boot is swallowed, as by an Arduino bootloader.
    with SimulatedLightFirmware(4, boot_delay=0.5) as firmware:
        with pytest.raises(LightTimeout, match="'ID\\?'"):
            _controller(firmware, timeout=0.1, reset_delay=0.0).open()
    with SimulatedLightFirmware(4, boot_delay=0.2) as firmware:
        with _controller(firmware, reset_delay=0.25) as controller:
            assert controller.count == 4
            assert firmware.history == ["ID?"]


def test_port_is_opened_exclusively(lights_firmware, lights_controller):
    with pytest.raises(LightConnectionError, match=lights_firmware.port):
        _controller(lights_firmware).open()


def test_missing_port_is_a_clear_error(tmp_path):
    with pytest.raises(LightConnectionError, match="no-such-tty"):
        SerialLightController(str(tmp_path / "no-such-tty"), reset_delay=0).open()


def test_make_light_controller_serial_and_sim(lights_firmware):
    controller = make_light_controller({"driver": "serial", "port": lights_firmware.port,
                                        "count": 8, "timeout": LIGHTS_TIMEOUT, "reset_delay": 0.0})
    assert isinstance(controller, SerialLightController) and isinstance(controller, LightController)
    with controller:
        controller.on(7)
        assert lights_firmware.lit == 7
    assert lights_firmware.lit is None

    sim = make_light_controller({"driver": "sim", "count": 5, "timeout": LIGHTS_TIMEOUT})
    assert isinstance(sim, SimLightController)
    with sim:
        assert sim.count == 5
        sim.on(4)
        assert sim.firmware.lit == 4
    assert sim.firmware.lit is None and not sim.firmware.connected


def test_make_light_controller_errors():
    with pytest.raises(LightError, match="lights.driver: unknown light driver 'dmx'"):
        make_light_controller({"driver": "dmx"})
    with pytest.raises(LightError, match="lights.port"):
        make_light_controller({"driver": "serial"})
    assert {"serial", "sim"} <= set(LIGHT_DRIVERS)


def test_sim_controller_uses_a_given_firmware(lights_firmware):
    with SimLightController(8, firmware=lights_firmware, timeout=LIGHTS_TIMEOUT) as controller:
        controller.on(3)
        assert lights_firmware.lit == 3
    assert lights_firmware.connected  # not ours to stop
