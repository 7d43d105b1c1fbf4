"""The scanline EXR reader gives OpenImageIO's pixels to the bit for the files it reads, leaves the
others to OpenImageIO, and names a damaged file."""

import numpy as np
import OpenImageIO as oiio
import pytest

from pipeline.core.errors import ImageFileError
from pipeline.core.exrscan import READER_KERNELS, _unpredict_py, read_exr_planes, unpredict
from pipeline.core.imageio import read_image_native, write_image
from pipeline.decode.exr import ExrBuffer, encode_exr
from pipeline.photometric.frame_read import SCALE_KERNEL, channel_mean, read_frame, scale_into

NAMES = {1: ("Y",), 3: ("R", "G", "B"), 4: ("R", "G", "B", "A")}


def pixels(channels=3, height=37, width=29, seed=0):
    """Smooth values with noise (compressible, not constant), a few exact zeros and large values."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[:height, :width]
    base = (np.sin(xx / 5.0) * np.cos(yy / 7.0) + 1.2)[..., None] * np.linspace(0.5, 1.5, channels)
    out = (base + rng.normal(0, 0.01, base.shape)).astype(np.float32)
    out[0, :3] = 0.0
    out[5, 5] = 3.0e4
    return out


def planes_as_pixels(found):
    planes, names = found
    order = [names.index(name) for name in NAMES[len(names)]]
    return np.moveaxis(planes[:, order], 1, 2)


@pytest.mark.parametrize("compression", ["none", "zip", "zips"])
@pytest.mark.parametrize("channels", [1, 3, 4])
def test_openimageio_files_read_to_the_bit(tmp_path, compression, channels):
    path = tmp_path / "f.exr"
    write_image(path, pixels(channels), compression=compression)
    found = read_exr_planes(path)
    assert found is not None and found[0].shape == (37, channels, 29)
    assert np.array_equal(planes_as_pixels(found).view(np.uint32), read_image_native(path).view(np.uint32))


@pytest.mark.parametrize("compression", ["none", "zip"])
@pytest.mark.parametrize("half", [False, True])
def test_psrig_decode_files_read_to_the_bit(tmp_path, compression, half):
    path = tmp_path / "f.exr"
    values = pixels(height=53)   # 53 rows: the last ZIP block is short
    exr = ExrBuffer(53, 29, ("R", "G", "B"))
    exr.fill(values, ("R", "G", "B"))
    data, _ = encode_exr(exr, compression, half=half)
    path.write_bytes(bytes(data))
    found = read_exr_planes(path)
    expected = read_image_native(path)
    assert found[0].dtype == expected.dtype == (np.float16 if half else np.float32)
    assert np.array_equal(planes_as_pixels(found), expected)


def test_other_kinds_are_left_to_openimageio(tmp_path):
    values = pixels()
    write_image(tmp_path / "piz.exr", values, compression="piz")
    spec = oiio.ImageSpec(29, 37, 3, oiio.FLOAT)
    spec.tile_width = spec.tile_height = 16
    out = oiio.ImageOutput.create(str(tmp_path / "tiled.exr"))
    out.open(str(tmp_path / "tiled.exr"), spec)
    out.write_image(values)
    out.close()
    (tmp_path / "not.exr").write_bytes(b"not an image at all")
    for name in ("piz.exr", "tiled.exr", "not.exr"):
        assert read_exr_planes(tmp_path / name) is None, name
    # read_frame falls back to OpenImageIO for them
    assert np.array_equal(read_frame(tmp_path / "piz.exr").pixels(), values)


def test_a_damaged_file_is_named(tmp_path):
    path = tmp_path / "f.exr"
    smooth = np.repeat(np.linspace(0, 1, 29, dtype=np.float32)[None, :, None], 80, axis=0).repeat(3, axis=2)
    write_image(path, smooth, compression="zip")   # every block deflated
    data = path.read_bytes()
    path.write_bytes(data[:len(data) - 300])
    with pytest.raises(ImageFileError, match="f.exr: truncated or corrupt"):
        read_exr_planes(path)
    damaged = bytearray(data)
    damaged[-60:-40] = bytes(20)
    path.write_bytes(bytes(damaged))
    with pytest.raises(ImageFileError, match="f.exr: corrupt ZIP block"):
        read_exr_planes(path)


def test_compiled_and_numpy_predictor_agree():
    rng = np.random.default_rng(2)
    for size in (1, 2, 7, 1000):
        data = rng.integers(0, 256, size, dtype=np.uint8)
        expected, got = np.empty_like(data), np.empty_like(data)
        _unpredict_py(data, expected)
        unpredict(data, got)
        assert np.array_equal(got, expected)
    assert READER_KERNELS.enabled() == (READER_KERNELS.get() is not None)


@pytest.mark.parametrize("channels", [1, 3, 4])
def test_frame_scaling_is_the_numpy_arithmetic_to_the_bit(tmp_path, channels):
    path = tmp_path / "f.exr"
    values = pixels(channels, seed=channels)
    write_image(path, values, compression="zip")
    gain = np.linspace(0.7, 1.3, channels).astype(np.float32)
    expected_scaled = values / gain
    expected = np.empty((37, 29), np.float32)
    channel_mean(expected_scaled, expected)
    frame = read_frame(path)
    assert frame.order is not None   # the planes' path
    out = np.empty((37, 29), np.float32)
    scaled = scale_into(frame, gain, out, colour=True)
    assert np.array_equal(out.view(np.uint32), expected.view(np.uint32))
    assert np.array_equal(scaled, expected_scaled)
    assert scale_into(frame, gain, out, colour=False) is None
    assert SCALE_KERNEL.get() is not None


def test_without_the_compiler_the_frame_is_the_same(tmp_path, monkeypatch):
    from pipeline.core.jit import ENV_NO_JIT

    path = tmp_path / "f.exr"
    write_image(path, pixels(seed=5), compression="none")
    gain = np.array([0.9, 1.0, 1.1], np.float32)
    frame = read_frame(path)
    compiled, plain = np.empty((37, 29), np.float32), np.empty((37, 29), np.float32)
    scaled = np.array(scale_into(frame, gain, compiled))
    monkeypatch.setenv(ENV_NO_JIT, "1")
    assert SCALE_KERNEL.get() is None and READER_KERNELS.get() is None
    assert np.array_equal(np.array(scale_into(read_frame(path), gain, plain)), scaled)
    assert np.array_equal(plain.view(np.uint32), compiled.view(np.uint32))
