"""Importers: DiLiGenT folders and loose image files -> sessions; bad input leaves nothing."""

from pathlib import Path

import numpy as np
import pytest

from pipeline.cli import main
from pipeline.core.errors import InputError, SessionError
from pipeline.core.imageio import read_image, read_mask, write_image, write_mask
from pipeline.importers import import_diligent, import_images, natural_key
from pipeline.core.lightsio import read_lights, read_lp
from pipeline.core.session import Session

from tests import SHARED_DATA

DATA = SHARED_DATA
BALL = DATA / "diligent" / "ballPNG"


@pytest.mark.skipif(not BALL.is_dir(), reason="shared DiLiGenT data missing")
def test_import_diligent_ball(tmp_path):
    from pipeline.importers import read_diligent

    obj = read_diligent(BALL)
    session = import_diligent(BALL, tmp_path / "ball")
    frames = session.frames("object")
    assert len(frames) == len(obj.files) == 96
    assert [f["light"] for f in frames] == list(range(96))
    assert frames[10]["source"] == obj.files[10].name
    assert session.path(frames[10]["file"]).read_bytes() == obj.files[10].read_bytes()
    lights = read_lights(session.path("calibration/lights.yaml"))
    np.testing.assert_allclose(lights.directions, obj.directions / np.linalg.norm(obj.directions, axis=1)[:, None], atol=1e-7)
    np.testing.assert_allclose(lights.intensities, obj.intensities, rtol=1e-7)
    assert "DiLiGenT" in lights.source
    names, lp_dirs = read_lp(session.path("calibration/lights.lp"))
    assert names[0] == Path(frames[0]["file"]).name
    np.testing.assert_allclose(lp_dirs, lights.directions, atol=1e-5)
    reopened = Session.open(session.root)
    assert reopened.manifest["lights"]["object_mask"] == "calibration/object_mask.png"
    assert (read_mask(reopened.path("calibration/object_mask.png")) == obj.mask).all()
    truth = read_image(reopened.truth("normals"))
    np.testing.assert_allclose(truth[obj.mask], obj.normals_gt[obj.mask], atol=1e-6)
    assert (read_mask(reopened.truth("mask")) == obj.mask).all()
    assert reopened.truth("lights").is_file()


def write_frames(folder, names, size=(12, 16), value=0.25):
    folder.mkdir(parents=True, exist_ok=True)
    for i, name in enumerate(names):
        write_image(folder / name, np.full(size + (3,), value + 0.01 * i, np.float32))


def test_import_images_natural_order_lights_mask_spheres(tmp_path):
    names = [f"img{i}.png" for i in (10, 2, 1, 3, 11, 4, 5, 6, 7, 8, 9, 12)]
    write_frames(tmp_path / "obj", names)
    write_frames(tmp_path / "sph", [f"s{i}.png" for i in range(1, 13)])
    dirs = np.random.default_rng(0).normal(size=(12, 3)) + [0, 0, 3]
    (tmp_path / "l.txt").write_text("".join(f"{x} {y} {z}\n" for x, y, z in dirs))
    mask = np.zeros((12, 16), bool)
    mask[2:9, 3:12] = True
    write_mask(tmp_path / "mask.png", mask)
    session = import_images(tmp_path / "s", str(tmp_path / "obj" / "img*.png"),
                            sphere_glob=str(tmp_path / "sph" / "*.png"),
                            mask=tmp_path / "mask.png", lights=tmp_path / "l.txt")
    objects = session.frames("object")
    assert [f["source"] for f in objects] == [f"img{i}.png" for i in range(1, 13)]
    assert [f["light"] for f in session.frames("sphere")] == list(range(12))
    np.testing.assert_allclose(read_lights(session.path("calibration/lights.yaml")).directions,
                               dirs / np.linalg.norm(dirs, axis=1)[:, None], atol=1e-7)
    assert (read_mask(session.path("calibration/object_mask.png")) == mask).all()
    assert sorted(["a10", "a9", "a1"], key=natural_key) == ["a1", "a9", "a10"]


def test_import_images_lp_file_via_cli(tmp_path, capsys):
    write_frames(tmp_path / "obj", ["a.png", "b.png", "c.png"])
    (tmp_path / "l.lp").write_text("3\na.png 0 0 1\nb.png 0.5 0 0.8\nc.png 0 0.5 0.8\n")
    code = main(["import", "images", str(tmp_path / "s"), "--object", str(tmp_path / "obj" / "*.png"),
                 "--lights", str(tmp_path / "l.lp")])
    assert code == 0 and "3 object frames" in capsys.readouterr().out
    lights = read_lights(Session.open(tmp_path / "s").path("calibration/lights.yaml"))
    assert lights.directions[1] == pytest.approx(np.array([0.5, 0, 0.8]) / np.hypot(0.5, 0.8))


def test_import_images_errors_leave_nothing(tmp_path, capsys):
    write_frames(tmp_path / "obj", ["a1.png", "a2.png", "a3.png"])
    write_image(tmp_path / "obj" / "a4.png", np.zeros((10, 16, 3), np.float32))
    dest = tmp_path / "s"
    with pytest.raises(InputError, match=r"a4\.png: image is 16x10"):
        import_images(dest, str(tmp_path / "obj" / "a*.png"))
    # a sphere frame of another size names the object frame it is compared with, and says
    # how to calibrate sphere photos cropped apart from the object's
    with pytest.raises(InputError, match=r"a4\.png: image is 16x10 but .*a1\.png is .*session of their own.*"
                                         r"psrig calibrate SESSION --from CAL"):
        import_images(dest, str(tmp_path / "obj" / "a[123].png"), sphere_glob=str(tmp_path / "obj" / "a4.png"))
    with pytest.raises(InputError, match=r"--object .*nothing\*\.png.*no files match"):
        import_images(dest, str(tmp_path / "nothing*.png"))
    (tmp_path / "l.txt").write_text("2\n0 0 1\n0 1 1\n")
    with pytest.raises(InputError, match=r"l\.txt: 2 lights but 3 object frames"):
        import_images(dest, str(tmp_path / "obj" / "a[123].png"), lights=tmp_path / "l.txt")
    assert not dest.exists()
    (tmp_path / "busy").mkdir()
    (tmp_path / "busy" / "keep.txt").write_text("mine")
    with pytest.raises(SessionError, match="not an empty folder"):
        import_images(tmp_path / "busy", str(tmp_path / "obj" / "a[123].png"))
    assert (tmp_path / "busy" / "keep.txt").read_text() == "mine"
    assert main(["import", "images", str(dest), "--object", str(tmp_path / "none*.png")]) == 1
    err = capsys.readouterr().err
    assert "none*.png" in err and "Traceback" not in err


def test_import_diligent_bad_folder(tmp_path):
    (tmp_path / "fake").mkdir()
    with pytest.raises(InputError, match="filenames.txt"):
        import_diligent(tmp_path / "fake", tmp_path / "s")
    assert not (tmp_path / "s").exists()


def test_diligent_load_images_returns_decode_saturation(tmp_path):
    # the Python loader must see what psrig decode sees: observations at the 16-bit maximum (any
    # channel) are saturated, and the values are decode's linear ones over the intensities
    from pipeline.decode.image import decode_image
    from pipeline.importers import read_diligent

    folder = tmp_path / "toyPNG"
    folder.mkdir()
    rng = np.random.default_rng(0)
    names = []
    for i in range(4):
        pixels = rng.integers(1000, 60000, (6, 5, 3), dtype=np.uint16)
        if i == 2:
            pixels[3, 1, 0] = 65535
        names.append(f"{i:03d}.png")
        write_image(folder / names[-1], pixels)
    (folder / "filenames.txt").write_text("\n".join(names) + "\n")
    np.savetxt(folder / "light_directions.txt", [[0, 0, 1], [0.5, 0, 0.87], [0, 0.5, 0.87], [-0.5, 0, 0.87]])
    np.savetxt(folder / "light_intensities.txt", [[1, 1, 1], [2, 2, 2], [0.5, 1, 2], [1, 1, 1]])
    write_mask(folder / "mask.png", np.ones((6, 5), bool))
    obj = read_diligent(folder)
    images, valid = obj.load_images()
    assert images.shape == valid.shape == (4, 6, 5)
    assert np.argwhere(~valid).tolist() == [[2, 3, 1]]
    rgb, _, _ = decode_image(folder / names[2])
    np.testing.assert_allclose(images[2], (rgb / np.float32([0.5, 1, 2])).mean(axis=2), rtol=1e-6)
    colour, colour_valid = obj.load_images(grey=False)
    assert colour.shape == (4, 6, 5, 3) and (colour_valid == valid).all()
