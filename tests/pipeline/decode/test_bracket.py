"""Exposure brackets through decode: captured on the simulated rig (``exposure: {bracket:
[1/60, 1/15]}``), decoded by ``psrig decode`` into one frame per light whose highlights come
from the short exposure where the long one clipped; each exposure minus the dark (ambient)
frame of its own shutter; refusals named; a re-shot exposure re-merges its group only; the
whole chain (``psrig run``) on a bracketed session against unbracketed ones."""

import shutil

import numpy as np
import pytest
import yaml

from pipeline.cli import main
from pipeline.decode import decode_frame
from pipeline.core.imageio import read_image, read_mask
from pipeline.core.session import Session, file_sha256
from rig.capture import CaptureError, capture_session
from rig.config import get_rig
from rig.sim.rig import SimulatedRig
from tests.pipeline.decode.test_interrupt import bracketed_session

QUIET = {"progress": False, "echo": lambda line: None}
RIG = """
rigs:
  r:
    lights: {{driver: sim, count: {count}, timeout: 0.4,
              rings: [{{elevation: 40, count: 4}}, {{elevation: 65, count: {rest}, azimuth: 45}}]}}
    camera: {{driver: sim, path: generic, busy_retries: 2, busy_backoff: 0.01}}
    frames: {{dark: 1, ambient: 1, sphere: {sphere}}}
    scene: {{shape: [96, 128], time_scale: 50}}
    exposure: {exposure}
"""
BRACKET = "{bracket: [1/60, 1/15]}"
LIGHTS = 8


def make_rig(folder, exposure=BRACKET, count=LIGHTS, sphere=False):
    path = folder / f"rig_{abs(hash((exposure, count, sphere)))}.yaml"
    path.write_text(RIG.format(count=count, rest=count - 4, sphere=str(sphere).lower(), exposure=exposure))
    return get_rig("r", path)


@pytest.fixture(scope="module")
def captured(tmp_path_factory):
    """A bracketed capture (dark, ambient, 8 lights; no sphere) and its true linear images."""
    folder = tmp_path_factory.mktemp("bracket")
    rig_config = make_rig(folder)
    with SimulatedRig(rig_config) as sim:
        capture_session(folder / "s", rig_config, sim=sim, **QUIET)
        # what each light alone gives at the factory shutter (1/30 s), before noise and clipping
        truth = [sim.scenes["object"].render_linear(k, ambient=False) for k in range(LIGHTS)]
    return folder / "s", truth


@pytest.fixture
def root(captured, tmp_path):
    return shutil.copytree(captured[0], tmp_path / "s")


def edit(root, change):
    path = root / "session.yaml"
    data = yaml.safe_load(path.read_text())
    change(data)
    data["frame_count"] = len(data["frames"])
    path.write_text(yaml.safe_dump(data, sort_keys=False))


def drop(*ids):
    return lambda data: data.__setitem__("frames", [f for f in data["frames"] if f["id"] not in ids])


def linear(session, frame_id):
    return read_image(session.linear_path(frame_id)), read_mask(session.saturation_path(frame_id))


def exposure(session, frame_id):
    """One exposure decoded alone, minus the ambient frame of its shutter (what decode does
    before merging): linear (H, W, 3) and saturation (H, W)."""
    index = session.frame(frame_id)["bracket"]["index"]
    lit, lit_sat, _ = decode_frame(session.path(session.frame(frame_id)["file"]))
    ambient, ambient_sat, _ = decode_frame(session.path(session.frame(f"ambient_000_b{index}")["file"]))
    return lit - ambient, lit_sat | ambient_sat


def test_a_bracket_decodes_to_one_frame_per_light_with_its_highlights_recovered(captured, root, capsys):
    assert main(["decode", str(root)]) == 0
    out = capsys.readouterr().out
    assert "10 exposure bracket(s) merged into one frame each, scaled to 1/60 s" in out, out
    session = Session.open(root)
    assert [f["id"] for f in session.stage_frames("object")] == [f"object_{k:03d}" for k in range(LIGHTS)]
    record = session.stage("decode")
    truth = captured[1]
    clipped_anywhere, errors = 0, {}
    for k in range(LIGHTS):
        (short, short_sat), (long, long_sat) = (exposure(session, f"object_{k:03d}_b{n}") for n in (0, 1))
        merged, merged_sat = linear(session, f"object_{k:03d}")
        clipped = long_sat & ~short_sat
        clipped_anywhere += clipped.sum()
        # where the long exposure clipped: the short one's values (the reference is 1/60 s) ...
        np.testing.assert_allclose(merged[clipped], short[clipped], rtol=1e-6, atol=1e-7)
        # ... elsewhere the long one's, scaled by 1/60 / (1/15)
        np.testing.assert_allclose(merged[~long_sat], long[~long_sat] / 4, rtol=1e-5, atol=1e-7)
        np.testing.assert_array_equal(merged_sat, long_sat & short_sat)
        info = record["merged"][f"object_{k:03d}"]
        assert info["merged_from"] == [f"object_{k:03d}_b0", f"object_{k:03d}_b1"]
        assert info["reference_shutter"] == pytest.approx(1 / 60)
        assert info["from"][f"object_{k:03d}_b0"] == pytest.approx(long_sat.mean(), abs=1e-6)
        assert info["ratios"][0]["measured"] == pytest.approx(4.0, rel=0.01)
        # against the truth at 1/60 s (half the factory shutter's light)
        true = truth[k] * 0.5
        lost = (true * 4 > 1).any(axis=2)   # the long exposure cannot hold these
        both = ~long_sat & ~short_sat
        for name, image, where in (("merged", merged, lost), ("long", long / 4, lost),
                                   ("merged_both", merged, both), ("short_both", short, both)):
            errors[name] = errors.get(name, 0.0) + np.abs(image - true)[where].sum()
    # the long exposure alone loses its highlights, the short one alone is noisier
    assert errors["merged"] < 0.5 * errors["long"], errors
    assert errors["merged_both"] < errors["short_both"], errors
    assert clipped_anywhere > 1000, "the long exposure clips the highlights"


def test_each_exposure_has_the_ambient_frame_of_its_own_shutter_subtracted(root):
    assert main(["decode", str(root)]) == 0
    session = Session.open(root)
    merged, _ = linear(session, "object_003")
    lit, lit_sat, _ = decode_frame(session.path(session.frame("object_003_b1")["file"]))
    ambient = [decode_frame(session.path(session.frame(f"ambient_000_b{n}")["file"]))[0] for n in (0, 1)]
    assert session.stage("decode")["merged"]["object_003"]["from"]["object_003_b1"] > 0.8
    # the long exposure minus the long ambient frame, not the mean of both shutters' ambient frames,
    # where the ambient light matters most (dark pixels, taken from the long exposure)
    dark = (merged.mean(axis=2) < 0.05) & ~lit_sat
    np.testing.assert_allclose(merged[dark], ((lit - ambient[1]) / 4)[dark], atol=1e-6)
    assert np.abs(merged[dark] - ((lit - (ambient[0] + ambient[1]) / 2) / 4)[dark]).mean() > 1e-4
    by_shutter = session.stage("decode")["subtracted"]["by_kind"]["object"]["by_shutter"]
    assert by_shutter == {"1/60": {"kind": "ambient", "frames": ["ambient_000_b0"]},
                          "1/15": {"kind": "ambient", "frames": ["ambient_000_b1"]}}


def test_an_exposure_without_a_dark_of_its_shutter_is_refused(root, capsys):
    edit(root, drop("dark_000_b1", "ambient_000_b1"))
    assert main(["decode", str(root)]) == 1
    captured = capsys.readouterr()
    assert "Traceback" not in captured.err
    assert ("frame 'object_002' (exposure 'object_002_b1'): no ambient or dark frame shot at 1/15 s like it "
            "to subtract (the session's are shot at 1/60 s: dark_000_b0, ambient_000_b0)") in captured.err, captured.err
    record = Session.open(root).stage("decode")
    assert record["status"] == "partial"
    assert "1 of the 2 exposures of its bracket" in record["failed"]["dark_000"]
    assert not any(group.startswith("object") for group in record.get("merged", {}))


def test_an_incomplete_bracket_is_not_merged(root, capsys):
    assert main(["decode", str(root)]) == 0
    edit(root, drop("object_007_b1"))   # as a capture stopped between the two exposures leaves it
    assert main(["decode", str(root)]) == 1
    err = capsys.readouterr().err
    assert ("frame 'object_007': 1 of the 2 exposures of its bracket are in the session (index 1 missing: "
            "the capture stopped mid-bracket); not merged: complete the capture with psrig capture --resume") in err
    session = Session.open(root)
    assert sorted(session.stage("decode")["merged"]) == ["ambient_000", "dark_000"] + [
        f"object_{k:03d}" for k in range(7)]
    assert not session.linear_path("object_007").exists(), "the earlier merge is not left to pass for it"
    assert main(["normals", str(root)]) == 1
    err = capsys.readouterr().err
    assert "linear/object_007.exr: normals: decoded frame of 'object_007' is missing" in err, err


def test_a_capture_stopped_mid_bracket_is_merged_once_resumed(tmp_path, capsys):
    rig_config = make_rig(tmp_path)
    root = tmp_path / "s"
    with SimulatedRig(rig_config, faults="camera.disconnect@object_001_b1") as sim:
        with pytest.raises(CaptureError, match="frame object_001_b1"):
            capture_session(root, rig_config, sim=sim, **QUIET)
    assert main(["decode", str(root)]) == 1
    assert "frame 'object_001': 1 of the 2 exposures of its bracket" in capsys.readouterr().err
    first = (root / "linear" / "object_000.exr").stat().st_mtime_ns
    capture_session(root, rig_config, resume=True, **QUIET)
    assert main(["decode", str(root)]) == 0
    record = Session.open(root).stage("decode")
    assert sorted(record["merged"]) == ["ambient_000", "dark_000"] + [f"object_{k:03d}" for k in range(LIGHTS)]
    assert (root / "linear" / "object_000.exr").stat().st_mtime_ns == first   # merged once


def reshoot(root, frame_id, like):
    """Decode, then shoot ``frame_id`` again (here: a copy of ``like``'s raw file as its new
    file, the manifest updated as a re-shoot leaves it) and decode again; the names of the
    files in linear/ the second decode rewrote."""
    assert main(["decode", str(root)]) == 0
    session = Session.open(root)
    before = {p.name: p.stat().st_mtime_ns for p in session.path("linear").glob("*")}
    new = session.path(f"raw/{frame_id}_again.dng")
    new.write_bytes(session.path(session.frame(like)["file"]).read_bytes())
    digest = file_sha256(new)

    def change(data):
        entry = next(f for f in data["frames"] if f["id"] == frame_id)
        entry.update(file=f"raw/{frame_id}_again.dng", sha256=digest)
    edit(root, change)
    assert main(["decode", str(root)]) == 0
    after = {p.name: p.stat().st_mtime_ns for p in session.path("linear").glob("*")}
    return sorted(name for name in before if after[name] != before[name])


def test_a_reshot_exposure_re_merges_its_group_only(root, capsys):
    assert reshoot(root, "object_003_b1", like="object_005_b1") == ["object_003.exr", "object_003_sat.png"]
    capsys.readouterr()
    assert main(["decode", str(root)]) == 0 and "up to date" in capsys.readouterr().out


def test_a_reshot_ambient_exposure_re_merges_every_bracket_it_is_subtracted_from(root):
    changed = [name for name in reshoot(root, "ambient_000_b1", like="dark_000_b1") if name.endswith(".exr")]
    assert changed == ["ambient_000.exr", "ambient_000_b1.exr"] + [f"object_{k:03d}.exr" for k in range(LIGHTS)]


@pytest.mark.parametrize("gain, outcome", [
    (4.5, "warning: frame 'object_001': the exposure at 1/15 s is 4.500 x the one at 1/60 s, its shutter "
          "time says 4.000 x; merged as the shutter times say"),
    (1.0, "frame 'object_001' (exposures object_001_b0, object_001_b1): the exposure at 1/15 s is 1.00 x the "
          "one at 1/60 s over"),
])
def test_exposures_off_their_shutter_ratio_are_said_or_refused(tmp_path, capsys, gain, outcome):
    root = bracketed_session(tmp_path / "s", groups=2, shape=(64, 64), gain=gain)
    code = main(["decode", str(root)])
    out, err = capsys.readouterr()
    assert outcome in (out if gain > 1 else err), (out, err)
    assert code == (0 if gain > 1 else 1) and "Traceback" not in err
    record = Session.open(root).stage("decode")
    if gain > 1:
        assert record["warnings"] and record["merged"]["object_001"]["ratios"][0]["measured"] == pytest.approx(4.5, rel=1e-3)
    else:
        assert "object_001" not in record["merged"] and "do not scale" in record["failed"]["object_001"]


@pytest.mark.slow
def test_psrig_run_on_a_bracketed_session_beats_single_exposures(tmp_path, capsys):
    """Every stage runs on a bracketed session, and its normals are no worse than a session
    shot at either of its shutter times alone (same scene, same seed)."""
    errors = {}
    for name, exposure in (("bracket", BRACKET), ("short", "{shutter: 1/60}"), ("long", "{shutter: 1/15}")):
        root = tmp_path / name
        capture_session(root, make_rig(tmp_path, exposure, sphere=True), **QUIET)
        assert main(["run", str(root)]) == 0
        ran = {line.split(": ")[1] for line in capsys.readouterr().out.splitlines() if ": ran in" in line}
        assert ran == {"decode", "calibrate", "normals", "integrate", "report"}
        assert main(["eval", str(root), "--json"]) == 0
        errors[name] = yaml.safe_load(capsys.readouterr().out)["normals"]["mean_deg"]
    assert errors["bracket"] <= min(errors["short"], errors["long"]), errors
    root = tmp_path / "bracket"
    assert main(["run", str(root)]) == 0 and ": ran in" not in capsys.readouterr().out
    frames = sorted(p.name for p in (root / "report" / "frames").glob("object_*.png"))
    assert frames == [f"object_{k:03d}.png" for k in range(LIGHTS)], frames   # one per light
