"""A ``.npy`` file mapped into memory whose pages the process can give back while it works.

A memory-mapped array's pages count in the process's resident set once touched, and stay
there until the mapping closes, though the kernel can drop them (they are the file's page
cache). Writing a stack of frames a frame at a time through one mapping would therefore show
the whole stack as the writer's memory by the last frame. :class:`MappedNpy` maps the file
itself (:mod:`mmap`) so that :meth:`MappedNpy.release` can hand the touched pages back to the
page cache (``MADV_DONTNEED``: for a shared file mapping the data stays in the file's pages
and is read back on the next touch; nothing written is lost).
"""

import mmap

import numpy as np

__all__ = ["MappedNpy", "FrameByFrame", "create_npy", "anonymous_array", "release_tail"]


def anonymous_array(shape, dtype):
    """A new array (uninitialised; zeros until written) in an anonymous private mapping of its
    own, so that :func:`release_tail` can give the memory of its unused end back."""
    size = int(np.prod(shape, dtype=np.int64)) * np.dtype(dtype).itemsize
    flags = getattr(mmap, "MAP_PRIVATE", 0) | getattr(mmap, "MAP_ANONYMOUS", 0)
    buffer = mmap.mmap(-1, max(size, 1), flags=flags) if flags else mmap.mmap(-1, max(size, 1))
    if hasattr(mmap, "MADV_HUGEPAGE"):
        # as numpy asks for its own large arrays: a 1.5 GB stack first written in 4 KB pages
        # spent about 3 s of CPU in page faults
        buffer.madvise(mmap.MADV_HUGEPAGE)
    return np.ndarray(tuple(shape), dtype, buffer=buffer)


def release_tail(array, keep):
    """Give the memory of ``array``'s mapping beyond its first ``keep`` bytes back to the system
    (an :func:`anonymous_array` or a view of one; the pages read as zeros afterwards). Returns
    the bytes given back (0 where the platform cannot)."""
    buffer = array
    while buffer is not None and not isinstance(buffer, mmap.mmap):
        buffer = getattr(buffer, "base", None) if isinstance(buffer, np.ndarray) else getattr(buffer, "obj", None)
    if buffer is None or not hasattr(mmap, "MADV_DONTNEED"):
        return 0
    start = -(-int(keep) // mmap.PAGESIZE) * mmap.PAGESIZE
    if start >= len(buffer):
        return 0
    buffer.madvise(mmap.MADV_DONTNEED, start, len(buffer) - start)
    return len(buffer) - start


def create_npy(path, shape, dtype):
    """Create ``path``, a ``.npy`` file of ``shape`` and ``dtype`` (sparse: no page written)."""
    array = np.lib.format.open_memmap(path, mode="w+", dtype=dtype, shape=tuple(shape))
    del array


class MappedNpy:
    """``with MappedNpy(path, write=False) as mapped:`` ``mapped.array`` is the file's array
    (C order), read-only unless ``write``; ``mapped.release()`` drops its pages from this
    process's memory; leaving the block flushes (when written) and unmaps."""

    def __init__(self, path, write=False):
        self.path, self.write = str(path), write
        self.array, self._map = None, None

    def __enter__(self):
        with open(self.path, "r+b" if self.write else "rb") as f:
            major, _ = np.lib.format.read_magic(f)
            read_header = np.lib.format.read_array_header_1_0 if major == 1 else np.lib.format.read_array_header_2_0
            shape, fortran, dtype = read_header(f)
            if fortran:
                raise ValueError(f"{self.path}: a Fortran-ordered array cannot be mapped here")
            offset = f.tell()
            self._map = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_WRITE if self.write else mmap.ACCESS_READ)
        self.array = np.ndarray(shape, dtype, buffer=self._map, offset=offset)
        if not self.write:
            self.array.flags.writeable = False
        return self

    def release(self):
        """Drop the mapping's resident pages from this process: written pages stay in the file's
        page cache, marked for writing back, so nothing needs flushing first."""
        if hasattr(mmap, "MADV_DONTNEED"):   # not on every platform: there the pages stay mapped
            self._map.madvise(mmap.MADV_DONTNEED)

    def __exit__(self, *exc):
        self.array = None
        if self.write:
            self._map.flush()
        try:
            self._map.close()
        except BufferError:   # a view of the array outlives the block: the map closes with it
            pass
        return False


class FrameByFrame:
    """A stack (K, ...) in a ``.npy`` file, read a frame at a time: ``stack[:, ...]`` (every
    frame, any index of the rest) is gathered frame by frame, each frame's pages given back
    after it. A sample spread over the image (a grid, a random set of pixels) touches most pages
    of every frame, and the kernel maps the pages around each touched one too: read through one
    plain mapping, it would show most of the stack as this process's memory at once.

    ``flat`` views each frame as one row of pixels, (K, H x W), as pixel indices address it.
    """

    def __init__(self, path, flat=False):
        self.path, self.flat = str(path), flat
        with MappedNpy(path) as mapped:
            self.dtype = mapped.array.dtype
            shape = mapped.array.shape
        self.shape = (shape[0], int(np.prod(shape[1:]))) if flat else tuple(shape)
        self.ndim = len(self.shape)

    def __len__(self):
        return self.shape[0]

    def __getitem__(self, key):
        key = key if isinstance(key, tuple) else (key,)
        if key[0] != slice(None):
            raise IndexError("every frame is read here: the first index must be ':'")
        rest = key[1:]
        with MappedNpy(self.path) as mapped:
            frames = mapped.array.reshape(self.shape)
            first = np.asarray(frames[0][rest])
            out = np.empty((self.shape[0],) + first.shape, self.dtype)
            out[0] = first
            mapped.release()
            for k in range(1, self.shape[0]):
                out[k] = frames[k][rest]
                mapped.release()
        return out
