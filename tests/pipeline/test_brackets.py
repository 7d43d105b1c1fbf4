"""Exposure brackets in the manifest: the stages' view (one frame per bracket) and the checks
that refuse a bracket that cannot be merged, naming its frames."""

import copy
import re

import pytest

from pipeline.core.brackets import format_seconds, reference_shutter, shutter_seconds
from pipeline.core.errors import ManifestError
from pipeline.core.session import Session, validate_manifest

SHA = "0" * 64


def frame(frame_id, kind="object", light=0, group=None, index=0, shutter="1/60", of=2):
    entry = {"id": frame_id, "kind": kind, "light": light, "file": f"raw/{frame_id}.dng", "sha256": SHA}
    if group is not None:
        entry["bracket"] = {"group": group, "index": index, "shutter": shutter, "of": of}
    return entry


def bracketed(kind, name, light):
    return [frame(f"{name}_b0", kind, light, name, 0, "1/60"), frame(f"{name}_b1", kind, light, name, 1, "1/15")]


def manifest(frames):
    return {"format": "psrig-session/1", "rig": {}, "camera": {}, "lights": {}, "frames": frames,
            "stages": {}, "truth": {}}


def session_of(tmp_path, frames):
    session = Session.create(tmp_path / "s")
    session.manifest["frames"] = frames
    session.save()
    return Session.open(session.root)


def test_the_stages_see_one_frame_per_bracket(tmp_path):
    frames = (bracketed("dark", "dark_000", None) + bracketed("object", "object_000", 0)
              + bracketed("object", "object_001", 1))
    session = session_of(tmp_path, frames)
    view = session.stage_frames()
    assert [f["id"] for f in view] == ["dark_000", "object_000", "object_001"]
    merged = session.stage_frames("object")[1]
    assert merged["light"] == 1 and merged["merged_from"] == ["object_001_b0", "object_001_b1"]
    assert merged["shutters"] == ["1/60", "1/15"] and merged["file"] == "raw/object_001_b0.dng"
    assert session.linear_path(merged) == session.path("linear/object_001.exr")
    assert len(session.frames("object")) == 4  # the manifest keeps every exposure
    assert reference_shutter(session.frames()) == pytest.approx(1 / 60)


def test_unbracketed_frames_are_seen_as_they_are(tmp_path):
    frames = [frame("dark_000", "dark", None), frame("object_000"), frame("object_001", light=1)]
    session = session_of(tmp_path, copy.deepcopy(frames))
    assert session.stage_frames() == session.frames()
    assert reference_shutter(session.frames()) is None


@pytest.mark.parametrize("change, message", [
    (lambda f: f[1].update(light=3), "'object_000_b0' and 'object_000_b1' are exposures of bracket 'object_000' "
                                     "but differ in kind or light"),
    (lambda f: f[1]["bracket"].update(shutter="1/60"), "share their index or shutter time"),
    (lambda f: f[1]["bracket"].update(index=0), "share their index or shutter time"),
    (lambda f: f.append(frame("object_000", light=5)), "bracket group 'object_000' (of 'object_000_b0') is also"),
    (lambda f: f.append(frame("object_009", light=9)), "object frames 'object_000_b0' (an exposure bracket) and "
                                                       "'object_009' (a single exposure) mix"),
    (lambda f: f[0]["bracket"].update(shutter="soon"), "frames[0].bracket.shutter: 'soon' is not a shutter time"),
    (lambda f: f[0]["bracket"].update(index=-1), "frames[0].bracket.index"),
    (lambda f: f[1]["bracket"].update(of=1), "frames[1].bracket.of"),
    (lambda f: f[0].update(bracket="yes"), "frames[0].bracket: expected a mapping"),
    (lambda f: f[0]["bracket"].update(group="../elsewhere"), "frames[0].bracket.group: expected the id"),
])
def test_a_bracket_that_cannot_be_merged_is_refused_naming_its_frames(change, message):
    frames = bracketed("object", "object_000", 0)
    change(frames)
    with pytest.raises(ManifestError, match=re.escape(message)):
        validate_manifest(manifest(frames), "session.yaml")


def test_shutter_times_as_recorded():
    assert shutter_seconds("1/60") == pytest.approx(1 / 60)
    assert shutter_seconds("1/60 s") == pytest.approx(1 / 60)
    assert shutter_seconds(2) == 2.0 and shutter_seconds("0.5s") == 0.5
    for bad in ("0", "-1/60", "1/0", "fast", True, "inf"):
        with pytest.raises(ValueError):
            shutter_seconds(bad)
    assert format_seconds(1 / 60) == "1/60 s" and format_seconds(2.0) == "2 s" and format_seconds(0.3) == "0.3 s"
