"""A raw header's claimed size is checked against the file and the machine before decoding."""

import struct

import numpy as np
import pytest
import tifffile

from pipeline.cli import main
from pipeline.decode import raw as decode_raw_module
from pipeline.decode.frame import frame_size
from pipeline.core.dng import write_dng
from pipeline.core.errors import ImageFileError
from pipeline.core.session import Session


def lying_dng(width, height, shape=(64, 96)):
    """A valid small DNG whose header then claims ``width`` x ``height`` photosites."""
    data = bytearray(write_dng(np.full(shape, 2000, np.uint16)))
    with tifffile.TiffFile(__import__("io").BytesIO(bytes(data))) as tif:
        tags = tif.pages[0].tags
        for code, value in ((256, width), (257, height), (278, height)):
            struct.pack_into("<I", data, tags[code].valueoffset, value)
    return bytes(data)


def test_a_header_claiming_more_than_the_file_holds_is_refused_before_decoding(tmp_path, capsys):
    session = Session.create(tmp_path / "s")
    session.add_frame("object", write_dng(np.full((64, 96), 2000, np.uint16)), light=0)
    session.add_frame("object", lying_dng(6000, 6000), light=1)
    assert main(["decode", str(session.root), "--jobs", "1"]) == 1
    err = capsys.readouterr().err
    assert "raw/object_001.dng: the header claims 6000 x 6000 photosites, more than" in err, err
    assert "Traceback" not in err
    record = Session.open(session.root).stage("decode")
    assert record["status"] == "partial" and list(record["failed"]) == ["object_001"]
    assert (session.root / "linear" / "object_000.exr").is_file()


def test_a_frame_too_big_for_this_machine_is_refused_with_the_numbers(tmp_path, monkeypatch):
    path = tmp_path / "frame.dng"
    path.write_bytes(write_dng(np.full((64, 96), 2000, np.uint16)))
    assert frame_size(path) == (64, 96)
    monkeypatch.setattr(decode_raw_module, "physical_memory", lambda: 64 * 96 * 20)
    with pytest.raises(ImageFileError, match=r"frame.dng: a 96 x 64 raw frame needs about .* GiB to decode"):
        frame_size(path)


def test_a_session_of_lying_headers_fails_each_frame_by_name(tmp_path, capsys):
    session = Session.create(tmp_path / "s")
    for light in range(2):
        session.add_frame("object", lying_dng(6000, 6000), light=light)
    assert main(["decode", str(session.root), "--jobs", "1"]) == 1
    err = capsys.readouterr().err
    for light in range(2):
        assert f"raw/object_00{light}.dng: the header claims 6000 x 6000" in err, err
    assert not list((session.root / "linear").iterdir())


def zero_png(width, height, rows_per_block=100):
    """A valid 8-bit grey PNG of zeros (``width`` x ``height``), under 1 MB for 30000 x 30000:
    one deflate block of ``rows_per_block`` rows, compressed once and repeated (each ends with a
    full flush, so the copies are independent)."""
    import zlib

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    assert height % rows_per_block == 0
    z = zlib.compressobj(9, zlib.DEFLATED, -15)
    block = z.compress(bytes((width + 1) * rows_per_block)) + z.flush(zlib.Z_FULL_FLUSH)
    adler = ((((width + 1) * height) % 65521) << 16) | 1   # adler32 of zeros: a = 1, b = their count
    stream = b"\x78\x01" + block * (height // rows_per_block) + b"\x03\x00" + struct.pack(">I", adler)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0))
            + chunk(b"IDAT", stream) + chunk(b"IEND", b""))


def test_a_huge_image_frame_is_refused_at_import_by_name_and_size(tmp_path, capsys):
    src = tmp_path / "src"
    src.mkdir()
    (src / "img1.png").write_bytes(zero_png(300, 200))
    (src / "img2.png").write_bytes(zero_png(30000, 30000))
    assert (src / "img2.png").stat().st_size < 1_000_000
    assert main(["import", "images", str(tmp_path / "s"), "--object", str(src / "img*.png")]) == 1
    err = capsys.readouterr().err
    assert err.strip().count("\n") == 0 and "Traceback" not in err, err
    assert (f"{src / 'img2.png'}: a 30000 x 30000 image (900.0 MP) is more than the 400 MP psrig decodes "
            "as a frame") in err, err
    assert not (tmp_path / "s").exists()


def test_a_huge_image_frame_is_refused_at_decode_before_reading_a_pixel(tmp_path, capsys):
    session = Session.create(tmp_path / "s")
    session.add_frame("object", zero_png(300, 200), light=0, suffix=".png")
    session.add_frame("object", zero_png(30000, 30000), light=1, suffix=".png")
    assert main(["decode", str(session.root), "--jobs", "1"]) == 1
    err = capsys.readouterr().err
    assert "raw/object_001.png: a 30000 x 30000 image (900.0 MP) is more than the 400 MP" in err, err
    assert "Traceback" not in err
    record = Session.open(session.root).stage("decode")
    assert record["status"] == "partial" and list(record["failed"]) == ["object_001"]


def test_an_image_frame_too_big_for_this_machine_is_refused_with_the_numbers(tmp_path, monkeypatch):
    path = tmp_path / "frame.png"
    path.write_bytes(zero_png(300, 200))
    assert frame_size(path) == (200, 300)
    monkeypatch.setattr(decode_raw_module, "physical_memory", lambda: 300 * 200 * 20)
    path.write_bytes(zero_png(300, 200, rows_per_block=50))   # another file: not the cached answer
    with pytest.raises(ImageFileError, match=r"frame.png: a 300 x 200 image \(0.1 MP\) needs about .* GiB to "
                                             r"decode, more than half of this machine's"):
        frame_size(path)
