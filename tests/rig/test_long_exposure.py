"""Exposures longer than the light firmware's 5 s watchdog (issue 20, item 1).

The simulated clock runs 40 times faster than real time (``scene: time_scale: 40``), so an 8 s
exposure takes 0.2 s and the watchdog trips after 0.125 s; a neutral-density filter
(``nd_stops: 8``) keeps the 240x longer exposure from clipping.
"""

import numpy as np
import pytest
import serial
import tifffile

from rig.capture import CaptureError, capture_session
from rig.config import get_rig
from rig.sim.clock import SimClock
from rig.sim.firmware import SimulatedLightFirmware
from rig.sim.rig import SimulatedRig

QUIET = {"progress": False, "echo": lambda line: None}
RIGS = """
rigs:
  long:
    lights: {driver: sim, count: 3, timeout: 0.4, rings: [{elevation: 50, count: 3}]}
    camera: {driver: sim, path: generic}
    exposure: {shutter: 8}
    frames: {dark: 0, ambient: 0, sphere: false}
    scene: {shape: [48, 64], time_scale: 40, nd_stops: 8}
"""


@pytest.fixture
def long_rig(tmp_path):
    path = tmp_path / "rigs.yaml"
    path.write_text(RIGS, encoding="utf-8")
    return get_rig("long", path)


def _signal(path):
    """Mean of a DNG's mosaic above black, as a share of white (float)."""
    mosaic = tifffile.imread(path).astype(float)
    return float(np.mean(mosaic - 512) / (16383 - 512))


def _expected_signal(sim, light):
    """The share of white an exposure lit all along by ``light`` records (no noise)."""
    scene = sim.scenes["object"]
    gain = sim.backend.camera.exposure_gain() * 2.0 ** -sim.settings["nd_stops"]
    return float(np.mean(np.clip(scene.render_linear(light) * gain, 0, 1)))


def test_an_8_s_exposure_keeps_its_light(long_rig, tmp_path):
    with SimulatedRig(long_rig) as sim:
        session = capture_session(tmp_path / "s", long_rig, sim=sim, **QUIET)
        assert sim.firmware.watchdog_trips == 0
        assert sim.firmware.history.count("STATE?") >= 3 * 7  # ~every 1 s of 8, per frame
        for frame in session.frames("object"):
            measured = _signal(session.path(frame["file"]))
            assert measured == pytest.approx(_expected_signal(sim, frame["light"]), rel=0.05), frame["id"]


def test_simulated_exposure_integrates_what_was_lit():
    clock = SimClock(40)
    with SimulatedLightFirmware(2, watchdog=5.0, clock=clock) as firmware:
        with serial.Serial(firmware.port, timeout=0.5) as port:
            port.write(b"LEVEL 1 51\n")
            port.readline()
            port.write(b"ON 1\n")
            assert port.readline() == b"OK ON 1\n"
            start = clock.now()
            clock.sleep(8.0)
            weights = firmware.light_weights(start, clock.now())
        assert firmware.watchdog_trips == 1
    # lit 5 s of 8 at level 51/255, then cut by the watchdog (start is a little after the ON)
    assert weights.keys() == {1}
    assert weights[1] == pytest.approx(5 / 8 * 0.2, abs=0.02)


def test_a_light_cut_during_the_exposure_refuses_the_frame(long_rig, tmp_path):
    """A controller that is not kept alive loses its light at 5 s of 8: the frame is shot
    again once, then refused with an error naming it; nothing dark is stored."""
    with SimulatedRig(long_rig) as sim:
        sim.lights.watchdog = None  # the host no longer keeps the light alive
        with pytest.raises(CaptureError, match=r"frame object_000 \(light 0\): after the exposure "
                                               r"the light controller reported no light lit .* "
                                               r"the frame was not stored \(2 exposures\)"):
            capture_session(tmp_path / "s", long_rig, sim=sim, **QUIET)
        assert sim.firmware.watchdog_trips == 2
    assert not list((tmp_path / "s" / "raw").glob("object_*"))
