"""Light directions from chrome-sphere frames: the public entry points.

>>> lights = calibrate_lights(images)                 # (K, 3), raises if a light is doubtful
>>> result = calibrate_sphere(images, spheres=2)      # directions, circles, highlights, flags,
...                                                   # uncertainty, positions (two spheres)
"""

from dataclasses import dataclass, field

import numpy as np

from pipeline.errors import InputError, PsrigError

from .circle import Circle, circle_from_mask, find_spheres, sphere_image
from .geometry import check_K, mirror, sphere_points
from .highlight import highlight_blob, saturation_level
from .positions import triangulate

__all__ = ["calibrate_lights", "calibrate_sphere", "SphereCalibration", "CalibrationError"]


class CalibrationError(PsrigError):
    """Some lights could not be calibrated; the message names the frames and why."""


@dataclass
class SphereCalibration:
    """Result of :func:`calibrate_sphere`.

    Attributes
    ----------
    directions : ndarray (K, 3)
        Unit light directions, camera frame (mean over the spheres that saw the light); rows of
        flagged lights hold the best guess, check ``flags``.
    circles : list of Circle
        One per sphere, left to right.
    highlights : ndarray (S, K, 2)
        Sub-pixel highlight centres (x, y) per sphere and light; NaN when none.
    per_sphere : ndarray (S, K, 3)
        Directions from each sphere.
    flags : dict
        {light index: reason}.
    uncertainty_deg : ndarray (K,)
        1-sigma angular uncertainty from the highlight and circle errors, degrees.
    residual_deg : ndarray (K,)
        Disagreement between spheres (two or more) or the uncertainty (one sphere), degrees.
    positions : ndarray (K, 3) or None
        Triangulated light positions (two or more spheres), frame of
        :func:`calibration.geometry.sphere_points`.
    method : str
    """

    directions: np.ndarray
    circles: list
    highlights: np.ndarray
    per_sphere: np.ndarray
    flags: dict = field(default_factory=dict)
    uncertainty_deg: np.ndarray = None
    residual_deg: np.ndarray = None
    positions: np.ndarray = None
    position_error: np.ndarray = None
    method: str = ""

    @property
    def circle(self):
        """The first (leftmost) sphere's circle."""
        return self.circles[0]


def _grey(images):
    images = np.asarray(images, dtype=np.float32)
    if images.ndim == 4:
        return images.mean(axis=-1), images.max(axis=-1)
    if images.ndim == 3:
        return images, images
    raise InputError(f"sphere images must be (K, H, W) or (K, H, W, C), got shape {images.shape}")


def _circles(grey, circle, mask, spheres):
    if circle is not None:
        given = [circle] if np.ndim(circle[0]) == 0 and not isinstance(circle[0], Circle) else list(circle)
        out = []
        for c in given:
            c = c if isinstance(c, Circle) else Circle(*map(float, c), method="given")
            if not (c.r > 0 and np.isfinite(c.params).all()):
                raise InputError(f"circle: radius must be positive and finite, got {c.params.tolist()}")
            out.append(c)
        return out
    if mask is not None:
        mask = np.asarray(mask, bool)
        if mask.shape != grey.shape[1:]:
            raise InputError(f"sphere mask: shape {mask.shape} does not match the frames {grey.shape[1:]}")
        return [circle_from_mask(mask)]
    return find_spheres(sphere_image(grey), spheres)


def _one_sphere(grey, peak, sat, circ, mask, K):
    """Directions, highlight centres, flags and uncertainties for one sphere."""
    n_lights, h, w = grey.shape
    cx, cy, r = circ.params
    rows, cols = np.mgrid[0:h, 0:w]
    disc = np.hypot(cols - cx, rows - cy) < r
    if mask is not None:
        disc &= mask
    background = np.median(grey, axis=0)
    dirs = np.full((n_lights, 3), np.nan)
    spots = np.full((n_lights, 2), np.nan)
    unc = np.full(n_lights, np.nan)
    flags = {}
    for k in range(n_lights):
        blob = highlight_blob(grey[k], background, disc, sat[k], radius=r, centre=(cx, cy))
        if not np.isfinite(blob.x):
            flags[k] = blob.flag
            continue
        normals, views, _ = sphere_points(blob.cols, blob.rows, circ.params, K)
        ok = np.isfinite(normals).all(-1)
        # averaging mirror directions, not pixels, keeps the centre unbiased where the sphere
        # foreshortens the lobe
        d = (mirror(normals[ok], views[ok]) * blob.weights[ok, None]).sum(0)
        dirs[k] = d / np.linalg.norm(d)
        spots[k] = blob.x, blob.y
        unc[k] = _uncertainty(blob, circ, K, dirs[k])
        if blob.flag:
            flags[k] = blob.flag
    return dirs, spots, flags, unc


def _uncertainty(blob, circ, K, direction):
    """1-sigma angle (degrees) from the highlight centroid error and the circle's errors."""
    base = np.array([blob.x, blob.y, *circ.params])
    sig = np.array([blob.sigma, blob.sigma, *np.maximum(circ.sigma, 0.05)])
    angles = []
    for i in range(5):
        p = base.copy()
        p[i] += sig[i]
        n, v, _ = sphere_points(p[:1], p[1:2], p[2:], K)
        d = mirror(n, v)[0]
        angles.append(np.degrees(np.arccos(np.clip(d @ mirror(*sphere_points(base[:1], base[1:2], base[2:], K)[:2])[0], -1, 1))))
    return float(np.sqrt(np.nansum(np.square(angles))))


def calibrate_sphere(images, circle=None, mask=None, *, saturation=None, K=None, spheres=None):
    """Light directions (and positions with two spheres) from chrome-sphere frames.

    Parameters
    ----------
    images : ndarray (K, H, W) or (K, H, W, C)
        One frame per light, float linear (gamma-encoded data works too).
    circle : (cx, cy, r), list of them, or None
        Sphere outline(s) in pixels (0-based, x = column, y = row downward); found when None.
    mask : ndarray (H, W) bool or None
        Pixels of the (single) sphere; used to get the circle and to limit the search.
    saturation : ndarray (K, H, W) bool or None
        Saturated pixels per frame; guessed from the data's clip level when None.
    K : ndarray (3, 3) or None
        Intrinsics for per-pixel view rays (perspective); orthographic when None.
    spheres : int or None
        How many spheres to find (default: len(circle) or 1).

    Returns
    -------
    SphereCalibration
    """
    grey, peak = _grey(images)
    K = check_K(K)
    if spheres is None:
        spheres = 1 if circle is None or np.ndim(circle) == 1 else len(circle)
    if saturation is None:
        sat = peak >= saturation_level(peak)
    else:
        sat = np.asarray(saturation, bool)
        if sat.shape != grey.shape:
            raise InputError(f"saturation masks: shape {sat.shape} does not match the frames {grey.shape}")
    circles = _circles(grey, circle, mask, spheres)
    keep = None if mask is None else np.asarray(mask, bool)
    parts = [_one_sphere(grey, peak, sat, c, keep if len(circles) == 1 else None, K) for c in circles]
    per = np.stack([p[0] for p in parts])
    flags = {}
    for s, part in enumerate(parts):
        for k, why in part[2].items():
            flags.setdefault(k, why if len(parts) == 1 else f"sphere {s}: {why}")
    unc = np.nanmax(np.stack([p[3] for p in parts]), axis=0) if len(parts) else None
    mean = np.nanmean(per, axis=0)
    norm = np.linalg.norm(mean, axis=1, keepdims=True)
    directions = np.divide(mean, norm, out=np.full_like(mean, np.nan), where=norm > 0)
    result = SphereCalibration(directions, circles, np.stack([p[1] for p in parts]), per, flags,
                               uncertainty_deg=unc, residual_deg=unc.copy(),
                               method=("perspective" if K is not None else "orthographic")
                               + f" chrome sphere x{len(circles)}, direction-weighted highlight")
    if len(circles) > 1:
        _add_positions(result, K)
    return result


def _add_positions(result, K):
    """Triangulate light positions from the highlight rays of every sphere."""
    starts, rays = [], []
    for s, circ in enumerate(result.circles):
        spots = result.highlights[s]
        n, v, pts = sphere_points(spots[:, 0], spots[:, 1], circ.params, K)
        starts.append(pts)
        rays.append(result.per_sphere[s])
    cos = np.clip((result.per_sphere[0] * result.per_sphere[1]).sum(-1), -1, 1)
    result.residual_deg = np.degrees(np.arccos(cos))
    result.positions, result.position_error = triangulate(np.stack(starts), np.stack(rays))


def calibrate_lights(images, circle=None, mask=None, *, on_flag="raise", **options):
    """Unit light directions (K, 3), camera frame, from chrome-sphere frames.

    A thin wrapper of :func:`calibrate_sphere` (same parameters). When a light is flagged (no
    highlight, two highlights, an overexposed blob, a highlight on the rim), ``on_flag='raise'``
    (default) raises :class:`CalibrationError` naming the frames and reasons; ``on_flag='nan'``
    returns those rows as NaN instead. A flagged direction is never returned as if it were good.
    """
    if on_flag not in ("raise", "nan"):
        raise InputError(f"on_flag: expected 'raise' or 'nan', got {on_flag!r}")
    result = calibrate_sphere(images, circle, mask, **options)
    directions = result.directions.copy()
    if result.flags:
        if on_flag == "raise":
            listed = "; ".join(f"frame {k}: {why}" for k, why in sorted(result.flags.items()))
            raise CalibrationError(f"{len(result.flags)} light(s) could not be calibrated: {listed}")
        directions[sorted(result.flags)] = np.nan
    return directions
