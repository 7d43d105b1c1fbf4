"""Pluggable drivers: registries, drivers' own keys, third-party plugins, sensible mixes."""

import importlib.metadata as md
import sys
import types

import pytest

import rig.drivers
from pipeline.cli import main
from rig.camera import Camera, CapturedImage
from rig.capture import capture_session
from rig.checks import ConfigError
from rig.config import get_rig, load_rigs
from rig.drivers import CameraDriver, LightDriver
from rig.lights import LightController
from rig.sim.rig import SimulatedRig

QUIET = {"progress": False, "echo": lambda line: None}


class MemoryLights(LightController):
    """A controller that only remembers what it was told (a stand-in for a DMX box)."""

    instances = []

    def __init__(self, universe):
        self.universe, self.count, self.lit, self.commands = universe, 3, None, []
        MemoryLights.instances.append(self)

    def open(self):
        return self

    def close(self):
        pass

    def on(self, index):
        self.lit = self.check_index(index)
        self.commands.append(f"ON {index}")

    def off(self):
        self.lit = None
        self.commands.append("OFF")

    def set_level(self, index, level):
        self.commands.append(f"LEVEL {index} {level}")

    def state(self):
        return self.lit


class DmxLights(LightDriver):
    """A third-party light driver: keys of its own, a 2 s watchdog and no keep-alive."""

    name = "dmx"
    keys = {"universe": rig.checks.integer(0, 32767), "host": rig.checks.text}
    required = ("universe",)
    reports_lit = True
    summary = "a DMX controller (test plugin)"

    def watchdog(self, config):
        return 2.0

    def create(self, config, **overrides):
        return MemoryLights(config["universe"])


class StillCamera(Camera):
    """A third-party camera returning one fixed DNG per capture."""

    dng = b""

    def open(self):
        return self

    def close(self):
        pass

    def capture(self):
        return CapturedImage(self.dng, "FIXED.DNG", 1, len(self.dng), 0x3811)

    @property
    def device_info(self):
        return {"model": "still", "serial": "1"}


class StillCameraDriver(CameraDriver):
    name = "still"
    keys = {"lens": rig.checks.text}
    summary = "a fixed image (test plugin)"

    def create(self, config, **overrides):
        return StillCamera()


@pytest.fixture
def plugins(monkeypatch):
    """Fake installed distributions declaring drivers (one broken), and fresh registries."""
    module = types.ModuleType("psrig_test_plugins")
    module.DmxLights, module.StillCameraDriver = DmxLights, StillCameraDriver
    monkeypatch.setitem(sys.modules, "psrig_test_plugins", module)
    points = {"psrig.lights": [md.EntryPoint("dmx", "psrig_test_plugins:DmxLights", "psrig.lights"),
                               md.EntryPoint("laser", "no_such_psrig_plugin:Driver", "psrig.lights")],
              "psrig.cameras": [md.EntryPoint("still", "psrig_test_plugins:StillCameraDriver",
                                              "psrig.cameras"),
                                md.EntryPoint("junk", "psrig_test_plugins:MemoryLights",
                                              "psrig.cameras")]}
    module.MemoryLights = MemoryLights
    monkeypatch.setattr(md, "entry_points", lambda group: points.get(group, []))
    lights, cameras = rig.drivers.new_registries()
    monkeypatch.setattr(rig.drivers, "LIGHT_DRIVERS", lights)
    monkeypatch.setattr(rig.drivers, "CAMERA_DRIVERS", cameras)
    MemoryLights.instances.clear()


def rigs_file(tmp_path, text):
    path = tmp_path / "rigs.yaml"
    path.write_text("rigs:\n" + text, encoding="utf-8")
    return path


DMX_SIM = """  dmx-bench:
    lights: {driver: dmx, universe: 2, count: 3, rings: [{elevation: 50, count: 3}]}
    camera: {driver: sim}
    frames: {dark: 1, ambient: 0, sphere: false}
    scene: {shape: [48, 64]}
"""


def test_rigs_lists_builtin_plugin_and_broken_drivers(plugins, tmp_path, capsys):
    assert main(["rigs", "--config", str(rigs_file(tmp_path, DMX_SIM))]) == 0
    out = capsys.readouterr().out
    assert "dmx-bench  dmx x3" in out
    lines = {tuple(line.split()[:3]): line for line in out.splitlines() if line.split()[:1] in
             (["lights"], ["camera"])}
    assert ("lights", "serial", "built") in lines and ("camera", "ptp", "built") in lines
    assert "a DMX controller" in lines[("lights", "dmx", "plugin")]
    assert "no_such_psrig_plugin" in lines[("lights", "laser", "plugin")]
    assert "BROKEN" in lines[("lights", "laser", "plugin")]
    assert "is not a rig.drivers.CameraDriver" in lines[("camera", "junk", "plugin")]


def test_each_driver_checks_its_own_keys(plugins, tmp_path):
    path = rigs_file(tmp_path, DMX_SIM.replace("universe: 2", "universe: 2, port: /dev/ttyACM0"))
    with pytest.raises(ConfigError, match=r"rig 'dmx-bench': lights.port: unknown key for the "
                                          r"'dmx' light driver \(known: universe, host\)"):
        load_rigs(path)
    path = rigs_file(tmp_path, DMX_SIM.replace("universe: 2, ", ""))
    with pytest.raises(ConfigError, match=r"lights.universe: missing \(the 'dmx' light driver"):
        load_rigs(path)
    path = rigs_file(tmp_path, DMX_SIM.replace("driver: dmx", "driver: laser"))
    with pytest.raises(ConfigError, match=r"lights.driver: light driver 'laser' is installed but "
                                          r"cannot be loaded"):
        load_rigs(path)
    # a serial driver without a port, a camera key the sim camera lacks
    path = rigs_file(tmp_path, "  r:\n    lights: {driver: sim, count: 1, directions: [[0, 0, 1]],"
                               " port: /dev/x}\n    camera: {driver: sim}\n")
    with pytest.raises(ConfigError, match=r"lights.port: unknown key for the 'sim' light driver"):
        load_rigs(path)


def test_a_plugin_light_driver_with_the_simulated_camera_captures(plugins, tmp_path):
    rig_config = get_rig("dmx-bench", rigs_file(tmp_path, DMX_SIM))
    session = capture_session(tmp_path / "s", rig_config, **QUIET)
    assert [f["id"] for f in session.frames()] == ["dark_000", "object_000", "object_001", "object_002"]
    (lights,) = MemoryLights.instances
    assert lights.universe == 2 and "ON 2" in lights.commands and lights.commands[-1] == "OFF"
    assert session.manifest["rig"]["lights"]["driver"] == "dmx"


def test_a_plugin_camera_with_simulated_lights_captures(plugins, tmp_path):
    picture = rigs_file(tmp_path, "  p:\n    lights: {driver: sim, count: 3, rings: [{elevation: 50, count: 3}]}\n"
                                  "    camera: {driver: sim}\n    scene: {shape: [48, 64]}\n")
    StillCamera.dng = SimulatedRig(get_rig("p", picture)).scenes["object"].render_dng(0)
    rig_config = get_rig("mixed", rigs_file(tmp_path, """  mixed:
    lights: {driver: sim, count: 3, timeout: 0.4, rings: [{elevation: 50, count: 3}]}
    camera: {driver: still, lens: 50mm}
    frames: {dark: 0, ambient: 0, sphere: false}
"""))
    session = capture_session(tmp_path / "s", rig_config, **QUIET)
    assert len(session.frames("object")) == 3
    assert session.manifest["camera"]["model"] == "still"


@pytest.mark.parametrize("text, message", [
    # no keep-alive and a 2 s watchdog: an 8 s exposure would lose its light
    (DMX_SIM + "    exposure: {shutter: 8}\n",
     r"exposure.shutter: 8 s exposures outlast the 2 s watchdog of the 'dmx' light controller"),
    (DMX_SIM.replace("driver: sim}", "driver: ptp, vendor_id: 1, product_id: 2}"),
     r"scene: only a simulated camera \(camera.driver: sim\) has a scene"),
])
def test_combinations_that_cannot_work_are_refused(plugins, tmp_path, text, message):
    with pytest.raises(ConfigError, match=message):
        load_rigs(rigs_file(tmp_path, text))


def test_serial_lights_take_long_exposures_and_sim_camera_needs_lights_that_report(plugins, tmp_path):
    ok = rigs_file(tmp_path, """  lab:
    lights: {driver: serial, port: /dev/ttyACM0, count: 1, directions: [[0, 0, 1]]}
    camera: {driver: sim}
    exposure: {shutter: 30}
""")
    assert load_rigs(ok)["lab"].simulated_camera  # real lights, simulated camera: allowed

    class Blind(DmxLights):
        reports_lit = False

    rig.drivers.LIGHT_DRIVERS.register("blind", Blind())
    with pytest.raises(ConfigError, match=r"camera.driver: a simulated camera renders the light "
                                          r"its controller reports lit; the 'blind' light driver"):
        load_rigs(rigs_file(tmp_path, DMX_SIM.replace("driver: dmx", "driver: blind")))
