"""Saturation flags held as bits (PackedFlags) read like the bool stack they replace, and give the
same normals."""

import numpy as np
import pytest

from pipeline.photometric import estimate_normals
from pipeline.photometric.flags import PackedFlags, flag_columns
from tests.pipeline.tiny_session import lights, sphere


@pytest.fixture
def stack():
    # 7 x 11 pixels: a frame's bits do not fill its last byte
    return np.random.default_rng(3).random((5, 7, 11)) > 0.3


def packed(stack):
    flags = PackedFlags.filled(len(stack), stack.shape[1:], value=False)
    for index, frame in enumerate(stack):
        flags[index] = frame
    return flags


def test_packed_flags_read_like_the_bool_stack(stack):
    flags = packed(stack)
    assert flags.shape == stack.shape and len(flags) == 5 and flags.nbytes == 5 * 10
    assert np.array_equal(np.asarray(flags), stack)
    for key in (2, -1, np.int64(3)):
        assert np.array_equal(flags[key], stack[key])
    for key in (slice(1, 4), slice(None, None, 2), np.array([4, 0, 2]), np.array([1, 0, 1, 1, 0], bool)):
        assert isinstance(flags[key], PackedFlags) and np.array_equal(np.asarray(flags[key]), stack[key])
    for key in ((slice(None), slice(1, 6, 2), slice(0, 11, 3)), (2, slice(None), slice(4, 9)),
                (np.array([3, 1]), 4, slice(None))):
        assert np.array_equal(flags[key], stack[key])
    idx = np.array([0, 7, 8, 76, 40, 40])
    assert np.array_equal(flags.columns(idx), stack.reshape(5, -1)[:, idx])
    assert np.array_equal(flag_columns(flags, idx), flag_columns(stack.reshape(5, -1), idx))


def test_packed_flags_take_frames_as_numpy_does(stack):
    flags, expected = packed(stack), stack.copy()
    flags[0] = flags[4]
    expected[0] = expected[4]
    flags[1:3] = packed(stack[3:5])
    expected[1:3] = stack[3:5]
    flags[np.array([4, 3])] = ~stack[:2]
    expected[np.array([4, 3])] = ~stack[:2]
    assert np.array_equal(np.asarray(flags), expected)
    view = flags[1:3]
    view[0] = np.zeros((7, 11), bool)   # a slice is a view, as numpy's
    assert not flags[1].any()
    with pytest.raises(ValueError, match="frames of"):
        flags[0] = np.zeros((7, 12), bool)
    with pytest.raises(TypeError, match="whole frames"):
        flags[0, 1] = False


def test_normals_from_packed_flags_are_those_from_the_bool_stack():
    normals, mask = sphere(32)
    dirs = lights(10)
    rng = np.random.default_rng(0)
    images = np.stack([np.clip(normals @ light, 0, None) * 0.9 * mask for light in dirs]).astype(np.float32)
    images += rng.normal(0, 0.003, images.shape).astype(np.float32) * mask
    valid = (images < 0.8) | (rng.random(images.shape) > 0.5)
    assert (~valid[:, mask]).any()
    expected = estimate_normals(images, dirs, mask, valid=valid)
    got = estimate_normals(images, dirs, mask, valid=packed(valid))
    for name in ("normals", "status", "used", "lit", "albedo", "uncertainty"):
        assert np.array_equal(getattr(got, name), getattr(expected, name), equal_nan=name == "uncertainty"), name
