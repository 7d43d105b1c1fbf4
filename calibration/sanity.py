"""Refusals of sphere outlines a user gave that cannot be a sphere's.

A mask or circle given by hand is trusted to limit the highlight search, so a wrong one gives
wrong lights without any other trace. Three checks, each refusing with its figure:

* a mask blob that is not a disc (an object's mask given as the sphere's): its boundary's RMS
  distance from the best circle above :data:`MASK_RMS` of the radius (at least
  :data:`MASK_RMS_PX`), or the disc of that circle covering under :data:`MASK_IOU` of the
  union with the blob;
* a given circle that the frames' own outline contradicts: the light frames show a credible
  limb more than 2 % of the radius (at least 3 px) away;
* a highlight outside the given outline: in some frame the highlight blob found over the disc
  and a margin of :data:`HIGHLIGHT_MARGIN` radii around it has its centre and most of its light
  outside the disc, beyond a rim of 3 % of the radius (at least 2 px).

The bounds sit between what rasterised discs and ellipses of axes 1 : 1.1 give and what object
masks and 1 : 1.2 ellipses give (docs/calibration.md).
"""

import numpy as np
from scipy import ndimage

from pipeline.core.errors import InputError

from .circle import SphereNotFound, credible, refine_circle

__all__ = ["check_mask_disc", "check_given_circle", "check_highlights_inside", "MASK_RMS", "MASK_RMS_PX",
           "MASK_IOU", "HIGHLIGHT_MARGIN"]

MASK_RMS, MASK_RMS_PX = 0.04, 2.0
MASK_IOU = 0.9
HIGHLIGHT_MARGIN = 0.3
_GIVEN_SHIFT, _GIVEN_SHIFT_PX = 0.02, 3.0
# a highlight centred this close outside the outline is a rim glint (a light behind the sphere,
# which the highlight search flags), not a sphere the outline misses
_RIM, _RIM_PX = 0.03, 2.0


def _overlap(region, circle):
    """Intersection over union of a blob (H, W) bool and a circle's disc, over the blob's box."""
    rows, cols = np.nonzero(region)
    top, bottom = max(int(min(rows.min(), circle.cy - circle.r)) - 1, 0), int(max(rows.max(), circle.cy + circle.r)) + 2
    left, right = max(int(min(cols.min(), circle.cx - circle.r)) - 1, 0), int(max(cols.max(), circle.cx + circle.r)) + 2
    yy, xx = np.mgrid[top:bottom, left:right]
    disc = np.hypot(xx - circle.cx, yy - circle.cy) <= circle.r
    blob = np.zeros_like(disc)
    crop = region[top:bottom, left:right]
    blob[:crop.shape[0], :crop.shape[1]] = crop
    return float((blob & disc).sum() / max((blob | disc).sum(), 1))


def check_mask_disc(region, circle, index=0):
    """InputError unless the mask blob ``region`` (H, W) bool is a disc like ``circle`` (fitted
    to it); the message gives the figures."""
    limit = max(MASK_RMS_PX, MASK_RMS * circle.r)
    overlap = _overlap(region, circle)
    if circle.rms > limit or overlap < MASK_IOU:
        raise InputError(
            f"sphere mask: blob {index} at ({circle.cx:.1f}, {circle.cy:.1f}) is not a disc: its outline is "
            f"{circle.rms:.1f} px rms from the best circle of radius {circle.r:.1f} px "
            f"({100 * circle.rms / circle.r:.1f} %; a sphere's is under {100 * MASK_RMS:.0f} % or "
            f"{MASK_RMS_PX:g} px) and that circle's disc covers {100 * overlap:.0f} % of it (a sphere's "
            f"{100 * MASK_IOU:.0f} % or more). Give the mask of the sphere alone, or --circle CX,CY,R")


def check_given_circle(grey, circle):
    """InputError when the frames (K, H, W) show this sphere's limb clearly elsewhere than the
    given ``circle``. Frames whose outline is too faint to fit pass: the circle is then all
    there is."""
    try:
        seen = refine_circle(grey, circle)
    except SphereNotFound:
        return
    if not credible(seen, grey.shape[1:]):
        return
    shift = max(np.hypot(seen.cx - circle.cx, seen.cy - circle.cy), abs(seen.r - circle.r))
    if shift > max(_GIVEN_SHIFT * circle.r, _GIVEN_SHIFT_PX):
        raise InputError(
            f"circle ({circle.cx:.1f}, {circle.cy:.1f}) r {circle.r:.1f}: the frames show the sphere's outline "
            f"at ({seen.cx:.1f}, {seen.cy:.1f}) r {seen.r:.1f}, {shift:.1f} px away (outline rms "
            f"{seen.rms:.2f} px); give the sphere's circle in 0-based pixels (x right, y down), or leave "
            "--circle out to have it found")


def check_highlights_inside(grey, background, circle, mask=None):
    """InputError naming the frames whose highlight lies outside the given outline.

    Parameters
    ----------
    grey : ndarray (K, H, W)
    background : ndarray (H, W)
        Per-pixel median over the frames.
    circle : Circle
    mask : ndarray (H, W) bool, optional
        The sphere's mask blob, when the outline came from one.
    """
    _, height, width = grey.shape
    reach = circle.r * (1 + HIGHLIGHT_MARGIN)
    top, bottom = max(int(circle.cy - reach), 0), min(int(circle.cy + reach) + 2, height)
    left, right = max(int(circle.cx - reach), 0), min(int(circle.cx + reach) + 2, width)
    yy, xx = np.mgrid[top:bottom, left:right]
    distance = np.hypot(xx - circle.cx, yy - circle.cy)
    inside = distance <= circle.r if mask is None else mask[top:bottom, left:right]
    near = distance <= reach
    outside = []
    for k in range(grey.shape[0]):
        signal = np.where(near, grey[k, top:bottom, left:right] - background[top:bottom, left:right], 0.0)
        peak = float(signal.max())
        if peak <= 0:
            continue
        labels, _ = ndimage.label(signal > 0.5 * peak)
        blob = labels == labels[np.unravel_index(np.argmax(signal), signal.shape)]
        weights = signal * blob
        cy, cx = (np.array(ndimage.center_of_mass(weights)) + [top, left])
        spot_inside = inside[int(round(cy)) - top, int(round(cx)) - left] if (
            0 <= int(round(cy)) - top < inside.shape[0] and 0 <= int(round(cx)) - left < inside.shape[1]) else False
        clear = np.hypot(cx - circle.cx, cy - circle.cy) > circle.r + max(_RIM_PX, _RIM * circle.r)
        if clear and not spot_inside and (weights * ~inside).sum() > (weights * inside).sum():
            outside.append((k, cx, cy, np.hypot(cx - circle.cx, cy - circle.cy)))
    if outside:
        listed = "; ".join(f"frame {k} at ({x:.1f}, {y:.1f}), {d:.1f} px from the centre" for k, x, y, d in outside[:4])
        raise InputError(
            f"{len(outside)} highlight(s) outside the sphere ({circle.cx:.1f}, {circle.cy:.1f}) r {circle.r:.1f} "
            f"({circle.method}): {listed}{' ...' if len(outside) > 4 else ''}; the circle or mask does not "
            "cover the sphere")
