"""One object frame into the normals stack: read, its light's intensities divided out, its channel
mean written into the stack's slice, in one pass over the pixels.

A decoded frame (``linear/<frame>.exr``) is read by :func:`pipeline.core.exrscan.read_exr_planes`
where it can be (psrig's own and other plain scanline EXRs: the channel planes (H, C, W) as
stored, no copy for an uncompressed file), else by OpenImageIO. The division and the mean are
one compiled pass (:func:`scale_into`) that also writes the divided colours when the albedo's
colour needs them: the same float32 arithmetic as ``linear / gain`` then the mean over the
channels, so the stack is the same to the bit whichever way the frame was read (tested).
"""

from typing import NamedTuple

import numpy as np

from ..core.exrscan import read_exr_planes
from ..core.imageio import read_image_native, to_float
from ..core.jit import Compiled, njit

__all__ = ["FramePixels", "read_frame", "scale_into", "channel_mean", "SCALE_KERNEL"]

#: the EXR channel sets read as planes, and where each of the image's channels (R, G, B, A
#: order, as OpenImageIO gives them) lies among the file's alphabetical planes
_ORDERS = {("B", "G", "R"): (2, 1, 0), ("A", "B", "G", "R"): (3, 2, 1, 0), ("Y",): (0,)}


class FramePixels(NamedTuple):
    """A frame's pixels: ``data`` (H, W, C) as stored (``order`` None), or channel planes
    (H, C, W) whose channel ``c`` is ``data[:, order[c]]``."""

    data: np.ndarray
    order: np.ndarray = None

    @property
    def shape(self):
        """(H, W, C) of the image."""
        if self.order is None:
            return self.data.shape
        height, _, width = self.data.shape
        return height, width, len(self.order)

    def pixels(self):
        """(H, W, C) as stored (a copy for planes)."""
        if self.order is None:
            return self.data
        return np.ascontiguousarray(np.moveaxis(self.data[:, self.order], 1, 2))


def read_frame(path):
    """The pixels of image ``path``: EXR planes where :func:`read_exr_planes` reads the file and
    its channels are R, G, B (A) or Y, else OpenImageIO's (H, W, C)."""
    if str(path).lower().endswith(".exr"):
        found = read_exr_planes(path)
        if found is not None and found[1] in _ORDERS:
            return FramePixels(found[0], np.array(_ORDERS[found[1]], np.intp))
    return FramePixels(read_image_native(path))


def channel_mean(pixels, out):
    """``np.mean(pixels, axis=2, out=out)`` for pixels (H, W, C) float32, to the bit, without
    numpy's reduction over a short last axis (an order of magnitude slower than adding the
    channel planes): below 8 channels numpy adds them one after another, as here."""
    count = pixels.shape[2]
    if count >= 8:
        return np.mean(pixels, axis=2, out=out)
    np.copyto(out, pixels[:, :, 0])
    for channel in range(1, count):
        np.add(out, pixels[:, :, channel], out=out)
    return np.divide(out, np.float32(count), out=out)


def _scale_mean_kernel(values, step, order, gain, out, scaled, colour):
    # channel by channel over contiguous rows, so that every inner loop vectorises; the sum is
    # ((c0 + c1) + c2) / C in float32, as numpy's channel mean
    height, width = out.shape
    count = len(order)
    divisor = np.float32(count)
    for y in range(height):
        for c in range(count):
            base, factor = y * step + order[c] * width, gain[c]
            for x in range(width):
                value = values[base + x] / factor
                if colour:
                    scaled[y, c, x] = value
                if c == 0:
                    out[y, x] = value
                else:
                    out[y, x] += value
        for x in range(width):
            out[y, x] = out[y, x] / divisor


def _build():
    kernel = njit(_scale_mean_kernel)
    kernel(np.ones(12, np.float32), 6, np.array([2, 1, 0], np.intp), np.ones(3, np.float32),
           np.empty((2, 2), np.float32), np.empty((2, 3, 2), np.float32), True)
    return kernel


def _rows(planes):
    """Planes (H, C, W) float32 whose rows are contiguous as one flat array over all of them
    (the gaps between rows included) and its step between rows, in values."""
    height, count, width = planes.shape
    if planes.strides[1:] != (width * 4, 4) or planes.strides[0] % 4:
        planes = np.ascontiguousarray(planes)
    step = planes.strides[0] // 4
    return np.lib.stride_tricks.as_strided(planes, ((height - 1) * step + count * width,), (4,)), step


SCALE_KERNEL = Compiled("frame reading kernel", _build)


def scale_into(frame, gain, out, colour=True, planes=None):
    """Divide ``frame`` (:class:`FramePixels`) by ``gain`` (C,) float32 and write the mean over
    its channels into ``out`` (H, W) float32; ``planes`` (H, C, W) float32, optional, receives
    the divided colours on the compiled path (a reading thread's buffer, reused frame after
    frame).

    Returns
    -------
    ndarray (H, W, C) float32 or None
        The divided pixels when ``colour`` (a new array the caller may change; from the
        compiled pass a view of channel planes (H, C, W)), else None.
    """
    gain = np.asarray(gain, np.float32)
    kernel = SCALE_KERNEL.get() if frame.order is not None and len(frame.order) < 8 else None
    if kernel is None:
        scaled = to_float(frame.pixels())
        if not scaled.flags.writeable:
            scaled = scaled.copy()
        np.divide(scaled, gain, out=scaled)
        channel_mean(scaled, out)
        return scaled if colour else None
    height, width, count = frame.shape
    scaled = planes if colour and planes is not None and planes.shape == (height, count, width) else \
        np.empty((height, count, width) if colour else (0, count, 0), np.float32)
    # half floats widen exactly (numba's kernels take no float16)
    values, step = _rows(frame.data.astype(np.float32, copy=False))
    kernel(values, step, frame.order, gain, np.asarray(out), scaled, colour)
    return np.moveaxis(scaled, 1, 2) if colour else None
