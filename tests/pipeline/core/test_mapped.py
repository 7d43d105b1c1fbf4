"""A mapped .npy file whose pages the process gives back (pipeline.core.mapped)."""

import sys

import numpy as np
import pytest

from pipeline.core.mapped import MappedNpy, create_npy

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc/self/status")


def resident_file_bytes():
    with open("/proc/self/status") as status:
        for line in status:
            if line.startswith("RssFile:"):
                return int(line.split()[1]) * 1024
    raise AssertionError("no RssFile in /proc/self/status")


def test_written_pages_leave_the_process_and_stay_in_the_file(tmp_path):
    path = tmp_path / "stack.npy"
    shape = (8, 1024, 1024)   # 32 MB of float32
    create_npy(path, shape, np.float32)
    expected = np.arange(np.prod(shape), dtype=np.float32).reshape(shape)
    with MappedNpy(path, write=True) as mapped:
        before = resident_file_bytes()
        mapped.array[:] = expected
        touched = resident_file_bytes()
        mapped.release()
        released = resident_file_bytes()
    assert touched - before > 24 << 20
    assert touched - released > 24 << 20
    assert np.array_equal(np.load(path), expected)


def test_a_read_only_map_cannot_be_written(tmp_path):
    path = tmp_path / "valid.npy"
    np.save(path, np.ones((3, 4), bool))
    with MappedNpy(path) as mapped:
        assert mapped.array.shape == (3, 4) and mapped.array.all()
        with pytest.raises(ValueError):
            mapped.array[0, 0] = False


def test_frame_by_frame_reads_what_the_array_holds(tmp_path):
    from pipeline.core.mapped import FrameByFrame

    path = tmp_path / "stack.npy"
    stack = np.random.default_rng(1).random((5, 12, 9)).astype(np.float32)
    np.save(path, stack)
    frames = FrameByFrame(path)
    assert frames.shape == stack.shape and len(frames) == 5 and frames.dtype == np.float32
    window = (slice(None), slice(2, 11, 3), slice(1, None, 2))
    assert np.array_equal(frames[window], stack[window])
    flat = FrameByFrame(path, flat=True)
    idx = np.array([0, 7, 50, 107])
    assert flat.shape == (5, 108) and np.array_equal(flat[:, idx], stack.reshape(5, -1)[:, idx])
    with pytest.raises(IndexError):
        frames[1:3]
