"""Outline frames carried by the session: imported, decoded as they are, used by calibrate."""

import numpy as np
import pytest
import yaml

from calibration.circle import find_spheres
from calibration.sphere import calibrate_sphere
from pipeline.cli import main
from pipeline.core.gamma import encode_gamma, inverse_gamma_lut
from pipeline.core.errors import InputError
from pipeline.core.imageio import read_image, write_image
from pipeline.core.session import Session
from tests.calibration.sim_session import linear_frames, sphere_scene
from tests.calibration.test_outline import _discs


@pytest.fixture(scope="module")
def scene():
    return sphere_scene(6)


def _write_frames(folder, scene):
    """16-bit linear PNGs of the sphere frames; returns their glob."""
    folder.mkdir()
    images, _ = linear_frames(scene)
    for k, image in enumerate(images):
        write_image(folder / f"f{k}.png", image.astype(np.float32), bits=16)
    return str(folder / "f*.png")


def _import(tmp_path, scene, photo, name="s"):
    frames = _write_frames(tmp_path / f"{name}_frames", scene)
    outline = tmp_path / f"{name}_room.png"
    write_image(outline, photo, bits=8)
    root = tmp_path / name
    assert main(["import", "images", str(root), "--object", frames, "--sphere", frames,
                 "--outline", str(outline)]) == 0
    assert main(["decode", str(root)]) == 0
    return Session.open(root), outline


def _methods(session):
    data = yaml.safe_load(session.path("calibration/lights.yaml").read_text())
    return {s["method"] for s in data["spheres"]}


def _record(session):
    return Session.open(session.root).stage("calibrate")


def test_imported_outline_frame_is_used_and_can_be_declined(tmp_path, scene, capsys):
    session, _ = _import(tmp_path, scene, _discs(scene.shape, scene.circles))
    outline = session.frames("outline")
    assert len(outline) == 1 and outline[0]["light"] is None and outline[0]["source"] == "s_room.png"
    # decoded as it is: nothing subtracted from it, and it is subtracted from nothing
    assert session.stage("decode")["subtracted"]["by_kind"]["sphere"]["frames"] == []
    assert main(["calibrate", str(session.root)]) == 0
    assert "circle found on the outline photo" in capsys.readouterr().out
    assert _methods(session) == {"outline"}
    assert _record(session)["params"]["outline_frames"] == [outline[0]["id"]]
    assert main(["run", str(session.root), "--from", "calibrate", "--to", "calibrate"]) == 0
    assert _methods(session) == {"outline"}
    assert session.path("calibration/overlay_outline.png").is_file()
    assert main(["calibrate", str(session.root), "--no-outline"]) == 0
    assert _methods(session) == {"fit"} and _record(session)["params"]["outline"] is False
    assert not session.path("calibration/overlay_outline.png").exists()
    # psrig run, rerunning the stage, keeps the photo declined (the recorded setting is replayed)
    capsys.readouterr()
    assert main(["run", str(session.root), "--from", "calibrate", "--to", "calibrate"]) == 0
    assert _methods(session) == {"fit"}
    # a circle given by hand wins over the session's photo, without complaint
    c = scene.circles[0]
    assert main(["calibrate", str(session.root), "--circle", f"{c[0]},{c[1]},{c[2]}"]) == 0
    assert _methods(session) == {"given"} and "outline_frames" not in _record(session)["params"]


def test_an_8_bit_outline_frame_gives_the_circle_its_file_gives(tmp_path, scene):
    # the decoded frame is linear; its circle is found on the encoded values, like the file's
    session, photo = _import(tmp_path, scene, _discs(scene.shape, scene.circles, inside=0.5, outside=0.02))
    assert main(["calibrate", str(session.root)]) == 0
    from_session = _record(session)
    images, sat = linear_frames(scene)
    from_file = calibrate_sphere(images, saturation=sat, outline=read_image(photo))
    data = yaml.safe_load(session.path("calibration/lights.yaml").read_text())
    got = sorted((s["cx"], s["cy"], s["r"]) for s in data["spheres"])
    want = sorted((k["cx"], k["cy"], k["r"]) for k in from_file.kinds)
    assert np.allclose(got, want, atol=2e-3), (got, want, from_session["params"])


def test_encode_gamma_inverts_the_decoding_curve():
    codes = np.arange(256) / 255
    for gamma in ("srgb", 2.2):
        assert np.allclose(encode_gamma(inverse_gamma_lut(gamma), gamma), codes, atol=1e-5)


def test_an_outline_photo_from_another_camera_position_is_refused(scene):
    images, sat = linear_frames(scene)
    moved = [(cx + 9, cy, r) for cx, cy, r in scene.circles]
    with pytest.raises(InputError, match=r"outline photo: .* 9\.\d px away; the camera or the sphere moved"):
        calibrate_sphere(images, saturation=sat, outline=_discs(scene.shape, moved))
    # a few pixels, as the limb's reflections move it between lightings, pass
    near = [(cx + 1.5, cy, r) for cx, cy, r in scene.circles]
    calibrate_sphere(images, saturation=sat, outline=_discs(scene.shape, near))


def test_import_outline_needs_sphere_frames_and_their_size(tmp_path, scene, capsys):
    frames = _write_frames(tmp_path / "frames", scene)
    write_image(tmp_path / "room.png", np.zeros((100, 100, 3), np.float32), bits=8)
    assert main(["import", "images", str(tmp_path / "a"), "--object", frames,
                 "--outline", str(tmp_path / "room.png")]) == 1
    assert "give --sphere too" in capsys.readouterr().err
    assert main(["import", "images", str(tmp_path / "b"), "--object", frames, "--sphere", frames,
                 "--outline", str(tmp_path / "room.png")]) == 1
    err = capsys.readouterr().err
    assert "room.png" in err and "100x100" in err
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


def test_calibrate_before_decoding_the_outline_frame_says_so(tmp_path, scene, capsys):
    session, _ = _import(tmp_path, scene, _discs(scene.shape, scene.circles))
    session.linear_path(session.frames("outline")[0]).unlink()
    assert main(["calibrate", str(session.root)]) == 1
    err = capsys.readouterr().err
    assert "outline_000" in err and "psrig decode" in err


def test_a_sphere_wins_over_a_smaller_circle_that_overlaps_it():
    # a bright disc straddling the bottom of the sphere (a stand): a crisp, whole outline, so a
    # larger share of its own circumference supports it than of the partly hidden limb
    big, small = (160.0, 110.0, 80.0), (160.0, 185.0, 30.0)
    image = _discs((240, 320), [big], inside=0.4, outside=0.05)
    image = np.maximum(image, _discs((240, 320), [small], inside=1.0, outside=0.0))
    found = find_spheres(image)
    assert len(found) == 1 and np.abs(found[0].params - big).max() < 0.5, found
