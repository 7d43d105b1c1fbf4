"""import images: files checked by content, lights paired by name, intensities, flags, globs."""

import cv2
import numpy as np
import pytest

from pipeline.cli import main
from pipeline.core.errors import InputError
from pipeline.core.imageio import read_mask, write_image, write_mask
from pipeline.importers import import_images, import_notes
from pipeline.core.lightsio import read_lights
from pipeline.core.session import Session


def frames(folder, names, size=(12, 16)):
    folder.mkdir(parents=True, exist_ok=True)
    for i, name in enumerate(names):
        write_image(folder / name, np.full(size + (3,), 0.2 + 0.01 * i, np.float32), bits=16)
    return folder


def lights_of(session):
    return read_lights(session.path("calibration/lights.yaml"))


DIRS = {"a.png": [0, 0, 1], "b.png": [0.6, 0, 0.8], "c.png": [0, 0.6, 0.8]}


def test_lp_lines_pair_with_frames_by_file_name(tmp_path, capsys):
    folder = frames(tmp_path / "obj", ["a.png", "b.png", "c.png"])
    lp = tmp_path / "l.lp"
    lp.write_text("3\n" + "".join(f"{n} {x} {y} {z}\n" for n, (x, y, z) in
                                  [("c.png", DIRS["c.png"]), ("a.png", DIRS["a.png"]), ("B.PNG", DIRS["b.png"])]))
    assert main(["import", "images", str(tmp_path / "s"), "--object", str(folder / "*.png"), "--lights", str(lp)]) == 0
    assert "paired with the frames by the names in l.lp (in another order" in capsys.readouterr().out
    session = Session.open(tmp_path / "s")
    lights = lights_of(session)
    for frame in session.frames("object"):
        np.testing.assert_allclose(lights.directions[frame["light"]], DIRS[frame["source"]], atol=1e-7)


def test_lp_names_that_do_not_pair_are_named_on_both_sides(tmp_path):
    folder = frames(tmp_path / "obj", ["a.png", "b.png", "c.png"])
    lp = tmp_path / "l.lp"
    lp.write_text("3\na.png 0 0 1\nb.png 0.6 0 0.8\nz.png 0 0.6 0.8\n")
    with pytest.raises(InputError, match=r"l\.lp: its names and the object frames do not pair up: lines naming no "
                                         r"object frame: z\.png; object frames without a line: c\.png"):
        import_images(tmp_path / "s", str(folder / "*.png"), lights=lp)
    assert not (tmp_path / "s").exists()


def test_intensities_from_columns_or_a_file_and_lights_behind(tmp_path, capsys):
    folder = frames(tmp_path / "obj", ["a.png", "b.png", "c.png", "d.png"])
    text = tmp_path / "l.txt"
    text.write_text("0 0 1 1 0.9 0.8\n0.6 0 0.8 1 1 1\n0 0.6 0.8 2 2 2\n0.3 0.1 -0.2 1 1 1\n")
    session = import_images(tmp_path / "s1", str(folder / "*.png"), lights=text)
    lights = lights_of(session)
    np.testing.assert_allclose(lights.intensities[0], [1, 0.9, 0.8])
    assert list(lights.flags) == [3] and "z = -0.535 <= 0" in lights.flags[3]
    assert any("1 with z <= 0" in line and "left out of the normals: 3" in line for line in import_notes(session))
    assert any(line == f"intensities: 3 per light from {text.name}" for line in import_notes(session))
    plain = tmp_path / "d.txt"
    plain.write_text("0 0 1\n0.6 0 0.8\n0 0.6 0.8\n0.3 0.1 0.9\n")
    (tmp_path / "i.txt").write_text("1\n2\n3\n4\n")
    session = import_images(tmp_path / "s2", str(folder / "*.png"), lights=plain, intensities=tmp_path / "i.txt")
    np.testing.assert_allclose(lights_of(session).intensities[:, 0], [1, 2, 3, 4])
    with pytest.raises(InputError, match="gives intensities already"):
        import_images(tmp_path / "s3", str(folder / "*.png"), lights=text, intensities=tmp_path / "i.txt")
    session = import_images(tmp_path / "s4", str(folder / "*.png"), lights=plain)
    assert any("none given, all 1" in line for line in import_notes(session))


def test_globs_skip_masks_and_maps_and_say_what_they_matched(tmp_path, capsys):
    folder = frames(tmp_path / "obj", ["ball.1.tga.png", "ball.2.tga.png", "ball.10.tga.png"])
    write_mask(folder / "ball.mask.png", np.ones((12, 16), bool))
    write_image(folder / "ball.albedo.png", np.ones((12, 16, 3), np.float32))
    write_image(folder / "ball_normal.png", np.ones((12, 16, 3), np.float32))
    code = main(["import", "images", str(tmp_path / "s"), "--object", str(folder / "ball*.png")])
    out = capsys.readouterr().out
    assert code == 0
    assert "object: 3 file(s) match" in out and "ball.1.tga.png ... ball.10.tga.png" in out
    assert "skipped 3 named like masks or maps (ball.albedo.png, ball.mask.png, ball_normal.png" in out
    assert Session.open(tmp_path / "s").manifest["rig"]["import"]["groups"]["object"]["skipped"] == [
        "ball.albedo.png", "ball.mask.png", "ball_normal.png"]
    session = import_images(tmp_path / "all", str(folder / "ball*.png"), keep_all=True)
    assert len(session.frames("object")) == 6


def test_a_count_mismatch_lists_the_unexpected_files(tmp_path):
    objects = frames(tmp_path / "obj", [f"obj_{k}.png" for k in range(1, 5)])
    spheres = frames(tmp_path / "sph", [f"sph_{k}.png" for k in (1, 2, 3, 4, 7)])
    with pytest.raises(InputError, match=r"5 frames for 4 object frames; .*unexpected: sph_7\.png"):
        import_images(tmp_path / "s", str(objects / "*.png"), sphere_glob=str(spheres / "*.png"))
    spheres = frames(tmp_path / "sph2", [f"sph_{k}.png" for k in (1, 2, 4)])
    with pytest.raises(InputError, match=r"object frames without one: obj_3\.png"):
        import_images(tmp_path / "s", str(objects / "*.png"), sphere_glob=str(spheres / "*.png"))


def test_an_unquoted_glob_is_told_to_quote_it(tmp_path, capsys):
    # the shell sorts img10 before img2; psrig's natural order would not: a pattern it expanded
    folder = frames(tmp_path / "obj", ["img1.png", "img2.png", "img10.png"])
    code = main(["import", "images", str(tmp_path / "s"), "--object", *(str(p) for p in sorted(folder.iterdir()))])
    err = capsys.readouterr().err
    assert code == 1 and "3 files" in err and "quote it" in err and "Traceback" not in err
    assert "img10.png before" in err
    # the shell's expansion with SESSION last: the same advice, not "SESSION is required"
    code = main(["import", "images", "--object", *(str(p) for p in sorted(folder.iterdir())), str(tmp_path / "s")])
    err = capsys.readouterr().err
    assert code == 1 and "3 files" in err and "quote it" in err


def test_object_takes_an_ordered_list_of_files_and_patterns(tmp_path, capsys):
    folder = frames(tmp_path / "obj", ["c.png", "a.png", "b.png", "x1.png", "x2.png", "x10.png"])
    given = [folder / "c.png", folder / "a.png", folder / "b.png", str(folder / "x*.png")]
    assert main(["import", "images", str(tmp_path / "s"), "--object", *map(str, given)]) == 0
    session = Session.open(tmp_path / "s")
    assert [f["source"] for f in session.frames("object")] == ["c.png", "a.png", "b.png", "x1.png", "x2.png", "x10.png"]
    assert [f["light"] for f in session.frames("object")] == list(range(6))
    code = main(["import", "images", str(tmp_path / "t"), "--object", str(folder / "a.png"), str(folder / "a.png")])
    assert code == 1 and "given twice" in capsys.readouterr().err


def test_session_may_follow_the_quoted_pattern(tmp_path, capsys):
    folder = frames(tmp_path / "obj", ["a.png", "b.png", "c.png"])
    assert main(["import", "images", "--object", str(folder / "*.png"), str(tmp_path / "s")]) == 0
    assert len(Session.open(tmp_path / "s").frames("object")) == 3
    capsys.readouterr()
    # several patterns: each expanded, in the order given (SESSION first here)
    assert main(["import", "images", str(tmp_path / "t"), "--object", str(folder / "b*"), str(folder / "a*")]) == 0
    assert [f["source"] for f in Session.open(tmp_path / "t").frames("object")] == ["b.png", "a.png"]
    assert main(["import", "images", "--object", str(folder / "*.png")]) == 1
    assert "give the SESSION folder" in capsys.readouterr().err


def test_files_that_cannot_be_decoded_are_refused_by_name(tmp_path):
    folder = frames(tmp_path / "obj", ["a.png", "b.png"])
    (folder / "c.png").write_bytes(b"this is no image")
    (folder / "d.cr2").write_bytes(b"nor a raw")
    with pytest.raises(InputError, match=r"2 file\(s\) cannot be decoded: .*c\.png, .*d\.cr2; readable are .*TGA.*DNG"):
        import_images(tmp_path / "s", str(folder / "*"))
    assert not (tmp_path / "s").exists()


def test_tga_and_bmp_frames_import_and_decode(tmp_path):
    from pipeline.decode import decode_session

    folder = tmp_path / "obj"
    folder.mkdir()
    for k in range(3):
        cv2.imwrite(str(folder / f"f{k}.bmp"), np.full((12, 16, 3), 60 * (k + 1), np.uint8))
    write_image(folder / "f3.tga", np.full((12, 16, 3), 0.5, np.float32))
    session = import_images(tmp_path / "s", str(folder / "f*"))
    record = decode_session(session, jobs=1, progress=False)
    assert record["status"] == "ok" and len(record["frames"]) == 4
    assert {info["format"] for info in record["frames"].values()} == {"bmp", "targa"}


def test_a_sphere_mask_is_stored_for_the_calibrate_stage(tmp_path):
    folder = frames(tmp_path / "obj", ["a.png", "b.png", "c.png"])
    mask = np.zeros((12, 16), bool)
    mask[3:9, 4:10] = True
    write_mask(tmp_path / "sphere.png", mask)
    session = import_images(tmp_path / "s", str(folder / "*.png"), sphere_glob=str(folder / "*.png"),
                            sphere_mask=tmp_path / "sphere.png")
    assert session.manifest["lights"]["sphere_mask"] == "calibration/sphere_mask.png"
    assert (read_mask(session.path("calibration/sphere_mask.png")) == mask).all()
