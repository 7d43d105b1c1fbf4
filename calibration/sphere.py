"""Light directions from chrome-sphere frames: the public entry points.

>>> lights = calibrate_lights(images)                 # (K, 3), raises if a light is doubtful
>>> result = calibrate_sphere(images, spheres=2)      # directions, circles, highlights, flags,
...                                                   # uncertainty, positions (two spheres)
>>> result = calibrate_sphere(images, outline=photo)  # outlines found on an evenly lit photo
"""

from dataclasses import dataclass, field, replace

import numpy as np
from scipy import ndimage

from pipeline.core.errors import InputError, PsrigError

from .circle import (Circle, SphereNotFound, circle_from_mask, credible, find_spheres, refine_circle,
                     sphere_image)
from .geometry import check_K, mirror, sphere_centre, sphere_points
from .highlight import highlight_blob, robust_centre, saturation_level
from .kinds import sphere_kind
from .positions import frame_offset, near_decision, triangulate
from .sanity import check_given_circle, check_highlights_inside, check_mask_disc

__all__ = ["calibrate_lights", "calibrate_sphere", "SphereCalibration", "CalibrationError"]


class CalibrationError(PsrigError):
    """Some lights could not be calibrated; the message names the frames and why."""


@dataclass
class SphereCalibration:
    """Result of :func:`calibrate_sphere`.

    Attributes
    ----------
    directions : ndarray (K, 3)
        Unit light directions, camera frame: the mean over the chrome spheres that saw the
        light under the directional model, or toward the triangulated position (from the frame
        origin) when the lights are near. Rows of flagged lights hold the best guess (NaN when
        none): check ``flags``.
    circles : list of Circle
        The chrome spheres, left to right.
    highlights : ndarray (S, K, 2)
        Sub-pixel highlight centres (x, y) per chrome sphere and light; NaN when none.
    per_sphere : ndarray (S, K, 3)
        Directions from each chrome sphere (directional model).
    flags : dict
        {light index: reason} for lights no chrome sphere calibrated well (or, for near
        lights, that could not be triangulated).
    sphere_flags : list of dict
        Per chrome sphere, {light index: reason}.
    uncertainty_deg : ndarray (K,)
        1-sigma angular uncertainty from the highlight and circle errors, degrees.
    residual_deg : ndarray (K,)
        Angle between the chrome spheres' directions (two or more; the parallax of a near
        light), else the uncertainty, degrees.
    targets : list of Circle
        Matte spheres in view (intensity targets).
    kinds : list of dict
        Every sphere considered: circle, kind ('chrome'/'matte') and the lit share it was
        classified on.
    positions : ndarray (K, 3) or None
        Triangulated light positions when the lights are near: orthographic, pixels with the
        origin at the image centre (x right, y up, z = 0 on the sphere centres' plane);
        perspective, camera frame in sphere radii.
    triangulated : ndarray (K, 3) or None
        The raw triangulation (two or more chrome spheres), whatever the decision.
    position_error : ndarray (K,) or None
        RMS miss distance of the rays to the triangulated point, same unit.
    near : bool
    near_reason : str
    method : str
    """

    directions: np.ndarray
    circles: list
    highlights: np.ndarray
    per_sphere: np.ndarray
    flags: dict = field(default_factory=dict)
    sphere_flags: list = field(default_factory=list)
    uncertainty_deg: np.ndarray = None
    residual_deg: np.ndarray = None
    targets: list = field(default_factory=list)
    kinds: list = field(default_factory=list)
    positions: np.ndarray = None
    triangulated: np.ndarray = None
    position_error: np.ndarray = None
    near: bool = False
    near_reason: str = "one chrome sphere: directional model"
    method: str = ""

    @property
    def circle(self):
        """The first (leftmost) chrome sphere's circle."""
        return self.circles[0]

    @property
    def distances(self):
        """Distance of each triangulated light from the frame origin (K,), or None."""
        return None if self.triangulated is None else np.linalg.norm(self.triangulated, axis=1)


def _grey(images):
    """Grey frames (K, H, W), and the per-pixel maximum and minimum over the colour channels."""
    images = np.asarray(images, dtype=np.float32)
    if images.ndim == 4:
        # channel by channel: numpy reduces a short last axis several times slower
        channels = [images[..., i] for i in range(images.shape[-1])]
        grey, peak, floor = channels[0].copy(), channels[0].copy(), channels[0].copy()
        for ch in channels[1:]:
            grey += ch
            np.maximum(peak, ch, out=peak)
            np.minimum(floor, ch, out=floor)
        return grey / len(channels), peak, floor
    if images.ndim == 3:
        return images, images, images
    raise InputError(f"sphere images must be (K, H, W) or (K, H, W, C), got shape {images.shape}")


def _edge_grey(frames, shape):
    """Grey (K, H, W) of ``edge_frames``, checked against the frames' ``shape``."""
    grey = _grey(frames)[0]
    if grey.shape != shape:
        raise InputError(f"edge frames: shape {grey.shape} does not match the frames {shape}")
    return grey


def _given(circle):
    """A circle or a list of circles -> list of Circle."""
    single = isinstance(circle, Circle) or np.ndim(circle) == 1
    out = []
    for c in ([circle] if single else list(circle)):
        c = c if isinstance(c, Circle) else Circle(*map(float, c), method="given")
        if not (c.r > 0 and np.isfinite(c.params).all()):
            raise InputError(f"circle: radius must be positive and finite, got {c.params.tolist()}")
        out.append(c)
    return out


def _mask_regions(mask, shape):
    """Sphere mask (H, W): bool (each connected blob one sphere) or integer labels."""
    mask = np.asarray(mask)
    if mask.shape != shape:
        raise InputError(f"sphere mask: shape {mask.shape} does not match the frames {shape}")
    values = np.unique(mask[mask > 0])
    if mask.dtype != bool and len(values) > 1:
        return [mask == v for v in values]
    labels, count = ndimage.label(mask > 0)
    regions = [labels == i for i in range(1, count + 1)]
    return [r for r in regions if r.sum() >= 20] or [mask > 0]


def _outline_grey(outline, shape):
    """Grey (H, W) float32 of the outline photo, checked against the frames' size ``shape``."""
    outline = np.asarray(outline)
    if outline.ndim not in (2, 3):
        raise InputError(f"outline photo: expected an (H, W) or (H, W, C) image, got shape {outline.shape}")
    if outline.shape[:2] != tuple(shape):
        raise InputError(f"outline photo: size {outline.shape[1]}x{outline.shape[0]} (W x H) does not match "
                         f"the frames' {shape[1]}x{shape[0]}; it must be taken from the same camera position "
                         "at the same resolution")
    grey = outline.astype(np.float32)
    if grey.ndim == 3:
        grey = grey.mean(axis=-1)
    return np.nan_to_num(grey, nan=0.0, posinf=0.0, neginf=0.0)


#: Largest shift between a sphere's circle on the outline photo and on the light frames before
#: they are taken to show different scenes: this fraction of the radius, and at least
#: OUTLINE_SHIFT_PX. The limb of a chrome ball mirrors what lies behind it, so its apparent edge
#: moves with the lighting: PSBox's room-lit photos and light frames differ by 1-2 px on 420 px
#: spheres (0.4 %), a dark limb crescent by its width. A knocked camera or sphere moves it further.
OUTLINE_SHIFT, OUTLINE_SHIFT_PX = 0.02, 3.0


def _outline_circles(outline, grey, spheres):
    """Circles found on the outline photo, labelled 'outline', checked against the frames."""
    try:
        found = find_spheres(_outline_grey(outline, grey.shape[1:]), spheres)
    except SphereNotFound as exc:
        raise SphereNotFound(f"outline photo: {exc}") from None
    for circ in found:
        _check_outline_matches(circ, grey)
    return [replace(c, method="outline") for c in found]


def _check_outline_matches(circ, grey):
    """Raise InputError when the light frames show this sphere clearly elsewhere.

    Frames whose outline is too faint to fit (a dark room, a black background) cannot be
    compared and pass: the photo is then the only outline there is.
    """
    try:
        seen = refine_circle(grey, circ)
    except SphereNotFound:
        return
    if not credible(seen, grey.shape[1:]):   # the bar find_spheres sets by default
        return
    shift = max(np.hypot(seen.cx - circ.cx, seen.cy - circ.cy), abs(seen.r - circ.r))
    if shift > max(OUTLINE_SHIFT * circ.r, OUTLINE_SHIFT_PX):
        raise InputError(f"outline photo: the sphere at ({circ.cx:.1f}, {circ.cy:.1f}) r {circ.r:.1f} px sits at "
                         f"({seen.cx:.1f}, {seen.cy:.1f}) r {seen.r:.1f} in the light frames, {shift:.1f} px "
                         "away; the camera or the sphere moved between them. Retake the photo, or calibrate "
                         "without it (psrig calibrate --no-outline)")


def _circles(grey, circle, mask, spheres, outline=None):
    """[(Circle, region mask or None)] of every sphere to consider."""
    if outline is not None:
        other = [name for name, v in (("circle", circle), ("mask", mask)) if v is not None]
        if other:
            raise InputError(f"give the sphere outlines one way only: got outline and {' and '.join(other)}")
        return [(c, None) for c in _outline_circles(outline, grey, spheres)]
    if circle is not None:
        given = _given(circle)
        for c in given:
            check_given_circle(grey, c)
        return [(c, None) for c in given]
    if mask is not None:
        found = [(circle_from_mask(r), r) for r in _mask_regions(mask, grey.shape[1:])]
        for index, (c, region) in enumerate(found):
            check_mask_disc(region, c, index)
        return found
    return [(_on_frames(grey, c), None) for c in find_spheres(sphere_image(grey), spheres)]


def _on_frames(grey, circ):
    """``circ``, found on the frames' maximum, refined on the frames (K, H, W) themselves."""
    try:
        seen = refine_circle(grey, circ)
    except SphereNotFound:
        return circ
    return seen if credible(seen, grey.shape[1:]) else circ


def _one_sphere(grey, peak, sat, circ, mask, K, background):
    """Directions, highlight centres, flags and uncertainties for one sphere (``background``
    (H, W): the per-pixel median over the frames)."""
    n_lights, h, w = grey.shape
    cx, cy, r = circ.params
    rows, cols = np.mgrid[0:h, 0:w]
    disc = np.hypot(cols - cx, rows - cy) < r
    if mask is not None:
        disc &= mask
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
        # the centre of mirror directions, not of pixels, stays unbiased where the sphere
        # foreshortens the lobe; a robust centre, not a mean, so a flare streak or a scratch
        # joined to the highlight does not pull it along
        d = robust_centre(mirror(normals[ok], views[ok]), blob.weights[ok])
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


def calibrate_sphere(images, circle=None, mask=None, *, saturation=None, K=None, spheres=None, outline=None,
                     edge_frames=None):
    """Light directions (and positions with two chrome spheres) from sphere frames.

    Parameters
    ----------
    images : ndarray (K, H, W) or (K, H, W, C)
        One frame per light, float linear (gamma-encoded data works too).
    circle : (cx, cy, r), list of them, or None
        Sphere outline(s) in pixels (0-based, x = column, y = row downward); found when None.
    mask : ndarray (H, W) bool or int or None
        Sphere pixels (one connected blob, or one label, per sphere); gives the circles and
        limits the highlight search.
    saturation : ndarray (K, H, W) bool or None
        Saturated pixels per frame; guessed from the data's clip level when None.
    K : ndarray (3, 3) or None
        Intrinsics for per-pixel view rays (perspective); orthographic when None.
    spheres : int or None
        How many spheres (chrome and matte) to find when no circle is given; None finds
        every credible one.
    outline : ndarray (H, W) or (H, W, C) or None
        An evenly (room-)lit photo of the sphere(s) from the same camera position, same size
        as the frames, any scale (linear or gamma-encoded). Used only to find the sphere
        circles: under even light the whole limb contrasts with the background, while in the
        light frames a dark rim or the stand can pull the outline off by pixels. The chrome or
        matte kind of each sphere is still decided on the frames. None (default) finds the
        circles on the frames. Not together with ``circle`` or ``mask``.
    edge_frames : ndarray (K, H, W) or (K, H, W, C) or None
        The same frames on the scale to find the sphere outlines on, when that is not the
        scale of ``images``: for 8-bit photos decoded to linear, their display-encoded values,
        on which the camera sharpened the edges. None (default): ``images``.

    Returns
    -------
    SphereCalibration

    Raises
    ------
    SphereNotFound
        No sphere, or no chrome sphere among those found.
    InputError
        The outline photo's size differs from the frames', or it comes with ``circle`` or
        ``mask``; a mask blob is not a disc, the frames contradict a given circle, or a
        highlight lies outside a given circle or mask (:mod:`calibration.sanity`).
    """
    grey, peak, floor = _grey(images)
    K = check_K(K)
    if saturation is None:
        # clipped where every channel is: a white light's highlight clips in all of them, while
        # a pixel clipped in one channel only is a coloured fringe (chromatic aberration, flare,
        # JPEG chroma subsampling) that would drag the clipped core off centre
        sat = floor >= saturation_level(peak)
    else:
        sat = np.asarray(saturation, bool)
        if sat.shape != grey.shape:
            raise InputError(f"saturation masks: shape {sat.shape} does not match the frames {grey.shape}")
    found = _circles(grey if edge_frames is None else _edge_grey(edge_frames, grey.shape), circle, mask,
                     spheres, outline)
    kinds, chrome, targets = [], [], []
    for circ, region in found:
        kind, share = sphere_kind(grey, circ.params)
        kinds.append({**circ.as_dict(), "kind": kind, "lit_share": round(share, 4)})
        (chrome if kind == "chrome" else targets).append((circ, region))
    if not chrome:
        raise SphereNotFound(f"no chrome sphere among the {len(found)} sphere(s) in view: each is shaded "
                             "broadly like a matte target; give the chrome sphere with --circle")
    background = np.median(grey, axis=0)   # per pixel over the frames: once for every sphere
    for c, region in chrome:
        if c.method in ("given", "mask"):
            check_highlights_inside(grey, background, c, region)
    parts = [_one_sphere(grey, peak, sat, c, region, K, background) for c, region in chrome]
    result = _combine(parts, [c for c, _ in chrome], K)
    result.targets, result.kinds = [c for c, _ in targets], kinds
    if len(chrome) > 1:
        _add_positions(result, K, grey.shape[1:])
    return result


def _combine(parts, circles, K):
    """Merge the chrome spheres' directions: the mean over the spheres that saw a light well."""
    per = np.stack([p[0] for p in parts])
    sphere_flags = [p[2] for p in parts]
    bad = np.array([[k in f for k in range(per.shape[1])] for f in sphere_flags])
    use = np.where(bad.all(0)[None, :, None], per, np.where(bad[..., None], np.nan, per))
    mean = np.nanmean(use, axis=0) if np.isfinite(use).any() else use[0]
    norm = np.linalg.norm(mean, axis=1, keepdims=True)
    directions = np.divide(mean, norm, out=np.full_like(mean, np.nan), where=norm > 0)
    flags = {}
    for k in np.flatnonzero(bad.all(0)):
        reasons = [f[k] for f in sphere_flags]
        flags[int(k)] = reasons[0] if len(parts) == 1 else "; ".join(
            f"sphere {s}: {why}" for s, why in enumerate(reasons))
    stacked = np.stack([p[3] for p in parts])
    # a light no sphere saw has no uncertainty (NaN, and it is flagged), not a warning
    unc = np.fmax.reduce(stacked, axis=0)   # NaN only where every sphere has NaN
    method = (("perspective" if K is not None else "orthographic")
              + f" chrome sphere x{len(circles)}, direction-weighted highlight")
    return SphereCalibration(directions, circles, np.stack([p[1] for p in parts]), per, flags,
                             sphere_flags, uncertainty_deg=unc, residual_deg=unc.copy(), method=method)


def _centre(circle, K):
    """Sphere centre (3,) in the frame of the triangulation."""
    if K is None:
        return np.array([circle.cx, -circle.cy, 0.0])
    return sphere_centre(circle.params, K)


def _add_positions(result, K, shape):
    """Triangulate light positions from the chrome spheres' rays and decide near or far."""
    starts, rays = [], []
    for s, circ in enumerate(result.circles):
        spots = result.highlights[s]
        starts.append(sphere_points(spots[:, 0], spots[:, 1], circ.params, K)[2])
        rays.append(result.per_sphere[s])
    starts, rays = np.stack(starts), np.stack(rays)
    if K is None:
        starts = starts - frame_offset(shape)
    cos = np.clip((rays[0] * rays[1]).sum(-1), -1, 1)
    result.residual_deg = np.degrees(np.arccos(cos))
    result.triangulated, result.position_error = triangulate(starts, rays)
    centres = np.array([_centre(c, K) for c in result.circles])
    baseline = float(np.max(np.linalg.norm(centres[:, None] - centres[None], axis=-1)))
    near, conditioned, reason = near_decision(result.triangulated, starts, rays, result.residual_deg,
                                              result.uncertainty_deg, baseline)
    # a ray a sphere doubts would drag the meeting point: such lights get no position
    conditioned &= ~np.array([any(k in f for f in result.sphere_flags) for k in range(len(conditioned))])
    result.near, result.near_reason = near, ("near point lights: " if near else "directional lights: ") + reason
    if not near:
        return
    result.positions = np.where(conditioned[:, None], result.triangulated, np.nan)
    norm = np.linalg.norm(result.positions, axis=1, keepdims=True)
    result.directions = np.where(conditioned[:, None], result.positions / norm, result.directions)
    for k in np.flatnonzero(~conditioned):
        why = ", ".join(f"sphere {s}: {f[k]}" for s, f in enumerate(result.sphere_flags) if k in f)
        result.flags.setdefault(int(k), "position not triangulated" + (f" ({why})" if why else
                                                                        " (rays do not converge)"))
    result.method += ", near lights triangulated from the spheres"


def calibrate_lights(images, circle=None, mask=None, *, outline=None, on_flag="raise", **options):
    """Unit light directions (K, 3), camera frame, from chrome-sphere frames.

    A thin wrapper of :func:`calibrate_sphere` (same parameters; ``outline`` is an evenly lit
    photo (H, W) or (H, W, C) the sphere circles are found on). When a light is flagged (no
    highlight, two highlights, an overexposed blob, a highlight on the rim), ``on_flag='raise'``
    (default) raises :class:`CalibrationError` naming the frames and reasons; ``on_flag='nan'``
    returns those rows as NaN instead. A flagged direction is never returned as if it were good.
    """
    if on_flag not in ("raise", "nan"):
        raise InputError(f"on_flag: expected 'raise' or 'nan', got {on_flag!r}")
    result = calibrate_sphere(images, circle, mask, outline=outline, **options)
    directions = result.directions.copy()
    if result.flags:
        if on_flag == "raise":
            listed = "; ".join(f"frame {k}: {why}" for k, why in sorted(result.flags.items()))
            raise CalibrationError(f"{len(result.flags)} light(s) could not be calibrated: {listed}")
        directions[sorted(result.flags)] = np.nan
    return directions
