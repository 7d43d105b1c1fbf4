"""The normals at the object's outline checked against the outline: a light file whose x or y
axis points the other way.

A light file in another convention than psrig's camera frame (x right, y up, z toward the
camera), say image rows for y (y down), gives normals that fit the images just as well, only
mirrored: nothing in the fit can tell. The mask can: at the outline of an object seen whole,
the surface turns away from the camera and its normal points out of the mask. Where the
estimated normals point *into* the mask along one axis nearly everywhere on the outline, the
lights' axis is the other way round. Measured (DiLiGenT ball, cat, reading): with their own
lights, 95-100 % of the outline pixels agree in x and in y; with y (or x) negated, 0-5 %.

A light file whose x and y are exchanged (x down the image's columns, y along its rows: a
transposed array) fits the images as well too, with the normals' x and y exchanged. Its direct
shares say nothing (0.30-0.71), but the outline agrees with the normals' x and y exchanged:
0.95-1.00 on both axes on ball, cat and reading, against 0.30-0.67 with the right lights
(:func:`transposed_axes`).

An object whose outline is not its silhouette (a crop of a larger surface, a relief filling the
mask) has no such cue; :func:`outline_check` then finds no clear agreement either way, and
nothing is said. Vectorised over pixels; a few milliseconds on a megapixel mask.
"""

import numpy as np
from scipy import ndimage

__all__ = ["outline_check", "mirrored_axes", "transposed_axes", "OUTLINE_BAND", "MIN_SIDE_PIXELS", "MIRRORED_SHARE", "SEEN_WHOLE"]

#: outline pixels: those within this many pixels of the mask's edge (not of the image's)
OUTLINE_BAND = 3
#: an axis is judged only with this many outline pixels facing each way along it (both edges)
MIN_SIDE_PIXELS = 20
#: an axis is mirrored when at most this share of its outline pixels agree (a seen-whole object:
#: 95-100 %; mirrored lights: 0-5 %)
MIRRORED_SHARE = 0.2
#: what the outline agreement was on objects seen whole (DiLiGenT ball, cat, reading; the simulated rig)
SEEN_WHOLE = "95-100 %"


def outline_check(normals, mask, band=OUTLINE_BAND, min_side=MIN_SIDE_PIXELS):
    """How often the normals at the outline point out of the mask, per axis.

    Parameters
    ----------
    normals : ndarray (H, W, 3)
        Unit normals, camera frame (x right, y up); zero where there is none.
    mask : ndarray (H, W) bool
        The object's pixels.

    Returns
    -------
    dict
        ``{"x": share or None, "y": share or None, "pixels": n}``: for each axis the share of
        the outline pixels, among those whose outward direction and normal both lean clearly
        along it (|component| > 0.5 and > 0.2), where the two agree in sign; None when fewer
        than ``min_side`` such pixels face either way (one edge of the image, a thin mask).
        And ``swapped``: the same shares with the normals' x and y exchanged (when any is known).
    """
    mask = np.asarray(mask, bool)
    if min(mask.shape) < 2 * band + 1:   # no outline to speak of (and no gradient on 1 x 1)
        return {"pixels": 0, "x": None, "y": None}
    ring = mask & ~ndimage.binary_erosion(mask, iterations=band, border_value=1)
    # out of the mask: down the slope of the blurred mask; rows run down, the camera's y up
    rows, cols = np.gradient(ndimage.gaussian_filter(mask.astype(np.float32), 2.0))
    outward = np.stack([-cols[ring], rows[ring]], axis=1)
    outward /= np.maximum(np.linalg.norm(outward, axis=1, keepdims=True), 1e-12)
    estimated = np.asarray(normals)[ring][:, :2]
    found = {"pixels": int(ring.sum()), **_shares(outward, estimated, min_side)}
    # the normals' x and y exchanged: a light file whose x and y are (a transposed image's)
    swapped = _shares(outward, estimated[:, ::-1], min_side)
    if any(v is not None for v in swapped.values()):
        found["swapped"] = swapped
    return found


def _shares(outward, estimated, min_side):
    """{axis: the share of the clear outline pixels whose normal leans out along it, or None}."""
    found = {}
    for axis, name in enumerate("xy"):
        out, normal = outward[:, axis], estimated[:, axis]
        clear = (np.abs(out) > 0.5) & (np.abs(normal) > 0.2)
        sides = min(np.sum(clear & (out > 0)), np.sum(clear & (out < 0)))
        agree = np.mean(np.sign(out[clear]) == np.sign(normal[clear])) if sides >= min_side else None
        found[name] = None if agree is None else round(float(agree), 3)
    return found


def _decided(share, limit):
    return share is not None and (share <= limit or share >= 1 - limit)


def mirrored_axes(check, share=MIRRORED_SHARE):
    """The axes ('x', 'y') whose outline agreement in ``check`` is at most ``share``."""
    if transposed_axes(check, share) is not None:   # then the direct shares mean nothing
        return []
    return [axis for axis in "xy" if (check or {}).get(axis) is not None and check[axis] <= share]


def transposed_axes(check, share=MIRRORED_SHARE):
    """None, or when the outline agrees with the normals only with their x and y exchanged (each
    exchanged share decided, at most ``share`` or at least 1 - ``share``, and the direct ones
    not both decided), the axes (list) still mirrored after the exchange."""
    check = check or {}
    swapped = check.get("swapped") or {}
    if not all(_decided(swapped.get(axis), share) for axis in "xy"):
        return None
    if all(_decided(check.get(axis), share) for axis in "xy"):
        return None
    return [axis for axis in "xy" if swapped[axis] <= share]
