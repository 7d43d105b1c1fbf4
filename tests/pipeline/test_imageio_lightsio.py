import numpy as np
import pytest

from pipeline.core.errors import ImageFileError, InputError
from pipeline.core.imageio import (image_size, read_image, read_image_native, read_mask, read_normal_png,
                              write_image, write_mask, write_normal_png)
from pipeline.core.lightsio import LightSet, read_lights, read_lights_yaml, read_lp, write_lights_yaml, write_lp


@pytest.mark.parametrize("name, bits, tol", [("a.exr", None, 0), ("a.png", 16, 1 / 65535), ("a.tif", 16, 1 / 65535),
                                              ("a.png", 8, 1 / 255), ("a.tga", 8, 1 / 255)])
def test_round_trip(tmp_path, name, bits, tol):
    pixels = np.random.default_rng(0).random((7, 9, 3)).astype(np.float32)
    write_image(tmp_path / name, pixels, bits=bits)
    back = read_image(tmp_path / name)
    assert back.shape == (7, 9, 3) and back.dtype == np.float32
    assert np.abs(back - pixels).max() <= tol / 2 + 1e-7
    assert image_size(tmp_path / name) == (7, 9, 3)


def test_native_types_and_jpg(tmp_path):
    write_image(tmp_path / "a.png", np.full((4, 4), 1000, np.uint16))
    assert read_image_native(tmp_path / "a.png").dtype == np.uint16
    write_image(tmp_path / "b.jpg", np.full((16, 16, 3), 0.5, np.float32))
    assert abs(read_image(tmp_path / "b.jpg").mean() - 0.5) < 0.01


def test_many_channel_exr(tmp_path):
    params = np.random.default_rng(1).random((5, 6, 9)).astype(np.float32)
    from pipeline.photometric.stage import PAPER_NAMES
    write_image(tmp_path / "brdf.exr", params, channel_names=PAPER_NAMES)
    np.testing.assert_array_equal(read_image(tmp_path / "brdf.exr"), params)
    many = np.random.default_rng(2).random((3, 4, 12)).astype(np.float32)
    write_image(tmp_path / "many.exr", many)
    np.testing.assert_array_equal(read_image(tmp_path / "many.exr"), many)


def test_normals_png_in_diligent_encoding(tmp_path):
    n = np.random.default_rng(2).normal(size=(6, 8, 3))
    n[..., 2] = np.abs(n[..., 2]) + 0.2
    n /= np.linalg.norm(n, axis=2, keepdims=True)
    mask = np.ones((6, 8), bool)
    mask[0, 0] = False
    write_normal_png(tmp_path / "n.png", n, mask)
    raw = read_image_native(tmp_path / "n.png")
    assert raw.dtype == np.uint16 and (raw[0, 0] == 0).all()
    np.testing.assert_array_equal(raw[1, 1], np.rint((n[1, 1] + 1) / 2 * 65535).astype(np.uint16))
    back, back_mask = read_normal_png(tmp_path / "n.png")
    np.testing.assert_array_equal(back_mask, mask)
    # float32 rounding near cos = 1 limits arccos to about 0.02 degrees
    assert np.degrees(np.arccos(np.clip((back[mask] * n[mask]).sum(1), -1, 1))).max() < 0.05


def test_mask_round_trip(tmp_path):
    mask = np.random.default_rng(3).random((5, 5)) > 0.5
    write_mask(tmp_path / "m.png", mask)
    np.testing.assert_array_equal(read_mask(tmp_path / "m.png"), mask)


def test_bad_image_files(tmp_path):
    with pytest.raises(ImageFileError, match="missing.png"):
        read_image(tmp_path / "missing.png")
    (tmp_path / "junk.png").write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    with pytest.raises(ImageFileError, match="junk.png"):
        read_image(tmp_path / "junk.png")
    with pytest.raises(ImageFileError, match="extension"):
        write_image(tmp_path / "a.xyz", np.zeros((2, 2)))


def test_light_text_formats(tmp_path):
    dirs = np.array([[0, 0, 1], [0.5, 0, 0.8], [0, 0.5, 0.8], [-0.4, -0.4, 0.8]])
    unit = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    (tmp_path / "plain.txt").write_text("\n".join(" ".join(map(str, d)) for d in dirs))
    (tmp_path / "counted.txt").write_text("4\n" + "\n".join(" ".join(map(str, d)) for d in dirs))
    (tmp_path / "columns.txt").write_text("\n".join(" ".join(map(str, row)) for row in dirs.T))
    for name in ("plain.txt", "counted.txt", "columns.txt"):
        np.testing.assert_allclose(read_lights(tmp_path / name).directions, unit, atol=1e-12)
    (tmp_path / "wrong.txt").write_text("5\n0 0 1\n")
    with pytest.raises(InputError, match="count line says 5"):
        read_lights(tmp_path / "wrong.txt")
    (tmp_path / "zero.txt").write_text("0 0 1\n0 0 0\n1 0 1\n")
    with pytest.raises(InputError, match="light 1 has a zero direction"):
        read_lights(tmp_path / "zero.txt")


def test_lp_and_yaml_round_trip(tmp_path):
    dirs = np.array([[0, 0, 1], [0.6, 0, 0.8], [0, 0.6, 0.8]])
    write_lp(tmp_path / "l.lp", ["a.jpg", "b.jpg", "c.jpg"], dirs)
    names, back = read_lp(tmp_path / "l.lp")
    assert names == ["a.jpg", "b.jpg", "c.jpg"]
    np.testing.assert_allclose(back, dirs, atol=1e-6)
    lights = LightSet(dirs, intensities=np.ones((3, 3)) * [1, 2, 3], flags={1: "no highlight"}, source="test",
                      extra={"method": "sphere"})
    write_lights_yaml(tmp_path / "lights.yaml", lights)
    again = read_lights_yaml(tmp_path / "lights.yaml")
    np.testing.assert_allclose(again.directions, dirs, atol=1e-8)
    assert again.flags == {1: "no highlight"} and again.extra["method"] == "sphere"
    (tmp_path / "bad.yaml").write_text("intensities: [[1]]\n")
    with pytest.raises(InputError, match="missing key 'directions'"):
        read_lights_yaml(tmp_path / "bad.yaml")


def test_identical_pixels_give_identical_bytes(tmp_path):
    import time
    pixels = np.random.default_rng(4).random((6, 6, 3)).astype(np.float32)
    for name in ("a.exr", "a.png", "a.tif"):
        write_image(tmp_path / name, pixels)
        first = (tmp_path / name).read_bytes()
        time.sleep(1.1)
        write_image(tmp_path / name, pixels)
        assert (tmp_path / name).read_bytes() == first, name
