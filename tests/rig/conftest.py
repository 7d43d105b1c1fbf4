"""Fixtures for the light-controller and rig-config tests (all named ``lights_*``)."""

import pytest

from rig.lights import SerialLightController
from rig.sim.firmware import SimulatedLightFirmware

# Short enough for a fast suite, long enough for a loaded 2-core machine to answer in time.
LIGHTS_TIMEOUT = 0.4


@pytest.fixture
def lights_firmware():
    """A started simulated light firmware with 8 lights (stopped afterwards)."""
    with SimulatedLightFirmware(8, watchdog=5.0) as firmware:
        yield firmware


@pytest.fixture
def lights_controller(lights_firmware):
    """The real serial driver, open on ``lights_firmware``'s pty."""
    controller = SerialLightController(lights_firmware.port, timeout=LIGHTS_TIMEOUT,
                                       write_timeout=LIGHTS_TIMEOUT, reset_delay=0.02)
    with controller:
        yield controller


@pytest.fixture
def lights_rigs_file(tmp_path):
    """Write a rigs.yaml into tmp_path from text; returns its path."""
    def write(text, name="rigs.yaml"):
        path = tmp_path / name
        path.write_text(text, encoding="utf-8")
        return path
    return write
