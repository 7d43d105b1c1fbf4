"""Specular anchoring of the light cone: the mirror geometry fixes what the diffuse fit cannot.

With lights in a narrow cone around the camera (DiLiGenT: polar angles <= 43 degrees), a
pixel's slant and the falloff of its diffuse reflectance trade off: a normal a few degrees too
slanted with a slightly different falloff (or, equally, light directions whose polar angles are
a few percent off) fits the observations as well as the truth. Measured on DiLiGenT ball: the
Lambertian fit on GT-chosen diffuse observations is already +1.4 degrees too slanted, the
biquadratic fits keep that bias, and the shared-shape residual is 2 x lower at the biased
normals than at the ground truth, so no least-squares refinement removes it.

A sharp specular peak is a cue that does not depend on the diffuse model: at the peak the
normal is the half vector h = unit(l + v) (Drbohlav and Sara 2002 use the same cue to remove
the bas-relief ambiguity of uncalibrated photometric stereo). Where the object shows sharp
highlights, this module measures the median difference between the slant of the estimated
normals and the slant of their specular-peak centroids, and finds the one global correction
that removes it: a scale ``f`` of the lights' polar angles about the view axis (the error mode
that both a chrome-sphere calibration and the slant/falloff ambiguity leave). The correction
is accepted only when the mismatch responds to ``f`` as a global error does (a root inside
``[1 - max_change, 1 + max_change]``); a local bias (e.g. a broad lobe that the biquadratic
absorbs near the highlight only) gives no such root and the lights are left unchanged.

What it recovers on DiLiGenT ball and on synthetic spheres, and where it rightly leaves the lights
unchanged: docs/photometric-stereo.md, step 6.

Functions here are vectorised over pixels; :func:`pipeline.photometric.estimate_normals` calls
them (option ``specular_anchor``). The mismatch is measured on each chunk while its
observations are in memory: about 1 % more CPU time when nothing is corrected.
"""

import numpy as np

from ..core.errors import InputError
from .model import half_vectors

__all__ = ["scale_cone", "highlight_mismatch", "first_verdict", "anchor_scale", "anchor_wanted", "root_range",
           "MIN_PEAK", "LOBE_DEG", "MIN_PIXELS", "MAX_CHANGE", "PROBE_STEP", "MAX_LOBE_DEG", "RESAMPLES"]

MIN_PEAK = 2.0      # highlight: the brightest near-mirror observation is >= 2 x the diffuse fit
LOBE_DEG = 12.0     # window around the normal (in half-vector angle) holding the peak's lights
#: a highlight counts only when its lobe (the fitted Gaussian's width) is at most this sharp,
#: degrees: only there is the peak at the half vector; broader lobes peak off it and would
#: scale exact lights (docs/photometric-stereo.md, "Constants").
MAX_LOBE_DEG = 3.5
MIN_PIXELS = 50     # highlight pixels needed for a median worth acting on
MAX_CHANGE = 0.10   # accepted scales: 0.9 .. 1.1 (larger is not a calibration-size error)
PROBE_STEP = 0.05   # second evaluation at 1 +- this, for the secant
TOL_DEG = 0.05      # mismatch left alone (synthetic, true lights: |median| <= 0.01 deg)
#: resamples of the highlight pixels behind the correction's range (``cone_scale_range``)
RESAMPLES = 200


def scale_cone(lights, scale):
    """Light directions (K, 3) with their polar angles about the view axis (+z) times ``scale``.

    Azimuths are kept; ``scale`` 1 returns the input unchanged.
    """
    lights = np.asarray(lights, float)
    if scale == 1.0:
        return lights
    polar = np.arccos(np.clip(lights[:, 2], -1.0, 1.0)) * scale
    azimuth = np.arctan2(lights[:, 1], lights[:, 0])
    return np.stack([np.sin(polar) * np.cos(azimuth), np.sin(polar) * np.sin(azimuth), np.cos(polar)], axis=1)


def highlight_mismatch(obs, b, lights, min_peak=MIN_PEAK, lobe_deg=LOBE_DEG, valid=None, max_lobe_deg=MAX_LOBE_DEG,
                       rows=False):
    """Slant of the estimated normal minus slant of its specular-peak centroid, per pixel (deg).

    Parameters
    ----------
    obs : ndarray (N, K)
        Intensities.
    b : ndarray (N, 3)
        Estimated albedo-scaled normals (the diffuse fit); zero rows are skipped.
    lights : ndarray (K, 3)
        Unit light directions shared by all pixels; the view is +z.
    min_peak : float
        A pixel is a highlight pixel when its brightest observation within ``lobe_deg`` of the
        mirror direction is at least ``min_peak`` x the diffuse prediction albedo x (n . l).
    lobe_deg : float
        Half-vector window around the normal, degrees. Only pixels whose whole window lies
        inside the lights' half-vector cone are used, so that the window is not cut on one
        side (which would pull the centroid inward).
    valid : ndarray (N, K) bool, optional
        False for observations not to use (saturated ones).
    max_lobe_deg : float
        Widest lobe counted (:data:`MAX_LOBE_DEG`).
    rows : bool
        Also return the rows (P,) of the pixels that show a peak (before the lobe-width test):
        the pixels a probe of other lights needs to solve again.

    Returns
    -------
    ndarray (M,)
        Degrees, for the M highlight pixels (positive: the estimate is too slanted).

    Notes
    -----
    The peak is located by the centroid of the half vectors weighted by the upper half of the
    specular excess (observation minus diffuse prediction, minus half its maximum), so that a
    residual diffuse gradient across the window does not shift it; the value returned is its
    slant difference to the centroid that a Gaussian lobe of the fitted width centred on the
    estimated normal gives through the same lights (the light layout's sampling bias cancels).
    """
    h, _ = half_vectors(lights)
    albedo = np.linalg.norm(b, axis=1)
    cos_lobe = np.cos(np.radians(lobe_deg))
    # The window must fit in the half-vector cone: slant(n) < max slant(h) - lobe.
    max_h = np.degrees(np.arccos(np.clip(h[:, 2], -1, 1))).max()
    nz = np.where(albedo > 0, b[:, 2] / np.maximum(albedo, 1e-300), -1.0)
    inner = np.flatnonzero(nz > np.cos(np.radians(max_h - lobe_deg)))   # cheap prefilter
    if inner.size == 0:
        return (np.zeros(0), inner) if rows else np.zeros(0)
    n = b[inner] / albedo[inner, None]
    diffuse = np.maximum(n @ lights.T, 0.0) * albedo[inner, None]
    near = (n @ h.T) > cos_lobe
    if valid is not None:
        near &= valid[inner]
    excess = np.where(near, obs[inner] - diffuse, 0.0)
    ratio = np.where(near & (diffuse > 0), obs[inner] / np.maximum(diffuse, 1e-300), 0.0)
    peak = ratio.max(axis=1) >= min_peak
    n, window, excess = n[peak], near[peak], excess[peak]
    data = _half_max_centroid(excess, h)
    # The same lights seen by a symmetric lobe centred on n: the sampling bias of the light
    # layout (which the median over pixels does not average out, as all pixels share it) is
    # common to both centroids and cancels in their difference.
    width2 = _lobe_width2(excess, data, h)
    angle2 = np.arccos(np.clip(n @ h.T, -1, 1)) ** 2
    model = _half_max_centroid(np.where(window, np.exp(-angle2 / (2 * width2[:, None])), 0.0), h)
    ok = np.isfinite(width2) & (width2 <= np.radians(max_lobe_deg) ** 2) & (np.linalg.norm(data, axis=1) > 0) \
        & (np.linalg.norm(model, axis=1) > 0)
    mismatch = _slant(model[ok]) - _slant(data[ok])
    return (mismatch, inner[peak]) if rows else mismatch


def _half_max_centroid(weights, h):
    """Centroid direction (M, 3) of the half vectors weighted by the part of ``weights`` (M, K)
    above half their maximum: the lobe's top, which a residual diffuse gradient barely shifts."""
    top = np.maximum(weights - 0.5 * weights.max(axis=1, keepdims=True), 0.0)
    centroid = top @ h
    return centroid / np.maximum(np.linalg.norm(centroid, axis=1, keepdims=True), 1e-300)


def _lobe_width2(excess, centre, h):
    """Squared angular width (rad^2, (M,)) of a Gaussian lobe fitted to the excess around ``centre``.

    Least squares of log(excess / max) on the squared angle from the centre, over the
    observations above a tenth of the maximum; NaN where the fit is not a decaying lobe.
    """
    peak = excess.max(axis=1, keepdims=True)
    use = excess > 0.1 * peak
    t = np.arccos(np.clip(centre @ h.T, -1, 1)) ** 2
    v = np.log(np.where(use, excess, 1.0) / np.maximum(peak, 1e-300))
    count = np.maximum(use.sum(axis=1), 1)
    t_mean = np.sum(use * t, axis=1) / count
    v_mean = np.sum(use * v, axis=1) / count
    dt = np.where(use, t - t_mean[:, None], 0.0)
    slope = np.sum(dt * (v - v_mean[:, None]), axis=1) / np.maximum(np.sum(dt * dt, axis=1), 1e-300)
    return np.where((slope < 0) & (use.sum(axis=1) >= 3), -0.5 / np.where(slope < 0, slope, -1.0), np.nan)


def _slant(v):
    return np.degrees(np.arccos(np.clip(v[:, 2], -1, 1)))


def first_verdict(mismatch, min_pixels=MIN_PIXELS, tol=TOL_DEG):
    """What the mismatches (M,) of a solve at the nominal lights say, before any probe.

    Returns the info dict of :func:`anchor_scale` with ``anchor`` 'no highlights' (fewer than
    ``min_pixels``), 'consistent' (median within ``tol`` degrees) or 'to correct' (probe next).
    Tiled solves (:mod:`pipeline.photometric.tiles`) use it to decide without a second pass.
    """
    mismatch = np.asarray(mismatch, float)
    info = {"cone_scale": 1.0, "highlight_pixels": int(mismatch.size), "mismatch_deg": float("nan")}
    if mismatch.size < min_pixels:
        return dict(info, anchor="no highlights")
    info["mismatch_deg"] = float(np.median(mismatch))
    return dict(info, anchor="consistent" if abs(info["mismatch_deg"]) <= tol else "to correct")


def anchor_scale(solve, lights, min_pixels=MIN_PIXELS, max_change=MAX_CHANGE, step=PROBE_STEP, tol=TOL_DEG,
                 probe=None):
    """The light-cone scale that makes normals agree with their specular peaks, and the result.

    Parameters
    ----------
    solve : callable
        ``solve(lights) -> (result, mismatch)``: runs the normal estimation with the given
        (K, 3) lights and returns its result and :func:`highlight_mismatch` values (M,).
    lights : ndarray (K, 3)
    probe : callable, optional
        ``probe(lights) -> mismatch`` (M,): the mismatches at other lights from a cheaper solve
        (the pixels that peaked, the first solve's context); default: a full ``solve``.

    Returns
    -------
    result
        The result of the accepted lights (the nominal ones if no correction is accepted).
    info : dict
        ``cone_scale`` (1.0 when not corrected), ``highlight_pixels``, ``mismatch_deg`` (median
        at the nominal lights, NaN without highlights), ``anchor`` (why: 'no highlights',
        'consistent', 'no global root', 'corrected'); when corrected also ``cone_scale_range``
        (:func:`root_range`), ``probe_mismatch_deg`` and ``final_mismatch_deg``.

    Notes
    -----
    Two evaluations: the nominal lights and 1 +- ``step`` (the probe); the secant root of the
    median mismatch must lie within ``max_change`` of 1, and the mismatch must fall as the
    scale rises (the sign a global error gives). Then a second solve at the root
    (:func:`pipeline.photometric.estimate_normals` keeps the first solve's selection of
    observations for that solve).
    """
    result, mismatch = solve(lights)
    info = first_verdict(mismatch, min_pixels, tol)
    if info["anchor"] != "to correct":
        return result, info
    d0 = info["mismatch_deg"]
    probed = 1.0 + step * np.sign(d0)
    probe_mismatch = probe(scale_cone(lights, probed)) if probe else solve(scale_cone(lights, probed))[1]
    if probe_mismatch.size < min_pixels:
        return result, dict(info, anchor="no global root")
    d1 = float(np.median(probe_mismatch))
    slope = (d1 - d0) / (probed - 1.0)
    root = 1.0 - d0 / slope if slope < 0 else np.inf
    if not abs(root - 1.0) <= max_change:
        return result, dict(info, anchor="no global root", probe_mismatch_deg=d1)
    spread = root_range(mismatch, probe_mismatch, probed, max_change)
    final, final_mismatch = solve(scale_cone(lights, root))
    left = float(np.median(final_mismatch)) if final_mismatch.size else float("nan")
    return final, dict(info, cone_scale=float(root), anchor="corrected", probe_mismatch_deg=d1,
                       final_mismatch_deg=left, cone_scale_range=spread)


def root_range(mismatch, probe_mismatch, probed, max_change=MAX_CHANGE, draws=RESAMPLES, seed=0):
    """How well the highlight pixels fix the secant's root: its 16th and 84th percentiles over
    resamples of the pixels (list of two floats, within ``1 +- max_change``).

    Each solve's mismatches (M,) are resampled on their own; the two sets share most pixels,
    whose mismatches move together, so the range is if anything too wide. A resample whose
    mismatch does not fall as the scale rises counts as a root at the far end of the range.
    """
    rng = np.random.default_rng(seed)
    d0 = np.median(rng.choice(np.asarray(mismatch, float), (draws, len(mismatch))), axis=1)
    d1 = np.median(rng.choice(np.asarray(probe_mismatch, float), (draws, len(probe_mismatch))), axis=1)
    slope = (d1 - d0) / (probed - 1.0)
    far = 1.0 + max_change * np.sign(d0)
    with np.errstate(divide="ignore", invalid="ignore"):
        roots = np.where(slope < 0, 1.0 - d0 / slope, far)
    roots = np.clip(roots, 1.0 - max_change, 1.0 + max_change)
    return [float(v) for v in np.percentile(roots, [16, 84])]


def anchor_wanted(wants, specular_anchor, options, lights, near):
    """Whether to anchor the light cone on specular peaks (this module); ``wants`` is the
    method's ``wants_anchor`` (:func:`pipeline.photometric.methods.method_traits`).

    'auto': for a method that wants it (its ``wants_anchor``: the biquadratic) with robust selection (the narrow-cone case, where the
    slant is nearly ambiguous) and directional lights shared by all pixels. True: for any
    method, still only with shared directional lights (the correction scales their polar
    angles). False: never.
    """
    if specular_anchor not in ("auto", True, False):
        raise InputError(f"specular_anchor must be 'auto', True or False, got {specular_anchor!r}")
    if near is not None or np.asarray(lights).ndim != 2 or specular_anchor is False:
        return False
    # 'auto' follows the narrow-cone default path only: robust selection (no explicit t_low)
    return specular_anchor is True or (wants and options.get("selection") == "robust"
                                       and options.get("t_low") is None)
