"""Each pixel's expected angular error: a calibrated uncertainty map of the normals.

A user capturing their own object has no ground truth; this map says which normals to believe.
It combines what the fit knows at each pixel:

- ``linearised``: the angle a Lambertian fit's normal moves under noise the size of the
  pixel's residual against its albedo, through the conditioning of the lights it used
  (:func:`pipeline.photometric.lambert.normal_leverage`), in degrees;
- ``neighbours``: the angle between the normal and the mean normal of its 5 x 5 neighbourhood,
  in degrees (a pixel alone against its neighbours is often one whose observations misled it);
- both again averaged (in logarithms) over the 7 x 7 pixels around: errors come in regions
  (interreflections, penumbrae, a specular lobe), which a single pixel's residual undersells;
- ``outline``: closeness to the mask's outline (mixed pixels and grazing observations);
- ``used``: how many observations the fit kept; ``slant``: 1 - n_z of the normal.

They are combined by a log-linear model whose constants (:data:`COEFFICIENTS`) were fitted
once, by least squares on the log of the actual error (each object weighted alike), on the
DiLiGenT ball, cat and reading with 96 lights and five 10-light subsets each, saturated
observations left out as ``psrig decode`` does, and frozen: nothing is fitted per session.
``python benchmarks/uncertainty.py --fit`` refits them and prints how well the frozen ones rank
and calibrate, and the leave-one-object-out check (docs/photometric-stereo.md, "Uncertainty").
"""

import numpy as np

from ..settings.normals import UNCERTAIN_DEG

__all__ = ["COEFFICIENTS", "FEATURES", "MIN_LIGHTS", "UNCERTAIN_DEG", "uncertainty_features", "predict_uncertainty",
           "design_matrix", "uncertainty_map", "uncertainty_summary", "roc_auc", "agreement", "agreement_text"]

#: Fewer lights than this: the uncertainty is not estimated (a fit of 3 lights leaves no
#: residual to measure the noise by).
MIN_LIGHTS = 4
#: Half-width of the neighbourhood whose mean normal a pixel is compared with (5 x 5).
NEIGHBOUR_RADIUS = 2
#: Side of the window over which the log terms are averaged (7 x 7).
AREA = 7
#: Pixels within this distance of the mask's outline count as on it (see ``outline``).
OUTLINE_PX = 4.0
#: Floor (degrees) under the angles before their logarithm: below it, differences are noise.
FLOOR_DEG = 0.1
#: Names of the model's terms, in the order of :data:`COEFFICIENTS` (after the intercept).
FEATURES = ("log_linearised", "log_neighbours", "outline", "log_used", "slant", "area_log_linearised",
            "area_log_neighbours")
#: The frozen model: log(expected error in degrees) = c0 + sum_i c_i x_i over :data:`FEATURES`.
COEFFICIENTS = (0.834, 0.18, 0.131, 0.431, 0.149, -0.214, 0.257, 0.349)


def _box_mean(values, has, size):
    """Mean of ``values`` over the pixels of ``has`` in each size x size window (H, W)."""
    from scipy.ndimage import uniform_filter

    weight = uniform_filter(has.astype(np.float64), size, mode="constant")
    total = uniform_filter(np.where(has, values, 0.0), size, mode="constant")
    return total / np.maximum(weight, 1e-12)


def _neighbour_angle(normals, has):
    """Angle (degrees, (H, W)) between each normal and the mean unit normal of its 5 x 5
    neighbours that have one (itself included)."""
    from scipy.ndimage import uniform_filter

    size = 2 * NEIGHBOUR_RADIUS + 1
    summed = np.stack([uniform_filter(np.where(has, normals[..., i], 0.0), size, mode="constant")
                       for i in range(3)], axis=-1)
    norm = np.linalg.norm(summed, axis=-1)
    cos = np.sum(normals * summed, axis=-1) / np.where(norm > 0, norm, 1.0)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def uncertainty_features(normals, status, residual, leverage, mask, used=None):
    """The model's terms at every pixel with a normal.

    Parameters
    ----------
    normals : ndarray (H, W, 3)
        Unit normals (zero where there is none).
    status : ndarray (H, W) uint8
        Codes of :data:`pipeline.photometric.STATUS` (kept for the record; the terms do not
        use it).
    residual : ndarray (H, W)
        RMS residual over the used observations, relative to the albedo.
    leverage : ndarray (H, W)
        :func:`pipeline.photometric.lambert.normal_leverage` (radians per unit relative noise).
    mask : ndarray (H, W) bool
    used : ndarray (H, W), optional
        Observations each pixel's fit used (none given: the ``log_used`` term is 0).

    Returns
    -------
    has : ndarray (H, W) bool
        Pixels with a normal whose terms are all finite.
    features : dict of name -> ndarray (H, W) float64
        :data:`FEATURES`: logs of degrees, ``outline`` in [0, 1] (1 on the outline, falling off
        over :data:`OUTLINE_PX`), ``log_used`` the log of the count, ``slant`` 1 - n_z.
    """
    from scipy.ndimage import distance_transform_edt

    normals = np.asarray(normals, dtype=np.float64)
    has = mask & (np.linalg.norm(normals, axis=-1) > 0) & np.isfinite(leverage) & np.isfinite(residual)
    linearised = np.log(np.maximum(np.degrees(np.where(has, residual * leverage, 0.0)), FLOOR_DEG))
    neighbours = np.log(np.maximum(_neighbour_angle(normals, has), FLOOR_DEG))
    # distance to the nearest pixel outside the mask; a mask touching the image's border is
    # not an outline there (the crop, not the surface, ends)
    distance = distance_transform_edt(np.pad(mask, 1, constant_values=True))[1:-1, 1:-1]
    count = np.zeros(mask.shape) if used is None else np.log(np.maximum(np.asarray(used, np.float64), 1.0))
    return has, {"log_linearised": linearised, "log_neighbours": neighbours,
                 "outline": np.clip(1.0 - (distance - 1.0) / OUTLINE_PX, 0.0, 1.0),
                 "log_used": count, "slant": 1.0 - normals[..., 2],
                 "area_log_linearised": _box_mean(linearised, has, AREA),
                 "area_log_neighbours": _box_mean(neighbours, has, AREA)}


def design_matrix(features, where):
    """(N, 1 + len(FEATURES)) rows of the model's terms at ``where`` (H, W) bool."""
    return np.stack([np.ones(int(where.sum()))] + [features[name][where] for name in FEATURES], axis=1)


def predict_uncertainty(features, has, coefficients=COEFFICIENTS):
    """Expected angular error (degrees, (H, W) float32; NaN where not ``has``)."""
    out = np.full(has.shape, np.nan, np.float32)
    out[has] = np.exp(design_matrix(features, has) @ np.asarray(coefficients, dtype=np.float64))
    return out


def uncertainty_map(normals, status, residual, leverage, mask, lights, used=None):
    """The expected angular error map, or None with the reason when it cannot be estimated.

    Parameters
    ----------
    normals, status, residual, leverage, mask, used
        As :func:`uncertainty_features` takes them.
    lights : int
        How many lights the session solved with.

    Returns
    -------
    uncertainty : ndarray (H, W) float32 or None
        Degrees; NaN where there is no normal.
    reason : str or None
        Why there is no map.
    """
    if lights < MIN_LIGHTS:
        return None, f"not estimated: {lights} light(s), at least {MIN_LIGHTS} are needed to measure the fit's noise"
    if leverage is None or not np.isfinite(leverage[mask]).any():
        return None, "not estimated: the method reports no conditioning of its observations"
    out = np.full(mask.shape, np.nan, np.float32)
    for band, inner, window in _bands(mask):
        terms = [None if a is None else a[band] for a in (normals, status, residual, leverage, mask, used)]
        has, features = uncertainty_features(*terms)
        out[window] = predict_uncertainty(features, has)[inner]
    return out, None


#: rows of the map made at once: its float64 terms are about 150 bytes a pixel, which in one
#: piece came on top of the stack at the normals stage's peak
BAND_ROWS = 256
#: rows and columns of context around a band: the 7 x 7 mean of the 5 x 5 neighbour angle needs
#: 5, the outline term the distance to the mask's edge up to OUTLINE_PX + 1
HALO = 6


def _bands(mask):
    """(band, inner, window) slices covering the mask's bounding box in BAND_ROWS rows: ``band``
    with HALO rows and columns of context (within the image), ``inner`` the band's own pixels
    within it, ``window`` where they go in the image. Every term at a band's own pixels is the
    whole image's (a nearer edge of the mask than HALO is inside the band; uniform filters differ
    at most in rounding)."""
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    if rows.size == 0:
        return
    height, width = mask.shape
    c0, c1 = max(cols[0] - HALO, 0), min(cols[-1] + 1 + HALO, width)
    for r0 in range(rows[0], rows[-1] + 1, BAND_ROWS):
        r1 = min(r0 + BAND_ROWS, rows[-1] + 1)
        b0, b1 = max(r0 - HALO, 0), min(r1 + HALO, height)
        yield ((slice(b0, b1), slice(c0, c1)), (slice(r0 - b0, r1 - b0), slice(None)),
               (slice(r0, r1), slice(c0, c1)))


def uncertainty_summary(uncertainty, mask, threshold=UNCERTAIN_DEG):
    """Shares of the pixels with a normal expected within 5 degrees and over ``threshold``
    (fractions), and how many pixels have an estimate."""
    values = uncertainty[mask & np.isfinite(uncertainty)]
    if values.size == 0:
        return {"pixels": 0, "within_5": 0.0, "over_threshold": 0.0, "threshold_deg": float(threshold)}
    return {"pixels": int(values.size), "within_5": float(np.mean(values <= 5.0)),
            "over_threshold": float(np.mean(values > threshold)), "threshold_deg": float(threshold),
            "median_deg": float(np.median(values))}


def roc_auc(score, positive):
    """Area under the ROC curve of ``score`` (N,) for telling ``positive`` (N,) bool from the
    rest (ties count half); NaN when either class is empty."""
    from scipy.stats import rankdata

    n_pos, n_neg = int(positive.sum()), int((~positive).sum())
    if n_pos == 0 or n_neg == 0:
        return float("nan")
    ranks = rankdata(score)
    return float((ranks[positive].sum() - n_pos * (n_pos + 1) / 2) / (n_pos * n_neg))


def agreement(predicted, actual, bad_deg=UNCERTAIN_DEG, bins=5, floor_deg=1.0, min_bad_share=0.01):
    """How well predicted errors agree with actual ones (both degrees, (N,), finite).

    Returns
    -------
    dict
        ``bad_share``: the share of pixels more than ``bad_deg`` off; ``auc``: the ROC AUC of
        the predicted error for telling them from the rest, or None when they are under
        ``min_bad_share`` of the pixels (too few to judge by); ``bins``: per fifth of the pixels
        by predicted error, its median predicted and median actual error (each at least
        ``floor_deg``) and their ratio; ``calibrated_bins``: how many ratios are within a
        factor of 2.
    """
    predicted, actual = np.asarray(predicted, np.float64), np.asarray(actual, np.float64)
    bad = actual > bad_deg
    auc = roc_auc(predicted, bad) if bad.mean() >= min_bad_share else None
    order = np.argsort(predicted, kind="stable")
    rows = []
    for part in np.array_split(order, bins):
        if part.size == 0:
            continue
        p = max(float(np.median(predicted[part])), floor_deg)
        a = max(float(np.median(actual[part])), floor_deg)
        rows.append({"predicted_deg": round(p, 3), "actual_deg": round(a, 3), "ratio": round(a / p, 3)})
    return {"pixels": int(predicted.size), "bad_deg": float(bad_deg), "bad_share": float(bad.mean()),
            "auc": auc, "bins": rows, "calibrated_bins": sum(0.5 <= r["ratio"] <= 2.0 for r in rows)}


def agreement_text(found):
    """:func:`agreement`'s result as ``psrig eval`` and the report say it: the AUC for the badly
    off pixels and the five bins' expected / actual median errors."""
    bad = f"pixels over {found['bad_deg']:g} deg ({found['bad_share']:.1%})"
    auc = f"AUC {found['auc']:.3f} for {bad}" if found["auc"] is not None else \
        f"AUC not judged: {bad}, under 1 %"
    bins = ", ".join(f"{b['predicted_deg']:.1f}/{b['actual_deg']:.1f}" for b in found["bins"])
    return (f"{auc}; expected/actual median error per fifth of the pixels (deg): {bins}; "
            f"within x2 in {found['calibrated_bins']} of {len(found['bins'])}")
