"""A raw header's claimed size is checked against the file and the machine before decoding."""

import struct

import numpy as np
import pytest
import tifffile

from pipeline.cli import main
from pipeline.decode import raw as decode_raw_module
from pipeline.decode.frame import frame_size
from pipeline.dng import write_dng
from pipeline.errors import ImageFileError
from pipeline.session import Session


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
    monkeypatch.setattr(decode_raw_module, "_memory", lambda: 64 * 96 * 20)
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
