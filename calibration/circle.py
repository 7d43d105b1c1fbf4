"""Finding a sphere's outline in an image: Hough seed, sub-pixel radial edges, robust circle fit.

Circles are ``(cx, cy, r)`` in pixels, 0-based, x = column, y = row (rows downward).
"""

from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage, optimize

from pipeline.core.errors import InputError

__all__ = ["Circle", "find_spheres", "find_sphere", "refine_circle", "circle_from_mask",
           "fit_circle", "sphere_image", "credible", "SphereNotFound"]


class SphereNotFound(InputError):
    """No sphere outline could be found in the image."""


@dataclass
class Circle:
    """A fitted circle.

    Attributes
    ----------
    cx, cy, r : float
        Centre column, centre row and radius, pixels (0-based, rows downward).
    rms : float
        RMS distance of the inlier edge points to the circle, pixels (0 when given).
    inliers : float
        Fraction of outline rays that support the circle (1 when given).
    sigma : ndarray (3,)
        Standard errors of (cx, cy, r), pixels.
    method : str
        'given', 'mask', 'fit' (found on the frames) or 'outline' (found on an outline photo).
    """

    cx: float
    cy: float
    r: float
    rms: float = 0.0
    inliers: float = 1.0
    sigma: np.ndarray = None
    method: str = "given"

    def __post_init__(self):
        if self.sigma is None:
            self.sigma = np.zeros(3)

    @property
    def params(self):
        """(cx, cy, r) as a float ndarray (3,)."""
        return np.array([self.cx, self.cy, self.r], float)

    def as_dict(self):
        return {"cx": round(float(self.cx), 3), "cy": round(float(self.cy), 3), "r": round(float(self.r), 3),
                "rms_px": round(float(self.rms), 3), "inliers": round(float(self.inliers), 3),
                "method": self.method}


def sphere_image(images):
    """Grey image in which the sphere outline is clearest: the max over frames, (H, W) float32.

    images : (K, H, W) or (K, H, W, C). The maximum shows every side of the sphere lit by some
    light, so the outline has contrast all round.
    """
    images = np.asarray(images, dtype=np.float32)
    grey = images.mean(axis=-1) if images.ndim == 4 else images
    return grey.max(axis=0)


def fit_circle(x, y, start=None, *, iterations=15):
    """Robust geometric circle fit (Tukey-weighted Levenberg-Marquardt).

    Parameters
    ----------
    x, y : ndarray (N,)
        Edge points, pixels.
    start : (3,) optional
        Initial (cx, cy, r); the algebraic (Kasa) fit when omitted.

    Returns
    -------
    params : ndarray (3,), weights : ndarray (N,) in [0, 1], sigma : ndarray (3,)
    """
    x, y = np.asarray(x, float), np.asarray(y, float)
    if len(x) < 3:
        raise SphereNotFound("fewer than 3 edge points to fit a circle to")
    c = np.asarray(start, float) if start is not None else _kasa(x, y)
    w = np.ones_like(x)
    for _ in range(iterations):
        res = np.hypot(x - c[0], y - c[1]) - c[2]
        scale = max(1.4826 * np.median(np.abs(res - np.median(res))), 0.25)
        u = res / (4.685 * scale)
        w = np.where(np.abs(u) < 1, (1 - u ** 2) ** 2, 0.0)
        sw = np.sqrt(w)
        new = optimize.least_squares(lambda p: sw * (np.hypot(x - p[0], y - p[1]) - p[2]), c).x
        done = np.abs(new - c).max() < 1e-4
        c = new
        if done:
            break
    return c, w, _fit_sigma(x, y, c, w)


def _kasa(x, y):
    a = np.c_[2 * x, 2 * y, np.ones_like(x)]
    sol = np.linalg.lstsq(a, x * x + y * y, rcond=None)[0]
    return np.array([sol[0], sol[1], np.sqrt(max(sol[2] + sol[0] ** 2 + sol[1] ** 2, 1e-9))])


def _fit_sigma(x, y, c, w):
    """Standard errors of (cx, cy, r) from the weighted Jacobian."""
    d = np.maximum(np.hypot(x - c[0], y - c[1]), 1e-9)
    jac = np.c_[-(x - c[0]) / d, -(y - c[1]) / d, -np.ones_like(x)] * np.sqrt(w)[:, None]
    res = (d - c[2]) * np.sqrt(w)
    dof = max(np.count_nonzero(w) - 3, 1)
    try:
        cov = np.linalg.inv(jac.T @ jac) * (res @ res) / dof
    except np.linalg.LinAlgError:
        return np.full(3, np.inf)
    return np.sqrt(np.clip(np.diag(cov), 0, None))


def _radial_edges(image, c, band, *, rays=720):
    """Sub-pixel outline points at the steepest step along rays from the centre.

    On each ray the edge is the steepest rise toward the background (the sign from the medians
    inside and outside) within ``band[0]`` of the circle, refined by a parabola through the
    derivative's peak: the classic edge, where a blurred step has its inflection whatever the
    blur. Crossing levels set between the inside and the background instead move with the
    limb: a chrome limb mirrors the background behind the sphere and fades into it, so the
    levelled crossings slide inward or outward with how bright that reflection is, frame by
    frame and side by side.

    Returns
    -------
    radius : ndarray (rays,)
        Distance of the outline point from the centre ``c``, pixels.
    slope : ndarray (rays,)
        The step's steepest rise toward the background, per pixel; > 0 on rays with a step.
    contrast : ndarray (rays,)
        |outside - inside|.
    """
    inner, outer = band
    step = 0.25
    theta = _angles(rays)
    off = np.arange(-outer, outer + step / 2, step)
    xs = c[0] + np.cos(theta)[:, None] * (c[2] + off)
    ys = c[1] + np.sin(theta)[:, None] * (c[2] + off)
    prof = ndimage.map_coordinates(image, [ys, xs], order=1, mode="nearest")
    lo = np.median(prof[:, off <= -inner], axis=1)
    hi = np.median(prof[:, off >= inner], axis=1)
    slope = np.sign(hi - lo)[:, None] * np.gradient(prof, step, axis=1)
    idx = np.clip(np.argmax(np.where(np.abs(off) < inner, slope, -np.inf), axis=1), 1, len(off) - 2)
    rows = np.arange(rays)
    g0, g1, g2 = slope[rows, idx - 1], slope[rows, idx], slope[rows, idx + 1]
    curv = g0 - 2 * g1 + g2
    shift = np.where(curv < 0, 0.5 * (g0 - g2) / np.where(curv < 0, curv, -1.0), 0.0)
    return c[2] + off[idx] + np.clip(shift, -1, 1) * step, g1, np.abs(hi - lo)


_RAYS = 720


def _angles(rays=_RAYS):
    return np.linspace(0, 2 * np.pi, rays, endpoint=False)


def refine_circle(image, circle, *, passes=3):
    """Refine a rough circle to sub-pixel precision on ``image`` (H, W) or frames (K, H, W).

    With several frames the circle is first refined on their maximum, which shows the limb
    all round and so pulls in a seed from pixels away. Then each ray takes its edge from the
    frame whose step there is sharpest (steepest for its contrast): a chrome limb's apparent
    edge moves by pixels from light to light, and the maximum keeps the outermost of the
    bright ones, biasing the circle toward the side the lights reach most (PSBox probe 1: the
    centre 2.6 px below the author's circle, clicked on a room-lit photo, on the maximum;
    1.2 px from the sharpest steps). Averaging every frame's edge instead would let soft ones
    count, say where a matte sphere's shading fades out at its limb.

    Returns a :class:`Circle` with method 'fit'. Rays whose step has little contrast (under a
    third of the median) and outline points the robust fit rejects (the stand, reflections)
    do not count; ``inliers`` is the share of the 720 rays that support the circle.
    """
    frames = np.asarray(image, np.float32)
    frames = frames[None] if frames.ndim == 2 else frames
    c = np.asarray(circle.params if isinstance(circle, Circle) else circle, float)
    corner, crop = _window(frames, c)
    c = c - corner
    wide = 0.08
    if len(crop) > 1:
        c = _refine(_smooth(crop.max(axis=0)[None]), c, passes, wide)[0]
        wide = 0.035
    c, x, y, weights, sigma = _refine(_smooth(crop), c, passes, wide)
    res = np.hypot(x - c[0], y - c[1]) - c[2]
    inl = weights > 0.5
    rms = float(np.sqrt(np.mean(res[inl] ** 2))) if inl.any() else float("inf")
    c = c + corner
    return Circle(c[0], c[1], c[2], rms=rms, inliers=float(inl.sum()) / _RAYS, sigma=sigma, method="fit")


def _refine(smooth, c, passes, wide):
    """Circle fits on smoothed frames (K, h, w); the first pass searches ``wide`` * r out."""
    for n in range(passes):
        band = (max(4.0, 0.015 * c[2]), max(10.0, (wide if n == 0 else 0.035) * c[2]))
        x, y = _sharpest_edges(smooth, c, band)
        if len(x) < 20:
            raise SphereNotFound("the sphere outline has too little contrast to fit a circle")
        c, weights, sigma = fit_circle(x, y, c)
    return c, x, y, weights, sigma


def _window(frames, c):
    """Corner (col0, row0, 0) and the frames (K, h, w) over the window the rays can reach.

    Only that window is smoothed: frames can be tens of megapixels, and there may be dozens.
    """
    pad = 0.1 * c[2] + 16   # the widest band, the blur's reach, and the circle's moves between passes
    h, w = frames.shape[1:]
    y0, y1 = int(np.clip(c[1] - c[2] - pad, 0, h - 1)), int(np.clip(c[1] + c[2] + pad + 1, 1, h))
    x0, x1 = int(np.clip(c[0] - c[2] - pad, 0, w - 1)), int(np.clip(c[0] + c[2] + pad + 1, 1, w))
    return np.array([x0, y0, 0.0]), frames[:, y0:y1, x0:x1]


def _smooth(frames):
    """Frames (K, h, w) blurred by a 1 px Gaussian (OpenCV's, several times faster than scipy's)."""
    out = np.empty(frames.shape, np.float32)
    for f, o in zip(frames, out):
        cv2.GaussianBlur(np.ascontiguousarray(f), (9, 9), 1.0, dst=o, borderType=cv2.BORDER_REFLECT)
    return out


def _sharpest_edges(smooth, c, band):
    """Outline points (x, y), one per ray with a clear step in some frame of ``smooth`` (K, h, w)."""
    radius, slope, contrast = (np.stack(v) for v in zip(*(_radial_edges(f, c, band, rays=_RAYS) for f in smooth)))
    rising = slope > 0
    if not rising.any():
        return np.zeros(0), np.zeros(0)
    clear = rising & (contrast > np.median(contrast[rising]) / 3)
    sharpness = np.where(clear, slope / np.maximum(contrast, 1e-12), -np.inf)
    best = np.argmax(sharpness, axis=0)
    rays = np.arange(_RAYS)
    keep = clear[best, rays]
    r, theta = radius[best, rays][keep], _angles()[keep]
    return c[0] + np.cos(theta) * r, c[1] + np.sin(theta) * r


def _hough_image(image):
    """Log-compressed copy of ``image`` for the Hough seed: a dark chrome ball beside a bright
    matte one (or a clipped highlight) must still show its outline."""
    image = np.asarray(image, np.float32)
    floor = 1e-3 * max(float(np.percentile(image, 99.5)), 1e-12)
    return np.log(np.maximum(image - float(image.min()), 0) + floor).astype(np.float32)


def _hough(image, count):
    """Rough circles (cx, cy, r) by a Hough transform on a downscaled image, strongest first.

    ``count`` None asks for every candidate the transform offers (at most 8).
    """
    h, w = image.shape
    s = max(1, int(round(max(h, w) / 400)))
    small = cv2.resize(image, (w // s, h // s), interpolation=cv2.INTER_AREA) if s > 1 else image
    top = np.percentile(small, 99.5) - small.min()
    if not np.isfinite(top) or top <= 0:
        return []
    u8 = cv2.GaussianBlur((np.clip((small - small.min()) / top, 0, 1) * 255).astype(np.uint8), (0, 0), 1.5)
    side = min(u8.shape)
    want = count or 8
    found = None
    for votes in (30, 20, 14):
        found = cv2.HoughCircles(u8, cv2.HOUGH_GRADIENT, dp=1, minDist=side / 4, param1=60,
                                 param2=votes, minRadius=max(4, side // 12), maxRadius=side // 2)
        if found is not None and len(found[0]) >= (count or 1):
            break
    return [] if found is None else [tuple(c * s) for c in found[0][:want]]


def credible(circle, shape, min_inliers=0.4, max_rms=None):
    """True when ``circle`` (a refined :class:`Circle`) is a sphere outline worth trusting: at
    least ``min_inliers`` of the rays support it, its RMS edge distance is under ``max_rms``
    pixels (2 % of the radius by default) and it lies in an image of ``shape`` (H, W)."""
    limit = max_rms if max_rms is not None else max(1.0, 0.02 * circle.r)
    return circle.inliers >= min_inliers and circle.rms <= limit and _inside(circle, shape)


def _overlaps(circle, others):
    return any(np.hypot(circle.cx - o.cx, circle.cy - o.cy) < 0.9 * (circle.r + o.r) for o in others)


def _nested(circle, others):
    """True when ``circle`` lies inside a larger one: no sphere shows inside another, so it is a
    reflection or a marking on that sphere (a room-lit chrome ball mirrors round lamps and
    windows, whose crisp outlines can be better supported than the sphere's own limb)."""
    return any(o.r > circle.r and np.hypot(circle.cx - o.cx, circle.cy - o.cy) + circle.r < 1.05 * o.r
               for o in others)


def find_spheres(image, count=None, *, min_inliers=0.4, max_rms=None):
    """Find the spheres in a grey image (H, W) with no clicks.

    Hough seeds on a log-compressed image are refined on the image itself
    (:func:`refine_circle`); a refined outline is credible when at least ``min_inliers`` of it
    supports the circle with an RMS edge distance under ``max_rms`` pixels (2 % of the radius
    by default). A candidate inside a larger credible one is dropped (a reflection on that
    sphere); of overlapping candidates the one with the longest supporting outline is kept.

    Parameters
    ----------
    image : ndarray (H, W)
    count : int or None
        How many spheres to expect; None returns every credible one (at least one).

    Returns
    -------
    list of Circle, left to right (then top to bottom).

    Raises
    ------
    SphereNotFound
        When fewer than ``count`` (or no) credible outlines are found.
    """
    image = np.asarray(image, np.float32)
    if image.ndim != 2:
        raise InputError(f"sphere image must be (H, W), got shape {image.shape}")
    found = []
    seeds = _hough(image, None) + _hough(_hough_image(image), None)
    for seed in seeds:
        if any(np.hypot(seed[0] - c.cx, seed[1] - c.cy) < 0.1 * c.r and abs(seed[2] - c.r) < 0.1 * c.r
               for c in found):
            continue
        try:
            circle = refine_circle(image, seed)
        except SphereNotFound:
            continue
        if credible(circle, image.shape, min_inliers, max_rms):
            found.append(circle)
    circles = []
    found = [c for c in found if not _nested(c, found)]
    # of overlapping candidates the one with the most supporting outline (in pixels, not as a
    # share of its own circumference): an arc inside a sphere, say a reflection that runs on
    # into the stand, can support a larger share of a smaller circle than the limb of the
    # whole sphere does
    for circle in sorted(found, key=lambda c: (-c.inliers * c.r, c.rms / c.r)):
        if not _overlaps(circle, circles):
            circles.append(circle)
    if count is not None:
        circles = circles[:count]
    if len(circles) < (count or 1):
        raise SphereNotFound(f"found {len(circles)} sphere outline(s), expected {count or 'one or more'}; "
                             "give the circle with --circle CX,CY,R or a --sphere-mask")
    return sorted(circles, key=lambda c: (round(c.cx / max(c.r, 1)), c.cy))


def find_sphere(image, **options):
    """The single best-supported sphere in a grey image (H, W); see :func:`find_spheres`."""
    return find_spheres(image, 1, **options)[0]


def _inside(circle, shape):
    h, w = shape
    return 0 <= circle.cx < w and 0 <= circle.cy < h and 3 < circle.r < max(h, w)


def circle_from_mask(mask):
    """Circle of a sphere mask (H, W) bool, fitted to its boundary pixels (robust)."""
    mask = np.asarray(mask, bool)
    if mask.sum() < 20:
        raise SphereNotFound("the sphere mask is empty or too small")
    edge = mask & ~ndimage.binary_erosion(mask)
    ys, xs = np.nonzero(edge)
    # boundary pixels sit half a pixel inside the true outline
    area_r = np.sqrt(mask.sum() / np.pi)
    c, w, sigma = fit_circle(xs.astype(float), ys.astype(float))
    res = np.hypot(xs - c[0], ys - c[1]) - c[2]
    return Circle(c[0], c[1], area_r, rms=float(np.sqrt(np.mean(res[w > 0.5] ** 2))),
                  inliers=float((w > 0.5).mean()), sigma=sigma, method="mask")
