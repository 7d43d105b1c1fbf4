"""Capture on the simulated rig: order, ids, hashes, truth, faults, interrupts, kills, resume."""

import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from pipeline.cli import main
from pipeline.core.errors import SessionError
from pipeline.core.session import Session
from rig.capture import PARTIAL, CaptureError, CaptureInterrupted, capture_session, check_raw_file, plan_frames
from rig.config import ConfigError, get_rig
from rig.sim.rig import SimulatedRig, parse_faults, split_faults

REPO = Path(__file__).resolve().parents[2]
_RINGS = """
      rings:
        - {elevation: 30, count: 8, azimuth: 0}
        - {elevation: 45, count: 8, azimuth: 22.5}
        - {elevation: 60, count: 8, azimuth: 0}
        - {elevation: 75, count: 8, azimuth: 22.5}"""
# Small scenes keep the suite fast; short timeouts keep lost replies cheap (0.4 s, as the light
# tests use on this loaded machine); 2 busy retries keep "busy beyond retries" quick.
RIGS = f"""
rigs:
  sim:
    lights:
      driver: sim
      count: 32
      timeout: 0.4
      write_timeout: 0.4{_RINGS}
    camera: {{driver: sim, path: generic, busy_retries: 2, busy_backoff: 0.01}}
    frames: {{dark: 1, ambient: 1, sphere: true}}
    scene: {{shape: [64, 96]}}
  sim8:
    lights:
      driver: sim
      count: 8
      timeout: 0.4
      write_timeout: 0.4
      rings: [{{elevation: 45, count: 8}}]
    camera: {{driver: sim, path: generic, busy_retries: 2, busy_backoff: 0.01}}
    frames: {{dark: 1, ambient: 1, sphere: true}}
    scene: {{shape: [48, 64], light_jitter_deg: 2.0}}
  slow:
    lights:
      driver: sim
      count: 32
      timeout: 0.4
      write_timeout: 0.4{_RINGS}
    camera: {{driver: sim, path: generic}}
    frames: {{dark: 1, ambient: 1, sphere: true}}
    scene: {{shape: [64, 96], exposure_seconds: 0.05}}
"""
QUIET = {"progress": False, "echo": lambda line: None}


@pytest.fixture
def rigs_path(tmp_path):
    path = tmp_path / "rigs.yaml"
    path.write_text(RIGS, encoding="utf-8")
    return path


@pytest.fixture
def rig32(rigs_path):
    return get_rig("sim", rigs_path)


@pytest.fixture
def rig8(rigs_path):
    return get_rig("sim8", rigs_path)


def assert_complete(root, rig):
    """Exactly the planned frames, each once, each matching its sha256; nothing else in raw/."""
    session = Session.open(root)
    ids = [f["id"] for f in session.frames()]
    assert sorted(ids) == sorted(s.frame_id for s in plan_frames(rig)), ids
    pairs = [(f["kind"], f["light"]) for f in session.frames()]
    assert len(pairs) == len(set(pairs))
    for frame in session.frames():
        session.verify_frame(frame)
        assert check_raw_file(session.path(frame["file"])) is None
    files = {f["file"] for f in session.frames()}
    leftovers = [p.name for p in session.path("raw").iterdir()
                 if p.name != ".partial" and f"raw/{p.name}" not in files]
    assert leftovers == []
    return session


# -- the whole capture ---------------------------------------------------------------------------

def test_full_capture_66_frames(tmp_path, rig32):
    session = capture_session(tmp_path / "s", rig32, **QUIET)
    assert_complete(session.root, rig32)
    ids = [f["id"] for f in session.frames()]
    assert ids == (["dark_000", "ambient_000"] + [f"object_{i:03d}" for i in range(32)]
                   + [f"sphere_{i:03d}" for i in range(32)])
    frame = session.frame("object_007")
    assert frame["light"] == 7 and frame["file"] == "raw/object_007.dng"
    assert frame["camera_file"].endswith(".DNG") and "captured_at" in frame
    m = session.manifest
    assert m["rig"]["name"] == "sim" and m["rig"]["config"].endswith("rigs.yaml")
    assert m["camera"]["model"] and m["camera"]["serial"] and m["camera"]["ptp_version"] == "1.00"
    # the session's lights are the nominal ones; the true (jittered) ones are in truth/ only
    nominal = np.array(m["lights"]["directions"])
    assert m["lights"]["source"] == "nominal" and np.allclose(nominal, rig32.lights.directions)
    true = np.array(yaml.safe_load(session.truth("lights").read_text())["directions"])
    angles = np.degrees(np.arccos(np.clip((true * nominal).sum(1), -1, 1)))
    assert np.allclose(angles, 1.5, atol=1e-3)
    for key in ("normals", "mask", "depth", "lights", "spheres"):
        assert session.truth(key).is_file(), key
    circles = yaml.safe_load(session.truth("spheres").read_text())["circles"]
    assert len(circles) == 3 and all(0 < c[0] < 96 and 0 < c[1] < 64 for c in circles)


def test_frames_show_what_the_rig_lit(tmp_path, rig8):
    import rawpy

    session = capture_session(tmp_path / "s", rig8, **QUIET)

    def mean(frame_id):
        with rawpy.imread(str(session.path(session.frame(frame_id)["file"]))) as raw:
            return float(raw.raw_image.mean())
    dark, ambient = mean("dark_000"), mean("ambient_000")
    assert dark < ambient < mean("object_000")
    assert abs(dark - 512) < 2  # black level: no light reached the sensor
    # sphere frames show the calibration scene, not the object
    assert session.frame("sphere_000")["sha256"] != session.frame("object_000")["sha256"]
    # reproducible: the same rig captures bit-identical frames
    again = capture_session(tmp_path / "t", rig8, **QUIET)
    assert [f["sha256"] for f in again.frames()] == [f["sha256"] for f in session.frames()]


def test_no_sphere_then_resume_adds_them(tmp_path, rig8):
    session = capture_session(tmp_path / "s", rig8, sphere=False, **QUIET)
    assert not session.frames("sphere") and len(session.frames("object")) == 8
    capture_session(tmp_path / "s", rig8, resume=True, **QUIET)
    assert_complete(tmp_path / "s", rig8)


# -- simulated rig settings --------------------------------------------------------------------

def test_sim_rig_scene_settings(rig8):
    rig8.scene = {"shape": [48, 64], "distance": 500.0, "seed": 3}
    sim = SimulatedRig(rig8)
    true = sim.true_lights
    assert np.allclose(true["positions"], true["directions"] * 500.0)
    assert sim.scenes["object"].positions is not None and sim.scenes["sphere"].shape == (48, 64)
    assert np.allclose(sim.scenes["object"].directions, sim.scenes["sphere"].directions)
    assert np.ptp(true["intensities"][:, 0]) > 0.05  # unequal intensities
    rig8.scene = {"shape": [48, 64], "colour": 1}
    with pytest.raises(ConfigError, match=r"scene\.colour: unknown key"):
        SimulatedRig(rig8)
    rig8.scene = {"shape": [47, 64]}
    with pytest.raises(ConfigError, match=r"scene\.shape"):
        SimulatedRig(rig8)


def test_fault_names():
    assert parse_faults("busy:2, garble@object_005") == {("busy", None): 2, ("garble", "object_005"): 1}
    split = split_faults({("camera.disconnect", "x"): 1, "err": 2, "light.disconnect": 1})
    assert split == {"x": {"light": {}, "camera": {"disconnect": 1}},
                     None: {"light": {"err": 2, "disconnect": 1}, "camera": {}}}
    with pytest.raises(ConfigError, match="light.disconnect or camera.disconnect"):
        split_faults({"disconnect": 1})
    with pytest.raises(ConfigError, match="unknown fault 'smoke'"):
        split_faults({"smoke": 1})


# -- faults --------------------------------------------------------------------------------------

AT = "object_003"
FAULTS = [  # (fault, count, ends the capture?)
    ("drop_reply", 1, False), ("drop_reply", 2, True),
    ("garble", 1, False), ("garble", 2, True),
    ("err", 1, False), ("err", 2, True),
    ("interlock", 1, True), ("light.disconnect", 1, True),
    ("busy", 2, False), ("busy", 3, True),
    ("timeout", 1, True), ("camera.disconnect", 1, True),
    ("truncated", 1, False), ("truncated", 2, True),
]


@pytest.mark.parametrize("fault,count,fatal", FAULTS, ids=[f"{f}:{n}" for f, n, _ in FAULTS])
def test_fault_then_resume(tmp_path, rig8, fault, count, fatal):
    root = tmp_path / "s"
    with SimulatedRig(rig8, faults={(fault, AT): count}) as sim:
        if fatal:
            with pytest.raises(CaptureError, match=rf"frame {AT} \(light 3\)") as info:
                capture_session(root, rig8, sim=sim, **QUIET)
            assert info.value.frame_id == AT and info.value.light == 3
            assert "--resume" in str(info.value)
        else:
            capture_session(root, rig8, sim=sim, **QUIET)
        assert sim.firmware.lit is None  # lights OFF, checked while the rig still runs
        assert not sim.firmware.pending_faults() and not sim.backend.faults.armed  # all struck
    if fatal:
        session = Session.open(root)  # valid after the failure, the failed frame not stored
        assert [f["id"] for f in session.frames()] == ["dark_000", "ambient_000", "object_000",
                                                       "object_001", "object_002"]
        assert not list(session.path("raw").glob(f"{AT}*"))
        capture_session(root, rig8, resume=True, **QUIET)
    assert_complete(root, rig8)


def test_session_left_open_on_camera_is_accepted(tmp_path, rig8):
    with SimulatedRig(rig8, faults={"session_open": 1}) as sim:
        capture_session(tmp_path / "s", rig8, sim=sim, **QUIET)
    assert_complete(tmp_path / "s", rig8)


def test_light_error_while_opening_is_retried(tmp_path, rig8):
    with SimulatedRig(rig8, faults={"garble": 1}) as sim:  # garbles the reply to ID?
        capture_session(tmp_path / "s", rig8, sim=sim, **QUIET)
        assert sim.firmware.history[0] == sim.firmware.history[1] == "ID?"
    assert_complete(tmp_path / "s", rig8)


# -- interrupts ------------------------------------------------------------------------------------

def _interrupt_at(sim, light, action):
    render = sim.backend.camera.render

    def sensor():
        if sim.scene == "object" and sim.firmware.lit == light:
            action()
        return render()
    sim.backend.camera.render = sensor


def test_ctrl_c_switches_lights_off_and_resumes(tmp_path, rig8):
    def ctrl_c():
        raise KeyboardInterrupt
    with SimulatedRig(rig8) as sim:
        _interrupt_at(sim, 4, ctrl_c)
        with pytest.raises(KeyboardInterrupt):
            capture_session(tmp_path / "s", rig8, sim=sim, **QUIET)
        assert sim.firmware.lit is None and sim.firmware.history[-1] == "OFF"
    session = Session.open(tmp_path / "s")
    assert [f["id"] for f in session.frames()][-1] == "object_003"
    capture_session(tmp_path / "s", rig8, resume=True, **QUIET)
    assert_complete(tmp_path / "s", rig8)


def test_sigterm_becomes_interrupt_and_handler_is_restored(tmp_path, rig8):
    before = signal.getsignal(signal.SIGTERM)
    with SimulatedRig(rig8) as sim:
        _interrupt_at(sim, 2, lambda: os.kill(os.getpid(), signal.SIGTERM))
        with pytest.raises(CaptureInterrupted):
            capture_session(tmp_path / "s", rig8, sim=sim, **QUIET)
        assert sim.firmware.lit is None
    assert signal.getsignal(signal.SIGTERM) is before
    capture_session(tmp_path / "s", rig8, resume=True, **QUIET)
    assert_complete(tmp_path / "s", rig8)


# -- resume -----------------------------------------------------------------------------------------

def test_resume_adopts_complete_orphans_and_moves_the_rest(tmp_path, rig8):
    root = tmp_path / "s"
    with SimulatedRig(rig8, faults={("timeout", "object_004"): 1}) as sim, pytest.raises(CaptureError):
        capture_session(root, rig8, sim=sim, **QUIET)
    raw = root / "raw"
    dng = SimulatedRig(rig8).scenes["object"].render_dng(4)
    (raw / "object_004.dng").write_bytes(dng)               # renamed in place, manifest not saved
    (raw / "object_005.dng").write_bytes(dng[: len(dng) // 2])  # not a complete file
    (raw / ".object_006.x1y2.tmp.dng").write_bytes(dng[:100])  # an atomic write's leftover
    (raw / "notes.txt").write_text("mine")
    capture_session(root, rig8, resume=True, **QUIET)
    session = assert_complete(root, rig8)
    assert session.frame("object_004")["adopted"] is True
    assert session.path("raw/object_004.dng").read_bytes() == dng
    partial = root / PARTIAL
    assert sorted(p.name for p in partial.iterdir()) == ["notes.txt", "object_005.dng"]
    assert (partial / "notes.txt").read_text() == "mine"
    assert not list(raw.glob(".*.tmp*"))


def test_resume_refuses_a_changed_or_missing_frame(tmp_path, rig8):
    root = tmp_path / "s"
    capture_session(root, rig8, sphere=False, **QUIET)
    target = root / "raw" / "object_002.dng"
    changed = target.read_bytes()[:-1] + b"\x00"
    target.write_bytes(changed)
    with pytest.raises(CaptureError, match="object_002") as info:
        capture_session(root, rig8, resume=True, **QUIET)
    assert "never captures over" in str(info.value) and target.read_bytes() == changed
    target.unlink()
    with pytest.raises(CaptureError, match="object_002.*missing"):
        capture_session(root, rig8, resume=True, **QUIET)
    assert not target.exists() and not Session.open(root).frames("sphere")


def test_refusals(tmp_path, rig8, rig32):
    root = tmp_path / "s"
    capture_session(root, rig8, sphere=False, **QUIET)
    with pytest.raises(CaptureError, match="--resume"):
        capture_session(root, rig8, **QUIET)
    with pytest.raises(CaptureError, match="rig 'sim8'.*rig 'sim'"):
        capture_session(root, rig32, resume=True, **QUIET)
    busy = tmp_path / "busy"
    busy.mkdir()
    (busy / "thesis.tex").write_text("precious")
    with pytest.raises(SessionError, match="neither an empty folder nor a session"):
        capture_session(busy, rig8, resume=True, **QUIET)
    assert (busy / "thesis.tex").read_text() == "precious"


def test_check_raw_file(tmp_path, rig8):
    dng = SimulatedRig(rig8).scenes["sphere"].render_dng(1)
    for name, data, ok in (("a.dng", dng, True), ("b.dng", dng[:-10], False),
                           ("c.dng", b"II*\x00garbage", False), ("d.nef", b"", False)):
        (tmp_path / name).write_bytes(data)
        assert (check_raw_file(tmp_path / name) is None) == ok, name


# -- command line ----------------------------------------------------------------------------------

def test_cli_capture_fault_and_resume(tmp_path, rigs_path, monkeypatch, capsys):
    root = str(tmp_path / "s")
    base = ["capture", root, "--rig", "sim8", "--config", str(rigs_path)]
    monkeypatch.setenv("PSRIG_SIM_FAULTS", "busy:3@sphere_002")
    assert main(base) == 1
    err = capsys.readouterr().err
    assert "frame sphere_002 (light 2)" in err and "DeviceBusy" in err and "Traceback" not in err
    monkeypatch.delenv("PSRIG_SIM_FAULTS")
    assert main(base) == 1 and "--resume" in capsys.readouterr().err
    assert main(base + ["--resume"]) == 0
    assert_complete(root, get_rig("sim8", rigs_path))


def test_cli_kill_9_at_random_moments_then_resume(tmp_path, rigs_path):
    # 50 ms exposures stretch a capture to ~4 s, so that kills in 0.3..3 s strike mid-capture
    rig = get_rig("slow", rigs_path)
    root = tmp_path / "s"
    command = [sys.executable, "-m", "pipeline", "capture", str(root), "--rig", "slow",
               "--config", str(rigs_path), "--resume"]
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    env.pop("PSRIG_SIM_FAULTS", None)
    moments = [random.uniform(0.3, 3.0) for _ in range(3)]
    killed, present = [], []
    for moment in moments:
        proc = subprocess.Popen(command, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        time.sleep(moment)
        proc.kill()
        proc.wait(timeout=30)
        killed.append(proc.returncode == -signal.SIGKILL)
        if (root / "session.yaml").is_file():  # whenever the kill struck, the session is valid
            present.append(len(Session.open(root).frames()))
    done = subprocess.run(command, env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, (moments, done.stderr)
    assert_complete(root, rig)
    assert any(killed), f"no run was killed at {moments}"
    print(f"killed at {moments} s: frames present after each kill {present}")


# -- a rig that is not the simulator: prompts -----------------------------------------------------

def test_hardware_path_asks_for_the_sphere(tmp_path, monkeypatch, bench_rig):
    rig = bench_rig("{dark: 0, ambient: 1, sphere: true}")
    asked = []
    session = capture_session(tmp_path / "a", rig, on_prompt=lambda m: asked.append(m) or False, **QUIET)
    assert asked and "sphere" in asked[0]
    assert [f["id"] for f in session.frames()] == ["ambient_000", "object_000", "object_001", "object_002"]
    assert session.manifest["rig"]["simulated"] is False and not session.manifest["truth"]
    monkeypatch.setattr("sys.stdin", None)
    with pytest.raises(CaptureError, match="--yes"):
        capture_session(tmp_path / "a", rig, resume=True, **QUIET)
    capture_session(tmp_path / "a", rig, resume=True, on_prompt=lambda m: True, **QUIET)
    assert_complete(tmp_path / "a", rig)


def test_session_without_sphere_frames_is_processed_with_the_nominal_lights(tmp_path, rig8):
    from pipeline.core.lightsio import read_lights
    from pipeline.runner import run_session

    session = capture_session(tmp_path / "s", rig8, sphere=False, **QUIET)
    assert not session.frames("sphere")
    outcomes = run_session(tmp_path / "s", stop="normals", echo=lambda line: None)
    notes = {o.name: o.note for o in outcomes}
    assert "nominal" in notes["calibrate"]
    lights = read_lights(session.path("calibration/lights.yaml"))
    assert "nominal" in lights.source
    assert np.allclose(lights.directions, rig8.lights.directions, atol=1e-7)
    assert session.path("normals/normals.exr").is_file()


def test_calibrate_takes_the_nominal_lights_as_run_does(tmp_path, rig8):
    # psrig calibrate and psrig run share one rule for a session without sphere frames: the
    # rig's nominal lights, said as such (calibrate refused them, and called them imported once
    # run had written them)
    from calibration import calibrate_session
    from pipeline.core.lightsio import read_lights

    session = capture_session(tmp_path / "s", rig8, sphere=False, **QUIET)
    said = []
    for _ in range(2):   # before any lights.yaml, and with the one it wrote
        assert calibrate_session(session, echo=said.append) is None
        lights = read_lights(session.path("calibration/lights.yaml"))
        assert "nominal" in lights.source and np.allclose(lights.directions, rig8.lights.directions, atol=1e-7)
    assert said == [f"{session.root}: no sphere frames: the rig's nominal (uncalibrated) lights are used"] * 2
