"""pipeline.core.dng: DNGs written here must open in rawpy with the values we wrote."""

import io

import numpy as np
import pytest
import rawpy

from pipeline.core.dng import CFA_ORDERS, cfa_indices, write_dng, write_dng_file
from pipeline.core.errors import InputError

# rawpy colour indices: 0 R, 1 G, 2 B, 3 second G
_LETTERS = {0: "R", 1: "G", 2: "B", 3: "G"}


def _open(data):
    return rawpy.imread(io.BytesIO(data))


@pytest.mark.parametrize("cfa", CFA_ORDERS)
def test_round_trip_mosaic_pattern_and_levels(cfa):
    rng = np.random.default_rng(1)
    mosaic = rng.integers(0, 16384, size=(30, 46), dtype=np.uint16)
    blacks = (500, 511, 522, 533)
    with _open(write_dng(mosaic, cfa=cfa, black_level=blacks, white_level=16000)) as raw:
        assert np.array_equal(raw.raw_image_visible, mosaic)
        pattern = raw.raw_pattern
        assert "".join(_LETTERS[int(c)] for c in pattern.ravel()) == cfa
        per_channel = raw.black_level_per_channel
        # each CFA cell's black level lands on the rawpy colour index of that cell
        for cell, level in zip(pattern.ravel(), blacks):
            assert per_channel[int(cell)] == level
        assert raw.white_level == 16000


def test_scalar_black_level_and_defaults():
    mosaic = np.full((24, 24), 700, dtype=np.uint16)
    with _open(write_dng(mosaic)) as raw:
        assert list(raw.black_level_per_channel) == [512] * 4
        assert raw.white_level == 16383
        assert np.allclose(raw.camera_whitebalance[:3], 1.0)


def test_write_dng_file_is_atomic_and_readable(tmp_path):
    mosaic = np.arange(24 * 30, dtype=np.uint16).reshape(24, 30)
    path = tmp_path / "frame.dng"
    write_dng_file(path, mosaic, cfa="GBRG", black_level=64, white_level=4095)
    assert [p.name for p in tmp_path.iterdir()] == ["frame.dng"]
    with rawpy.imread(str(path)) as raw:
        assert np.array_equal(raw.raw_image_visible, mosaic)
        assert raw.white_level == 4095


def test_cfa_indices():
    assert cfa_indices("bggr").tolist() == [[2, 1], [1, 0]]


@pytest.mark.parametrize("kwargs, word", [
    ({"cfa": "RGBX"}, "cfa"),
    ({"black_level": (1, 2, 3)}, "black_level"),
    ({"black_level": 20000}, "black_level"),
    ({"white_level": 70000}, "white_level"),
])
def test_bad_arguments_name_the_key(kwargs, word):
    with pytest.raises(InputError, match=word):
        write_dng(np.zeros((24, 24), np.uint16), **kwargs)


def test_too_small_or_wrong_type_mosaic():
    with pytest.raises(InputError, match="mosaic"):
        write_dng(np.zeros((8, 8), np.uint16))
    with pytest.raises(InputError, match="mosaic"):
        write_dng(np.full((24, 24), -1, np.int32))
