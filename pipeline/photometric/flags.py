"""Per-observation flags (K, H, W) bool held eight to a byte: the saturation flags of a stack.

In memory, the normals stage's stack is K x H x W float32 and its usable-observation flags as
numpy bools one byte more per observation: a quarter of the stack again (0.37 GB at 4 MP x 96
lights). :class:`PackedFlags` holds them as bits (an eighth of that) and gives each reader what
it reads: a frame, the rows of frames (packed still), every frame's flags at some pixels, or a
window of every frame, each as plain bools. :func:`pipeline.photometric.estimate_normals` and
the stage's checks take it where they take a bool stack.

>>> flags = PackedFlags.filled(2, (2, 3))
>>> flags[1] = np.array([[True, False, True], [False, False, True]])
>>> flags.columns(np.array([0, 5]))
array([[ True,  True],
       [ True,  True]])
>>> flags[1].astype(int).tolist()
[[1, 0, 1], [0, 0, 1]]
"""

import numpy as np

__all__ = ["PackedFlags", "flag_columns"]


class PackedFlags:
    """(K, H, W) bool flags stored as bits, frame by frame (``bits`` (K, ceil(H W / 8)) uint8,
    :func:`numpy.packbits` order).

    Indexing the first axis alone (an int, a slice, an index array or a bool mask over frames)
    reads like a bool stack: an int gives the frame (H, W) bool, the others a ``PackedFlags``
    of those frames (a view for a slice, as numpy); assigning to it takes bools or another
    ``PackedFlags`` of the same frame size. A key with pixel axes (a window such as ``[:, ::4,
    ::4]``) gives bools, unpacked one frame at a time. ``np.asarray(flags)`` unpacks the whole
    stack.
    """

    ndim = 3
    dtype = np.dtype(bool)

    def __init__(self, bits, frame_shape):
        self.bits = bits
        self.frame_shape = tuple(int(n) for n in frame_shape)
        self._pixels = self.frame_shape[0] * self.frame_shape[1]
        if bits.ndim != 2 or bits.shape[1] != -(-self._pixels // 8):
            raise ValueError(f"bits {bits.shape} do not hold frames of {self.frame_shape}")

    @classmethod
    def filled(cls, count, frame_shape, value=True):
        """``count`` frames of ``frame_shape`` (H, W), every flag ``value``."""
        width = -(-int(frame_shape[0]) * int(frame_shape[1]) // 8)
        return cls(np.full((int(count), width), 0xFF if value else 0, np.uint8), frame_shape)

    @property
    def shape(self):
        return (self.bits.shape[0],) + self.frame_shape

    @property
    def nbytes(self):
        return self.bits.nbytes

    def __len__(self):
        return self.bits.shape[0]

    def frame(self, index):
        """Frame ``index``'s flags (H, W) bool (a new array)."""
        return np.unpackbits(self.bits[index], count=self._pixels).view(bool).reshape(self.frame_shape)

    def columns(self, idx):
        """Every frame's flags at flat pixel indices ``idx`` (N,): (K, N) bool."""
        idx = np.asarray(idx, np.intp)
        shift = (7 - (idx & 7)).astype(np.uint8)
        return ((self.bits[:, idx >> 3] >> shift) & 1).view(bool)

    def _pack(self, frame):
        frame = np.asarray(frame, bool)
        if frame.shape != self.frame_shape:
            raise ValueError(f"flags of {frame.shape} for frames of {self.frame_shape}")
        return np.packbits(frame.ravel())

    def __getitem__(self, key):
        frames, pixels = (key[0], key[1:]) if isinstance(key, tuple) else (key, ())
        if pixels:
            chosen = np.arange(len(self))[frames]
            if np.ndim(chosen) == 0:
                return self.frame(int(chosen))[pixels]
            first = self.frame(0)[pixels] if len(chosen) else np.zeros((0, 0), bool)
            out = np.empty((len(chosen),) + first.shape, bool)
            for slot, index in enumerate(chosen):
                out[slot] = self.frame(index)[pixels]
            return out
        if isinstance(frames, (int, np.integer)):
            return self.frame(frames)
        return PackedFlags(self.bits[frames], self.frame_shape)

    def __setitem__(self, key, value):
        if isinstance(key, tuple):
            raise TypeError("packed flags are assigned whole frames (flags[k] = frame)")
        if isinstance(value, PackedFlags):
            if value.frame_shape != self.frame_shape:
                raise ValueError(f"flags of frames {value.frame_shape} for frames of {self.frame_shape}")
            self.bits[key] = value.bits
        elif isinstance(key, (int, np.integer)):
            self.bits[key] = self._pack(value)
        else:
            value = np.asarray(value, bool)
            chosen = np.arange(len(self))[key]
            for slot, index in enumerate(chosen):
                self.bits[index] = self._pack(value[slot] if value.ndim == 3 else value)

    def __array__(self, dtype=None, copy=None):
        out = np.unpackbits(self.bits, axis=1, count=self._pixels).view(bool).reshape(self.shape)
        return out if dtype is None else out.astype(dtype, copy=False)


def flag_columns(flags, idx):
    """Every frame's flags at flat pixel indices ``idx`` (N,): (K, N) bool, from a flat bool
    stack (K, P) or a :class:`PackedFlags`."""
    return flags.columns(idx) if isinstance(flags, PackedFlags) else flags[:, idx]
