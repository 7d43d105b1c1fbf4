"""rigs.yaml loading and validation, and the ``psrig rigs`` command."""

from pathlib import Path

import numpy as np
import pytest
import yaml

from pipeline.cli import main
from pipeline.core.lightsio import write_lp
from rig.config import (ConfigError, RigConfig, default_rig_name, find_rigs_file, get_rig,
                        load_rigs, ring_directions)
from rig.drivers import make_light_controller

REPO = Path(__file__).resolve().parents[2]

GOOD = """
rigs:
  lab2:
    lights: {driver: serial, port: /dev/ttyACM1, count: 2, directions: [[0, 0, 1], [1, 0, 1]]}
    camera: {driver: ptp, vendor_id: 0x04a9, product_id: "0x3294", path: canon}
    exposure: {shutter: 1/30, iso: 100}
    frames: {dark: 3, ambient: 1, sphere: false}
"""


def test_shipped_rigs_file_is_valid_and_the_sim_rigs_defined_once():
    rigs = load_rigs(REPO / "rigs.yaml")
    assert {"sim", "sim-near", "lab-dome", "bench-arm"} <= set(rigs)
    assert all(isinstance(rig, RigConfig) for rig in rigs.values())
    # one definition of the simulated rigs: the packaged file, not the example file
    assert "sim" not in (yaml.safe_load((REPO / "rigs.yaml").read_text())["rigs"])
    assert rigs["sim"].source.endswith("rig/sim/rigs.yaml")
    assert rigs["sim"].frames.ambient == 1  # as the demo has always captured
    assert not (REPO / "rig" / "rigs_default.yaml").exists()


def test_sim_rig_always_present_with_upper_hemisphere_rings(lights_rigs_file):
    rigs = load_rigs(lights_rigs_file(GOOD))
    assert set(rigs) == {"lab2", "sim", "sim-near"}
    sim = rigs["sim"]
    assert sim.is_simulated and sim.lights.count == 32
    dirs = sim.lights.directions
    assert dirs.shape == (32, 3)
    np.testing.assert_allclose(np.linalg.norm(dirs, axis=1), 1.0)
    elevation = np.degrees(np.arcsin(dirs[:, 2]))
    assert elevation.min() >= 29.9 and elevation.max() <= 75.1
    assert len(np.unique(np.round(dirs, 6), axis=0)) == 32
    # The built-in sim matches the shipped file's sim.
    np.testing.assert_allclose(load_rigs(REPO / "rigs.yaml")["sim"].lights.directions, dirs)


def test_good_rig_values(lights_rigs_file):
    rig = get_rig("lab2", lights_rigs_file(GOOD))
    assert rig.lights.driver == "serial" and rig.lights.port == "/dev/ttyACM1"
    assert rig.lights.baudrate == 115200 and rig.lights.count == 2
    np.testing.assert_allclose(rig.lights.directions[1], [2 ** -0.5, 0, 2 ** -0.5])
    assert (rig.camera.vendor_id, rig.camera.product_id, rig.camera.path) == (0x04A9, 0x3294, "canon")
    assert rig.exposure == {"shutter": "1/30", "iso": 100}
    assert (rig.frames.dark, rig.frames.ambient, rig.frames.sphere) == (3, 1, False)
    assert rig.raw_format == "dng"
    assert rig.lights["count"] == 2 and rig["camera"]["path"] == "canon"  # mapping access too
    assert len(rig.light_set()) == 2 and "lab2" in rig.light_set().source


BAD = [
    ("lights: {driver: serial, port: /dev/x, baudrate: fast, count: 1, directions: [[0,0,1]]}",
     "rig 'lab2': lights.baudrate: expected an integer, got 'fast'"),
    ("lights: {driver: serial, port: /dev/x, baudrat: 9600, directions: [[0,0,1]]}",
     "rig 'lab2': lights.baudrat: unknown key"),
    ("lights: {driver: serial, directions: [[0,0,1]]}", "rig 'lab2': lights.port: missing"),
    ("lights: {driver: dmx, port: /dev/x, directions: [[0,0,1]]}",
     "rig 'lab2': lights.driver: unknown light driver 'dmx'"),
    ("lights: {driver: serial, port: /dev/x}", "rig 'lab2': lights: give exactly one of"),
    ("lights: {driver: serial, port: /dev/x, directions: [[0,0,1]], rings: [{elevation: 30, count: 4}]}",
     "(got directions, rings)"),
    ("lights: {driver: serial, port: /dev/x, count: 3, directions: [[0,0,1]]}",
     "lights.count: 3 lights, but lights.directions gives 1"),
    ("lights: {driver: serial, port: /dev/x, directions: [[0,0,1,2]]}",
     "lights.directions: expected lists of 3 numbers"),
    ("lights: {driver: serial, port: /dev/x, directions: [[0,0,0]]}",
     "lights.directions: light 0 has no direction"),
    ("lights: {driver: serial, port: /dev/x, directions: [[0,0,1]], target: [0,0,0]}",
     "lights.target: only meaningful"),
    ("lights: {driver: serial, port: /dev/x, rings: [{elevation: 30}]}", "lights.rings:"),
    ("lights: {driver: serial, port: /dev/x, lp: missing.lp}", "lights.lp: cannot read"),
]


@pytest.mark.parametrize("lights, message", BAD)
def test_bad_lights_named(lights_rigs_file, lights, message):
    path = lights_rigs_file(f"rigs:\n  lab2:\n    {lights}\n    camera: {{driver: sim}}\n")
    with pytest.raises(ConfigError) as info:
        load_rigs(path)
    assert str(info.value).startswith(f"{path}: ")
    assert message in str(info.value)


@pytest.mark.parametrize("extra, message", [
    ("    camera: {driver: ptp, product_id: 1}\n", "camera.vendor_id: missing"),
    ("    camera: {driver: ptp, vendor_id: 1, product_id: zz}\n", "camera.product_id: expected a USB id"),
    ("    camera: {driver: sim, path: sony}\n", "camera.path: expected one of generic, canon, nikon"),
    ("    camera: {driver: sim}\n    frames: {dark: -1}\n", "frames.dark: expected an integer from 0 to 1000, got -1"),
    ("    camera: {driver: sim}\n    frames: {sphere: yes please}\n", "frames.sphere: expected true or false"),
    ("    camera: {driver: sim}\n    raw_format: jpeg\n", "raw_format: expected one of dng"),
    ("    camera: {driver: sim}\n    exposure: 1/30\n", "exposure: expected a mapping"),
    ("    camera: {driver: sim}\n    exposur: {iso: 100}\n", "exposur: unknown key"),
    ("", "rig 'lab2': camera: missing"),
])
def test_bad_rig_keys_named(lights_rigs_file, extra, message):
    text = "rigs:\n  lab2:\n    lights: {driver: sim, count: 1, directions: [[0,0,1]]}\n" + extra
    with pytest.raises(ConfigError, match="rig 'lab2': ") as info:
        load_rigs(lights_rigs_file(text))
    assert message in str(info.value)


@pytest.mark.parametrize("text, message", [
    ("rigs:\n  a: {lights: {driver: sim, rings: [{elevation: 30, count: 2}]}, camera: {driver: sim}}\n"
     "  a: {lights: {driver: sim, rings: [{elevation: 30, count: 2}]}, camera: {driver: sim}}\n",
     "line 3: key 'a' appears twice"),
    ("rig:\n  a: {}\n", "rig: unknown top-level key"),
    ("rigs: [1, 2]\n", "rigs: expected a mapping"),
    ("rigs: {a: [}\n", "not valid YAML"),
    ("rigs: !!python/object/apply:os.system [echo hi]\n", "not valid YAML"),
    ("default: lab9\n", "default: no rig named 'lab9'"),
    ("rigs:\n  sim: {lights: {driver: serial, port: /dev/x, count: 1, directions: [[0,0,1]]},"
     " camera: {driver: sim}}\n", "rig 'sim': lights.driver: the rig 'sim' must need no hardware"),
    ("rigs:\n  'my rig': {}\n", "'my rig' is not a valid rig name"),
])
def test_file_level_errors(lights_rigs_file, text, message):
    path = lights_rigs_file(text)
    with pytest.raises(ConfigError) as info:
        load_rigs(path)
    assert str(info.value).startswith(str(path)) and message in str(info.value)


def test_lp_relative_to_rig_file_and_positions(tmp_path, lights_rigs_file):
    dirs = np.array([[0.3, 0.1, 1.0], [-0.5, 0.2, 1.0], [0.0, -0.6, 1.0]])
    (tmp_path / "lp").mkdir()
    write_lp(tmp_path / "lp" / "dome.lp", ["a.jpg", "b.jpg", "c.jpg"], dirs)
    path = lights_rigs_file(
        "rigs:\n"
        "  lp: {lights: {driver: serial, port: /dev/x, count: 3, lp: lp/dome.lp}, camera: {driver: sim}}\n"
        "  near: {lights: {driver: sim, positions: [[10, 0, 10], [0, 20, 10]], target: [0, 0, 5]},"
        " camera: {driver: sim}}\n")
    rigs = load_rigs(path)
    expected = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    np.testing.assert_allclose(rigs["lp"].lights.directions, expected, atol=1e-6)
    near = rigs["near"].lights
    np.testing.assert_allclose(near.directions, [[10 / 125 ** 0.5, 0, 5 / 125 ** 0.5],
                                                 [0, 20 / 425 ** 0.5, 5 / 425 ** 0.5]])
    np.testing.assert_allclose(near.positions, [[10, 0, 10], [0, 20, 10]])


def test_ring_directions_azimuth_convention():
    dirs = ring_directions([{"elevation": 0, "count": 4, "azimuth": 0}])
    np.testing.assert_allclose(dirs, [[1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0]], atol=1e-12)


def test_file_search_order(tmp_path, monkeypatch, lights_rigs_file):
    monkeypatch.delenv("PSRIG_RIGS", raising=False)
    monkeypatch.chdir(tmp_path)
    assert find_rigs_file() == REPO / "rigs.yaml"
    local = lights_rigs_file(GOOD)
    assert find_rigs_file() == local and "lab2" in load_rigs()
    other = lights_rigs_file("default: sim\n", name="other.yaml")
    monkeypatch.setenv("PSRIG_RIGS", str(other))
    assert set(load_rigs()) == {"sim", "sim-near"} and default_rig_name() == "sim"
    with pytest.raises(ConfigError, match=r"nowhere\.yaml: cannot read"):
        load_rigs(tmp_path / "nowhere.yaml")
    with pytest.raises(ConfigError, match="no rig named 'lab9' \\(rigs: sim, sim-near\\)"):
        get_rig("lab9")


def test_sim_rig_drives_its_lights():
    rig = get_rig("sim", REPO / "rigs.yaml")
    with make_light_controller(rig.lights, timeout=0.5) as lights:
        assert lights.count == rig.lights.count
        lights.on(31)
        assert lights.firmware.lit == 31
    assert lights.firmware.lit is None


def test_cli_lists_and_validates(lights_rigs_file, capsys):
    path = lights_rigs_file(GOOD)
    assert main(["rigs", "--config", str(path)]) == 0
    out = capsys.readouterr().out
    assert "lab2" in out and "serial x2 on /dev/ttyACM1" in out and "ptp canon 04a9:3294" in out
    assert "sim x32" in out and "3 rigs, all valid" in out

    assert main(["rigs", "--config", str(path), "--show", "lab2"]) == 0
    assert "port: /dev/ttyACM1" in capsys.readouterr().out

    bad = lights_rigs_file(GOOD.replace("dark: 3", "dark: many"), name="bad.yaml")
    assert main(["rigs", "--config", str(bad)]) == 1
    err = capsys.readouterr().err
    assert err.strip() == (f"psrig rigs: error: {bad}: rig 'lab2': frames.dark: "
                           "expected an integer, got 'many'")
    assert "Traceback" not in err

    assert main(["rigs", "--config", str(path), "--show", "lab9"]) == 1
    assert "no rig named 'lab9'" in capsys.readouterr().err


def test_cli_check_lights(lights_rigs_file, capsys):
    path = lights_rigs_file(GOOD)
    assert main(["rigs", "--config", str(path), "--check-lights", "sim"]) == 0
    assert "psrig light protocol 1, 32 lights, none lit" in capsys.readouterr().out
    assert main(["rigs", "--config", str(path), "--check-lights", "lab2"]) == 1
    assert "/dev/ttyACM1: cannot open the light controller" in capsys.readouterr().err


def test_sections_are_dicts_the_drivers_accept(lights_rigs_file):
    camera_module = pytest.importorskip("rig.camera")
    rig = get_rig("lab2", lights_rigs_file(GOOD))
    assert isinstance(rig.camera, dict) and isinstance(rig.lights, dict)
    assert set(rig.camera) <= set(camera_module.CONFIG_KEYS)
    camera = camera_module.make_camera(rig.camera)  # built, not opened: no USB needed
    assert (camera.vendor_id, camera.product_id) == (0x04A9, 0x3294)
