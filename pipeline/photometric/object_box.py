"""The normals stack cropped to the object's box, and the result put back in the whole frame.

A capture frames more than its object: the DiLiGenT-like sphere of the 4 MP benchmark covers
47 % of the frame and its box 60 %. Once the object mask is known the in-memory stage moves
each frame's box to the front of the stack (in place), gives the rest of the stack's memory back
(:func:`pipeline.core.mapped.release_tail`) and solves, checks and predicts on the box; the
maps go back into the whole frame (:func:`uncrop_result`) only for writing, when the stack is
gone. Every step after the read sees the same pixels in the same raster order, with at least
:data:`BOX_MARGIN` pixels of the frame around the object, so the outputs are those of the whole
frame to the bit (tested).
"""

import dataclasses

import numpy as np

from ..core.mapped import release_tail
from .flags import PackedFlags

__all__ = ["BOX_MARGIN", "BOX_MIN_SAVING", "object_box", "crop_stack", "uncrop_result"]

#: pixels of the frame kept around the object: more than any step's reach beyond it (the
#: registration's dilation of 8, the uncertainty's halo of 6, the neighbours' vote of 6)
BOX_MARGIN = 32
#: the stack is cropped when the box leaves out at least this share of the frame
BOX_MIN_SAVING = 0.1
#: the maps whose pixels without a normal hold NaN (the others hold zeros)
_NAN_MAPS = ("leverage", "uncertainty")
_MAPS = ("normals", "status", "albedo", "params", "residual", "used", "lit", "leverage", "uncertainty")


def object_box(mask, margin=None, min_saving=None):
    """(rows, cols) slices of the mask's (H, W) bounding box widened by ``margin`` (default
    :data:`BOX_MARGIN`) within the frame, or None when it would leave out less than
    ``min_saving`` (default :data:`BOX_MIN_SAVING`) of the frame."""
    margin = BOX_MARGIN if margin is None else margin
    min_saving = BOX_MIN_SAVING if min_saving is None else min_saving
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    if rows.size == 0:
        return None
    height, width = mask.shape
    r0, r1 = max(rows[0] - margin, 0), min(rows[-1] + 1 + margin, height)
    c0, c1 = max(cols[0] - margin, 0), min(cols[-1] + 1 + margin, width)
    if (r1 - r0) * (c1 - c0) > (1.0 - min_saving) * height * width:
        return None
    return slice(int(r0), int(r1)), slice(int(c0), int(c1))


def crop_stack(images, valid, box):
    """The stack ``images`` (K, H, W) and its flags ``valid`` cropped to ``box``.

    The frames' boxes are moved to the front of ``images`` in place (a frame's box never lands
    beyond its own start, so no frame is overwritten before it is moved) and the memory past
    them given back when ``images`` is an :func:`pipeline.core.mapped.anonymous_array`;
    ``images`` must not be used afterwards. Returns the cropped stack (K, h, w), a view of the
    same memory, and the cropped flags as :class:`PackedFlags`.
    """
    rows, cols = box
    count = len(images)
    height, width = rows.stop - rows.start, cols.stop - cols.start
    cropped = images.reshape(-1)[:count * height * width].reshape(count, height, width)
    flags = PackedFlags.filled(count, (height, width))
    for index in range(count):
        np.copyto(cropped[index], images[index, rows, cols])   # overlapping: numpy buffers it
        flags[index] = valid[index][rows, cols]
    release_tail(images, cropped.nbytes)
    return cropped, flags


def uncrop_result(result, box, mask):
    """``result`` (a :class:`pipeline.photometric.PhotometricResult` of the box) in the whole
    frame of ``mask`` (H, W): zeros around the box, NaN in the maps that hold NaN where there
    is no normal."""
    whole = {}
    for name in _MAPS:
        part = getattr(result, name)
        if part is None:
            continue
        fill = np.nan if name in _NAN_MAPS else 0
        whole[name] = np.full(mask.shape + part.shape[2:], fill, part.dtype)
        whole[name][box] = part
    return dataclasses.replace(result, mask=mask, **whole)
