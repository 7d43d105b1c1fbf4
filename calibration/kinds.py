"""Chrome or matte: tell the spheres in view apart from how their light moves between frames.

A chrome ball shows each light as a small sharp highlight; a matte ball is shaded broadly. Per
frame, the share of the disc brighter than half that frame's peak (over the per-pixel minimum of
all frames, which removes ambient light and shared reflections) is a few percent or less on
chrome and tens of percent on a matte sphere.
"""

import numpy as np

__all__ = ["sphere_kind", "lit_fraction", "CHROME_MAX_FRACTION"]

CHROME_MAX_FRACTION = 0.08  # median lit share of the disc below this: a mirror ball


def lit_fraction(grey, circle):
    """Median over frames of the disc share above half the frame's peak.

    Parameters
    ----------
    grey : ndarray (K, H, W)
        Linear grey frames, one per light.
    circle : (cx, cy, r)
        Sphere outline, pixels.

    Returns
    -------
    float in [0, 1], or NaN when no frame lights the sphere.
    """
    grey = np.asarray(grey, np.float32)
    cx, cy, r = map(float, circle)
    rows, cols = np.mgrid[0:grey.shape[1], 0:grey.shape[2]]
    # the inner 90 % keeps the limb, which mirrors the background, out of the statistic
    disc = np.hypot(cols - cx, rows - cy) < 0.9 * r
    if not disc.any():
        return float("nan")
    pixels = grey[:, disc]
    signal = pixels - pixels.min(axis=0)
    peak = signal.max(axis=1)
    lit = peak > 1e-6 * max(float(np.abs(pixels).max()), 1e-30)
    if not lit.any():
        return float("nan")
    share = (signal[lit] > 0.5 * peak[lit, None]).mean(axis=1)
    return float(np.median(share))


def sphere_kind(grey, circle):
    """'chrome' or 'matte' for the sphere ``circle`` in frames ``grey`` (K, H, W).

    Returns
    -------
    kind : str
    share : float
        The :func:`lit_fraction` it was decided on.
    """
    share = lit_fraction(grey, circle)
    return ("chrome" if not share >= CHROME_MAX_FRACTION else "matte"), share
