"""Per-light levels (lights: levels:) and exposure bracketing (exposure: bracket:)."""

import numpy as np
import pytest
import tifffile
import yaml

from pipeline.core.session import Session
from rig.capture import CaptureError, capture_session
from rig.config import ConfigError, get_rig, load_rigs
from rig.sim.rig import SimulatedRig

QUIET = {"progress": False, "echo": lambda line: None}
BASE = """
rigs:
  r:
    lights: {{driver: sim, count: 3, timeout: 0.4, rings: [{{elevation: 50, count: 3}}]{lights}}}
    camera: {{driver: sim, path: generic, busy_retries: 2, busy_backoff: 0.01}}
    frames: {{dark: 1, ambient: 0, sphere: false}}
    scene: {{shape: [48, 64], time_scale: 50}}
{extra}"""


def make_rig(tmp_path, lights="", extra=""):
    path = tmp_path / "rigs.yaml"
    path.write_text(BASE.format(lights=lights, extra=extra), encoding="utf-8")
    return get_rig("r", path)


def signal(session, frame_id):
    mosaic = tifffile.imread(session.path(session.frame(frame_id)["file"])).astype(float)
    return float(np.mean(mosaic - 512) / (16383 - 512))


def test_levels_are_set_before_capture_and_recorded(tmp_path):
    rig_config = make_rig(tmp_path, lights=", levels: [255, 51, 0]")
    lines = []
    with SimulatedRig(rig_config) as sim:
        session = capture_session(tmp_path / "s", rig_config, sim=sim, progress=False, echo=lines.append)
        assert sim.firmware.levels == [255, 51, 0]
        assert sim.firmware.history[1:4] == ["LEVEL 0 255", "LEVEL 1 51", "LEVEL 2 0"]
        ambient = signal(session, "object_002")  # level 0: only the room's light
        lit = [signal(session, f"object_{i:03d}") - ambient for i in range(2)]
        full = float(np.mean(sim.scenes["object"].render_linear(1, ambient=False)))
    assert session.manifest["lights"]["levels"] == [255, 51, 0]
    assert [f.get("level") for f in session.frames("object")] == [255, 51, 0]
    assert lit[1] == pytest.approx(full * 51 / 255, rel=0.05)
    assert any("lights 2 at level 0 will give dark frames" in line for line in lines)


@pytest.mark.parametrize("levels, message", [
    ("[255, 255]", r"lights.levels: 2 levels for 3 lights"),
    ("[255, 256, 0]", r"lights.levels: expected an integer from 0 to 255"),
    ("high", r"lights.levels: expected a list of levels"),
])
def test_bad_levels_are_refused(tmp_path, levels, message):
    with pytest.raises(ConfigError, match=message):
        make_rig(tmp_path, lights=f", levels: {levels}")


BRACKET = "    exposure: {bracket: [1/60, 1/15]}\n"


def test_a_bracket_shoots_every_frame_at_each_shutter(tmp_path):
    rig_config = make_rig(tmp_path, extra=BRACKET)
    with SimulatedRig(rig_config) as sim:
        session = capture_session(tmp_path / "s", rig_config, sim=sim, **QUIET)
    ids = [f["id"] for f in session.frames()]
    assert ids == ["dark_000_b0", "dark_000_b1", "object_000_b0", "object_000_b1",
                   "object_001_b0", "object_001_b1", "object_002_b0", "object_002_b1"]
    frame = session.frame("object_001_b1")
    assert frame["exposure"]["shutter"] == "1/15" and session.frame("object_001_b0")["exposure"]["shutter"] == "1/60"
    assert frame["bracket"] == {"group": "object_001", "index": 1, "shutter": "1/15", "of": 2}
    assert frame["light"] == 1
    ratio = signal(session, "object_001_b1") / signal(session, "object_001_b0")
    assert ratio == pytest.approx(4.0, rel=0.05)


def test_a_stopped_bracketed_capture_resumes_with_nothing_lost_or_doubled(tmp_path):
    rig_config = make_rig(tmp_path, extra=BRACKET)
    with SimulatedRig(rig_config, faults="camera.disconnect@object_001_b1") as sim:
        with pytest.raises(CaptureError, match="frame object_001_b1"):
            capture_session(tmp_path / "s", rig_config, sim=sim, **QUIET)
    first = {f["id"]: f["sha256"] for f in Session.open(tmp_path / "s").frames()}
    assert list(first) == ["dark_000_b0", "dark_000_b1", "object_000_b0", "object_000_b1",
                           "object_001_b0"]
    # as if killed between the raw file's rename and the manifest's save: the frame is adopted
    manifest = yaml.safe_load((tmp_path / "s" / "session.yaml").read_text())
    manifest["frames"] = manifest["frames"][:-1]
    manifest["frame_count"] = len(manifest["frames"])   # as a kill before the save leaves it
    (tmp_path / "s" / "session.yaml").write_text(yaml.safe_dump(manifest, sort_keys=False))
    session = capture_session(tmp_path / "s", rig_config, resume=True, **QUIET)
    frames = session.frames()
    assert [f["id"] for f in frames] == [
        "dark_000_b0", "dark_000_b1", "object_000_b0", "object_000_b1", "object_001_b0",
        "object_001_b1", "object_002_b0", "object_002_b1"]
    assert {f["id"]: f["sha256"] for f in frames if f["id"] in first} == first
    adopted = session.frame("object_001_b0")
    assert adopted["adopted"] and adopted["bracket"]["shutter"] == "1/60"
    assert session.frame("object_002_b1")["exposure"]["shutter"] == "1/15"
    for frame in frames:
        session.verify_frame(frame)
    assert sorted(p.name for p in session.path("raw").iterdir()) == sorted(
        f"{f['id']}.dng" for f in frames)


def test_bracket_validation(tmp_path):
    for text, message in [("    exposure: {bracket: [1/60]}\n", "2 or more shutter times"),
                          ("    exposure: {bracket: [1/60, 1/60]}\n", "the same shutter time twice"),
                          ("    exposure: {bracket: [1/60, 1/15], shutter: 1/30}\n", "not both"),
                          ("    exposure: {bracket: [1/60, soon]}\n", "'soon' is not a number")]:
        path = tmp_path / "rigs.yaml"
        path.write_text(BASE.format(lights="", extra=text), encoding="utf-8")
        with pytest.raises(ConfigError, match=message):
            load_rigs(path)
