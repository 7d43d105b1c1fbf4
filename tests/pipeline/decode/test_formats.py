"""Decoding by content: every image OpenImageIO reads, every raw layout LibRaw reads, and the
transfer function of integer files (declared, assumed or given) recorded and said."""

import struct
import zlib

import cv2
import numpy as np
import OpenImageIO as oiio
import pytest

from pipeline.cli import main
from pipeline.decode import decode_frame, decode_session, frame_format
from pipeline.core.dng import XTRANS, write_dng_file, write_linear_dng
from pipeline.core.errors import ImageFileError
from pipeline.core.gamma import encode_gamma, inverse_gamma_lut
from pipeline.core.session import Session

WHITE, BLACK = 16383, 512


def write_oiio(path, pixels, **attributes):
    """Write ``pixels`` (H, W, C) uint8/uint16 with OpenImageIO, setting spec attributes."""
    spec = oiio.ImageSpec(pixels.shape[1], pixels.shape[0], pixels.shape[2],
                          oiio.UINT8 if pixels.dtype == np.uint8 else oiio.UINT16)
    for key, value in attributes.items():
        spec.attribute(key, value)
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec) and out.write_image(np.ascontiguousarray(pixels))
    out.close()


def png_with_chunks(path, pixels, chunks):
    """A PNG (OpenCV, no colour chunks) with ``chunks`` [(type, data)] put after IHDR."""
    data = cv2.imencode(".png", pixels)[1].tobytes()
    end_ihdr = 8 + 8 + 13 + 4
    extra = b"".join(struct.pack(">I", len(body)) + kind + body
                     + struct.pack(">I", zlib.crc32(kind + body) & 0xFFFFFFFF) for kind, body in chunks)
    path.write_bytes(data[:end_ihdr] + extra + data[end_ihdr:])


def icc_with_gamma(gamma):
    """A minimal ICC profile whose rTRC is a 'curv' with one gamma entry."""
    curve = b"curv" + b"\0" * 4 + struct.pack(">IH", 1, int(round(gamma * 256))) + b"\0\0"
    desc = b"desc" + b"\0" * 4 + struct.pack(">I", 5) + b"test\0"
    table_start = 128 + 4 + 2 * 12
    tags = struct.pack(">I", 2) + struct.pack(">4sII", b"rTRC", table_start, len(curve)) \
        + struct.pack(">4sII", b"desc", table_start + len(curve), len(desc))
    body = tags + curve + desc
    header = struct.pack(">I", 128 + len(body)) + b"\0" * 124
    return header + body


CODES = np.arange(256, dtype=np.uint8).reshape(16, 16, 1).repeat(3, axis=2)


@pytest.mark.parametrize("suffix", [".tga", ".bmp", ".png", ".raw"])
def test_image_formats_decode_by_content(tmp_path, suffix):
    # a TGA stored as .raw, a BMP as .png: the content decides, not the name
    kind = {".tga": ".tga", ".bmp": ".bmp", ".png": ".bmp", ".raw": ".tga"}[suffix]
    encoded = tmp_path / f"frame{kind}"
    write_oiio(encoded, CODES) if kind == ".tga" else cv2.imwrite(str(encoded), CODES)
    path = tmp_path / f"named{suffix}"
    path.write_bytes(encoded.read_bytes())
    assert frame_format(path).kind == "image"
    linear, saturated, info = decode_frame(path)
    assert info["raw"] is False and info["format"] == {".tga": "targa", ".bmp": "bmp"}[kind]
    assert info["transfer"] == "srgb" and "assumed" in info["transfer_from"]
    np.testing.assert_allclose(linear[:, :, 0].ravel(), inverse_gamma_lut("srgb"), atol=1e-7)
    assert saturated.sum() == 1   # code 255


def test_a_file_neither_reads_is_refused_listing_the_formats(tmp_path):
    path = tmp_path / "frame.png"
    path.write_bytes(b"not an image at all" * 10)
    with pytest.raises(ImageFileError, match=r"frame\.png: neither an image nor a camera raw.*BMP.*TGA.*DNG"):
        frame_format(path)


def ramp(height=48, width=66, channels=3):
    y, x = np.mgrid[0:height, 0:width] / np.array([height, width])[:, None, None]
    planes = [0.05 + 0.9 * x, 0.05 + 0.9 * (0.7 * y + 0.3 * x), 0.05 + 0.8 * (1 - x)][:channels]
    return np.stack(planes, axis=2)


def to_dn(scene):
    return np.clip(np.rint(BLACK + scene * (WHITE - BLACK)), 0, WHITE).astype(np.uint16)


@pytest.mark.parametrize("layout", ["linear", "monochrome", "x-trans"])
def test_other_raw_layouts_decode_linearly_through_libraw(tmp_path, layout):
    path = tmp_path / "frame.dng"
    if layout == "linear":
        scene = ramp()
        path.write_bytes(write_linear_dng(to_dn(scene)))
    elif layout == "monochrome":
        scene = ramp(channels=1)
        path.write_bytes(write_linear_dng(to_dn(scene[:, :, 0])))
    else:
        scene = ramp()
        colours = np.tile(np.array(XTRANS), (8, 11))[:48, :66]
        mosaic = np.take_along_axis(scene, colours[:, :, None], axis=2)[:, :, 0]
        write_dng_file(path, to_dn(mosaic), cfa=XTRANS, black_level=BLACK)
    assert frame_format(path).kind == "raw"
    linear, saturated, info = decode_frame(path)   # the default (mosaic) method is for Bayer
    assert info["sensor"] == layout and info["decoded_by"] == "postprocess"
    assert linear.shape == (48, 66, 3) and not saturated.any()
    inner = (slice(3, -3), slice(3, -3))
    for channel in range(3):
        truth = scene[inner + (min(channel, scene.shape[2] - 1),)]
        slope, intercept = np.polyfit(truth.ravel(), linear[inner + (channel,)].ravel(), 1)
        # LibRaw's 16-bit output: 1 / 65535 steps; X-Trans interpolation is linear but not
        # centred on every pixel, so a ramp is off by up to half a photosite's step
        assert abs(slope - 1) < (0.02 if layout == "x-trans" else 2e-3), (channel, slope)
        assert abs(intercept) < (0.01 if layout == "x-trans" else 1e-3), (channel, intercept)
    half, _, _ = decode_frame(path, binning=2)
    assert half.shape == (24, 33, 3)


def test_saturation_of_a_linear_dng_is_judged_on_its_raw_values(tmp_path):
    values = to_dn(np.full((30, 40, 3), 0.5))
    values[4, 5, 1] = WHITE
    path = tmp_path / "frame.dng"
    path.write_bytes(write_linear_dng(values))
    _, saturated, _ = decode_frame(path)
    assert saturated.sum() == 1 and saturated[4, 5]


@pytest.mark.parametrize("chunks, expected, source", [
    ([], "srgb", "assumed"),
    ([(b"sRGB", b"\0")], "srgb", "sRGB chunk"),
    ([(b"gAMA", struct.pack(">I", 100000))], "linear", "gAMA"),
    ([(b"gAMA", struct.pack(">I", 45455))], 2.2, "gAMA"),
    ([(b"iCCP", b"test\0\0" + zlib.compress(icc_with_gamma(1.8)))], 1.8, "ICC profile"),
    ([(b"cICP", bytes((1, 8, 0, 1)))], "linear", "cICP"),
])
def test_8bit_png_transfer_comes_from_its_metadata(tmp_path, chunks, expected, source):
    path = tmp_path / "frame.png"
    png_with_chunks(path, CODES, chunks)
    linear, _, info = decode_frame(path)
    assert info["transfer"] == (expected if isinstance(expected, str) else pytest.approx(expected, abs=0.01))
    assert source in info["transfer_from"]
    np.testing.assert_allclose(linear[:, :, 0].ravel(), inverse_gamma_lut(expected), atol=2e-3)


def test_16bit_files_are_linear_unless_they_say_otherwise_and_gamma_overrides(tmp_path):
    values = (np.arange(256 * 3, dtype=np.uint16).reshape(16, 16, 3) * 80)
    plain, marked = tmp_path / "plain.png", tmp_path / "srgb.png"
    png_with_chunks(plain, values, [])
    png_with_chunks(marked, values, [(b"sRGB", b"\0")])
    linear, _, info = decode_frame(plain)
    assert info["transfer"] == "linear" and "16-bit" in info["transfer_from"]
    np.testing.assert_array_equal(linear, values.astype(np.float32)[:, :, ::-1] * np.float32(1 / 65535))
    linear, _, info = decode_frame(marked)
    assert info["transfer"] == "srgb" and "sRGB chunk" in info["transfer_from"]
    np.testing.assert_allclose(linear, inverse_gamma_lut("srgb", 65536)[values[:, :, ::-1]], atol=1e-7)
    linear, _, info = decode_frame(marked, gamma="linear")
    assert info["transfer"] == "linear" and info["transfer_from"] == "--gamma"


def test_tga_gamma_field_and_bmp_colour_space_are_read(tmp_path):
    tga = tmp_path / "frame.tga"
    write_oiio(tga, CODES, **{"oiio:Gamma": 1.0})
    assert decode_frame(tga)[2]["transfer"] == "linear"
    bmp = tmp_path / "frame.bmp"
    cv2.imwrite(str(bmp), CODES)
    data = bytearray(bmp.read_bytes())
    # rewrite the 40-byte header as a 108-byte V4 header declaring LCS_CALIBRATED_RGB, gamma 1.0
    header = bytearray(data[14:54]) + bytearray(68)
    header[0:4] = struct.pack("<I", 108)
    header[56:60] = b"\0\0\0\0"
    header[96:108] = struct.pack("<III", 65536, 65536, 65536)
    offset = struct.unpack("<I", data[10:14])[0] + 68
    body = data[:10] + struct.pack("<I", offset) + header + data[54:]
    body[2:6] = struct.pack("<I", len(body))
    bmp.write_bytes(bytes(body))
    linear, _, info = decode_frame(bmp)
    assert info["transfer"] == "linear" and "BMP" in info["transfer_from"]
    np.testing.assert_allclose(linear[:, :, 0].ravel(), np.arange(256) / 255, atol=1e-6)


def test_session_records_and_says_the_transfer_it_assumed(tmp_path, capsys):
    session = Session.create(tmp_path / "s")
    for k in range(3):
        path = tmp_path / f"f{k}.bmp"
        cv2.imwrite(str(path), np.clip(encode_gamma(np.full((24, 30, 3), 0.1 * (k + 1)), "srgb") * 255,
                                       0, 255).astype(np.uint8))
        session.add_frame("object", source=path, light=k)
    assert main(["decode", str(session.root), "--jobs", "1"]) == 0
    out = capsys.readouterr().out
    assert "3 frame(s) (8-bit BMP) decoded as sRGB (assumed: 8-bit file without colour metadata)" in out
    assert "--gamma" in out
    record = Session.open(session.root).stage("decode")
    assert list(record["transfer"].values()) == [["object_000", "object_001", "object_002"]]
    assert main(["decode", str(session.root), "--jobs", "1", "--gamma", "linear"]) == 0
    out = capsys.readouterr().out
    assert "decoded as linear (--gamma)" in out and "if that is wrong" not in out


def test_postprocessed_layouts_are_recorded_and_said(tmp_path, capsys):
    session = Session.create(tmp_path / "s")
    for k in range(2):
        session.add_frame("object", write_linear_dng(to_dn(ramp() * (0.5 + 0.2 * k))), light=k)
    record = decode_session(session, jobs=1, progress=False)
    assert record["status"] == "ok" and record["postprocessed"] == {"linear": ["object_000", "object_001"]}
    assert main(["decode", str(session.root), "--force", "--jobs", "1"]) == 0
    assert "2 raw frame(s) from a linear sensor decoded by LibRaw's linear postprocess" in capsys.readouterr().out


def test_jpeg_exif_colour_space_is_read(tmp_path):
    path = tmp_path / "frame.jpg"
    write_oiio(path, CODES, **{"Exif:ColorSpace": 1})
    info = decode_frame(path)[2]
    assert info["format"] == "jpeg" and info["transfer"] == "srgb" and "Exif" in info["transfer_from"]


def test_psrig_run_takes_gamma_and_says_what_was_assumed(tmp_path, capsys):
    session = Session.create(tmp_path / "s")
    for k in range(2):
        path = tmp_path / f"f{k}.png"
        png_with_chunks(path, CODES, [])
        session.add_frame("object", source=path, light=k)
    assert main(["run", str(session.root), "--to", "decode"]) == 0
    out = capsys.readouterr().out
    assert "decoded as sRGB (assumed: 8-bit file without colour metadata)" in out and "--gamma" in out
    assert main(["run", str(session.root), "--to", "decode", "--gamma", "linear"]) == 0
    assert "decoded as linear (--gamma)" in capsys.readouterr().out
    assert main(["run", str(session.root), "--to", "decode"]) == 0   # the choice is kept
    assert "decode: up to date" in capsys.readouterr().out
    assert Session.open(session.root).stage("decode")["params"]["gamma"] == "linear"
