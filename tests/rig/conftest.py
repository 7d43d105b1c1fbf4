"""Fixtures for the light-controller and rig-config tests (named ``lights_*``) and a rig that
is not the simulator (``bench_rig``)."""

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


@pytest.fixture
def bench_rig(tmp_path, monkeypatch):
    """A rig that is not the simulator (3 simulated lights, a PTP camera on a simulated USB
    backend whose every capture is one rendered DNG), so capture asks its operator; built from
    its ``frames:`` text, e.g. ``bench_rig("{dark: 0, ambient: 1, sphere: true}")``."""
    from rig.camera import PtpCamera
    from rig.config import get_rig
    from rig.sim.rig import SimulatedRig
    from rig.sim.usb_camera import make_backend

    def make(frames):
        path = tmp_path / "bench.yaml"
        path.write_text(f"""
rigs:
  bench:
    lights: {{driver: sim, count: 3, reset_delay: 0, timeout: 0.4, rings: [{{elevation: 50, count: 3}}]}}
    camera: {{driver: ptp, vendor_id: 0x1209, product_id: 0x7053}}
    frames: {frames}
  picture:
    lights: {{driver: sim, count: 3, rings: [{{elevation: 50, count: 3}}]}}
    camera: {{driver: sim}}
    scene: {{shape: [48, 64]}}
""", encoding="utf-8")
        dng = SimulatedRig(get_rig("picture", path)).scenes["object"].render_dng(0)
        monkeypatch.setattr("rig.capture.make_camera", lambda config: PtpCamera(backend=make_backend(lambda: dng)))
        return get_rig("bench", path)
    return make
