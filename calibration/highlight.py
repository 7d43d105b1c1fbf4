"""Specular highlights on a chrome sphere: locate, weigh, and say when one cannot be trusted.

Each frame is compared with the per-pixel median of all frames, so reflections that every frame
shares (windows, monitors, the room) cancel and only the light of that frame remains.
"""

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

__all__ = ["Blob", "highlight_blob", "saturation_level", "HALF", "RIM", "MAX_SATURATED"]

HALF = 0.5            # blob = pixels above this fraction of the frame's highlight peak
RIM = 0.96            # highlight beyond this fraction of the radius: normal too oblique to trust
MAX_SATURATED = 0.015 # saturated blob larger than this fraction of the disc: overexposed
SHOULDER = 0.5       # clipped highlights: weights ramp from this fraction of the clip level
SECOND = 0.25         # a second blob this large (relative to the main one) means two highlights


@dataclass
class Blob:
    """The highlight of one frame.

    Attributes
    ----------
    rows, cols : ndarray (N,)
        Pixels of the highlight blob.
    weights : ndarray (N,)
        Intensity weights (signal above the blob threshold).
    x, y : float
        Intensity-weighted centroid, pixels (x = column, y = row); NaN when none.
    sigma : float
        Standard error of the centroid, pixels.
    flag : str or None
        Why the highlight cannot be trusted, or None.
    """

    rows: np.ndarray
    cols: np.ndarray
    weights: np.ndarray
    x: float
    y: float
    sigma: float
    saturated: int
    flag: str = None


def saturation_level(images):
    """A clip level for data without saturation masks: 98 % of the stack's maximum when that
    maximum looks clipped (many pixels share it), else infinity."""
    top = float(np.max(images))
    clipped = np.count_nonzero(images >= top * 0.999)
    return top * 0.98 if clipped > 4 * images.shape[0] else np.inf


def _empty(flag):
    e = np.zeros(0)
    return Blob(e.astype(int), e.astype(int), e, np.nan, np.nan, np.inf, 0, flag)


def highlight_blob(frame, background, disc, saturated, *, radius, centre):
    """Find the highlight of one frame on the sphere.

    Parameters
    ----------
    frame, background : ndarray (H, W)
        Grey frame and the per-pixel median over all frames.
    disc : ndarray (H, W) bool
        Sphere pixels to search.
    saturated : ndarray (H, W) bool
        Saturated pixels of this frame.
    radius : float
        Sphere radius, pixels (for the rim and size tests).
    centre : (2,)
        Sphere centre (cx, cy), pixels.
    """
    signal = np.where(disc, frame - background, 0.0)
    values = signal[disc]
    if values.size == 0:
        return _empty("no sphere pixels to search")
    peak = float(values.max())
    noise = 1.4826 * float(np.median(np.abs(values - np.median(values))))
    if peak <= max(10 * noise, 0.02 * max(float(frame[disc].max()), 1e-12)):
        return _empty("no highlight (light behind the sphere or off)")
    labels, count = ndimage.label(signal > HALF * peak)
    main = labels[np.unravel_index(np.argmax(signal), signal.shape)]
    sizes = ndimage.sum_labels(np.ones_like(signal), labels, index=np.arange(1, count + 1))
    rows, cols = np.nonzero(labels == main)
    weights = signal[rows, cols] - HALF * peak
    if saturated[rows, cols].any():
        rows, cols, weights = _clipped_top(signal, saturated & disc, rows, cols)
    total = weights.sum()
    x = float((weights * cols).sum() / total)
    y = float((weights * rows).sum() / total)
    spread = np.sqrt((weights * ((cols - x) ** 2 + (rows - y) ** 2)).sum() / total)
    n_eff = total ** 2 / max((weights ** 2).sum(), 1e-30)
    sigma = float(spread / np.sqrt(max(n_eff, 1.0)) + 0.05)
    nsat = int(np.count_nonzero(saturated[rows, cols]))
    blob = Blob(rows, cols, weights, x, y, sigma, nsat)
    blob.flag = _judge(blob, sizes, main, radius, centre)
    return blob


def _clipped_top(signal, saturated, rows, cols):
    """Weights for a highlight with a clipped core.

    The largest clipped patch of the blob, grown by two pixels, weighted by how far each
    pixel reaches up a ramp from ``SHOULDER`` of the clip level to the clip level. The ramp's
    top is a level set of the (symmetric) lobe, so its centroid is unbiased, and the partial
    edge pixels make it sub-pixel where counting clipped pixels alone quantises it. Flare
    spikes of real lenses are separate clipped patches or lie lower, and stay out.
    """
    inside = np.zeros_like(saturated)
    inside[rows, cols] = True
    labels, count = ndimage.label(saturated & inside)
    sizes = ndimage.sum_labels(np.ones(saturated.shape), labels, index=np.arange(1, count + 1))
    core = labels == 1 + int(np.argmax(sizes))
    region = ndimage.binary_dilation(core, iterations=2) & inside
    r, c = np.nonzero(region)
    top = float(np.median(signal[core]))
    low = SHOULDER * top
    weights = np.clip((signal[r, c] - low) / max(top - low, 1e-12), 0, 1)
    keep = weights > 0
    return r[keep], c[keep], weights[keep]


def _judge(blob, sizes, main, radius, centre):
    """The reason a found blob is doubtful, or None (the rim first: a grazing highlight often
    breaks into pieces, and its obliqueness is the real cause)."""
    dist = np.hypot(blob.cols - centre[0], blob.rows - centre[1])
    if np.hypot(blob.x - centre[0], blob.y - centre[1]) > RIM * radius or dist.max() > 0.995 * radius:
        return "highlight on the rim of the sphere (normal too oblique)"
    main_size = sizes[main - 1]
    others = np.delete(sizes, main - 1)
    if others.size and others.max() >= max(SECOND * main_size, 4):
        return f"two highlights (a second blob of {int(others.max())} px beside {int(main_size)} px)"
    disc_area = np.pi * radius ** 2
    if blob.saturated > MAX_SATURATED * disc_area:
        return f"saturated blob of {blob.saturated} px: overexposed, highlight centre not reliable"
    return None
