"""Each frame's light direction checked against the images: a wrong order of frames or lights,
a light that moved.

Given the albedo-scaled normals b (N, 3) of many pixels (the robust Lambertian fit of all the
frames, in which one wrong frame is a small minority), a frame's own observations o (N,)
determine its light: o = b . l, a linear least-squares problem in l (3,) alone. Where that
direction lies far from the light file's and also explains the frame much better, the frame's
light is not where the file says: frames and light file in different orders (two lights
swapped, a natural against a plain sort), a light that moved after calibration.

With the right lights the estimate lands within a few degrees of the file's, and a swapped
frame's on the other frame's direction, explaining its frame many times better
(docs/photometric-stereo.md). Hence a frame is said to be
off when both hold: :data:`DIRECTION_TOL` and :data:`RESIDUAL_RATIO`. Nothing is changed (with
96 lights the robust selection keeps a swapped pair out at most pixels, and with 12 leaving the
pair out did not help); the normals stage names the frames.
"""

import numpy as np

__all__ = ["check_directions", "estimate_directions", "column_quantiles", "DIRECTION_TOL", "RESIDUAL_RATIO", "SWAP_TOL",
           "MIN_DIRECTION_EVIDENCE"]

#: a frame's light is off when the images put it more than this many degrees from the file's ...
DIRECTION_TOL = 5.0
#: ... and that direction's median residual is this many times smaller than the file's
RESIDUAL_RATIO = 2.0
#: two off frames are swapped when each one's estimate is within this of the other's direction (deg)
SWAP_TOL = 3.0
#: sampled pixels a frame must light to be judged
MIN_DIRECTION_EVIDENCE = 20


def estimate_directions(obs, base, b, iterations=3, k=2.5):
    """Each frame's light (K, 3) from the fitted ``b`` (N, 3): robust least squares of o = b . l.

    ``obs`` (N, K) observations, ``base`` (N, K) their non-shadowed ones (the ones used).
    After the first fit, each of the ``iterations`` - 1 more keeps the observations within ``k``
    robust standard deviations (MAD) of the last estimate. Not normalised: the length is the
    frame's gain; NaN for a frame whose pixels do not determine it.
    """
    lit = base > 0
    outer = (b[:, :, None] * b[:, None, :]).reshape(len(b), 9)
    found = _weighted_fit(obs, lit.astype(float), b, outer)
    for _ in range(iterations - 1):
        residual = np.abs(obs - b @ np.nan_to_num(found).T)
        (median,) = column_quantiles(residual, lit, dtype=np.float32)
        scale = 1.4826 * median
        found = _weighted_fit(obs, (lit & (residual <= k * np.maximum(scale, 1e-12))).astype(float), b, outer)
    return found


def _weighted_fit(obs, weights, b, outer):
    # BLAS products: einsum over three operands loops in Python-speed C
    normal = (weights.T @ outer).reshape(-1, 3, 3)
    rhs = (weights * obs).T @ b
    ok = np.linalg.det(normal) > 1e-12 * np.maximum(np.trace(normal, axis1=1, axis2=2), 1e-300) ** 3
    found = np.full((obs.shape[1], 3), np.nan)
    found[ok] = np.linalg.solve(normal[ok], rhs[ok][:, :, None])[:, :, 0]
    return found


def check_directions(obs, base, b, lights, min_evidence=MIN_DIRECTION_EVIDENCE, tol=DIRECTION_TOL,
                     ratio=RESIDUAL_RATIO):
    """What the images say of each frame's light direction, as a record (dict).

    Parameters
    ----------
    obs, base, b
        A pixel sample's observations (N, K) (intensities divided out), its non-shadowed ones
        and its Lambertian fit (N, 3).
    lights : ndarray (K, 3)
        The light file's unit directions, camera frame.

    Returns
    -------
    dict
        ``max_angle`` (degrees, over the judged frames); ``off`` {frame index: {"angle",
        "estimated" (3,)}}, the frames whose light is off (see the module docstring), an off
        frame whose estimate is another frame's direction with ``"like"`` that frame;
        ``swapped`` [[a, b], ...], off frames each of whose estimate is the other's direction;
        ``dark`` [k, ...], frames that light almost none of the pixels facing their light.
    """
    estimated = estimate_directions(obs, base, b)
    length = np.linalg.norm(estimated, axis=1)
    judged = ((base > 0).sum(axis=0) >= min_evidence) & np.isfinite(length) & (length > 0)
    unit = np.where(judged[:, None], estimated / np.where(judged, length, 1.0)[:, None], np.nan)
    angle = np.degrees(np.arccos(np.clip(np.sum(unit * lights, axis=1), -1, 1)))
    lit = base > 0
    # both residuals' medians in one sort
    (both,) = column_quantiles(np.abs(np.concatenate([obs - b @ lights.T, obs - b @ np.nan_to_num(estimated).T],
                                                     axis=1)), np.concatenate([lit, lit], axis=1), dtype=np.float32)
    given, own = both[:len(lights)], both[len(lights):]
    off = np.flatnonzero(judged & (angle > tol) & (given > ratio * np.maximum(own, 1e-12)))
    record = {"max_angle": round(float(np.nanmax(angle)), 2) if judged.any() else None,
              "off": {int(k): {"angle": round(float(angle[k]), 1), "estimated": [round(float(v), 4) for v in unit[k]]}
                      for k in off}}
    record["swapped"] = _swapped(off, unit, lights)
    paired = {k for pair in record["swapped"] for k in pair}
    for k in off:
        other = _nearest_other(k, unit[k], lights)
        if k not in paired and other is not None:
            record["off"][int(k)]["like"] = other
    record["dark"] = _dark(base, b, lights)
    return record


def _swapped(off, unit, lights):
    """Pairs [a, b] of off frames each of whose estimate is within SWAP_TOL of the other's light."""
    cross = np.degrees(np.arccos(np.clip(unit[off] @ lights[off].T, -1, 1))) if off.size else np.zeros((0, 0))
    return [[int(off[i]), int(off[j])] for i in range(len(off)) for j in range(i + 1, len(off))
            if cross[i, j] < SWAP_TOL and cross[j, i] < SWAP_TOL]


def _nearest_other(k, direction, lights):
    """The frame other than ``k`` whose light is within SWAP_TOL of ``direction`` (None if none):
    a frame captured twice, or an order shifted by one."""
    angles = np.degrees(np.arccos(np.clip(lights @ direction, -1, 1)))
    angles[k] = np.inf
    nearest = int(np.argmin(angles))
    return nearest if angles[nearest] < SWAP_TOL else None


def _dark(base, b, lights, facing=0.3, lit_share=0.1, min_facing=MIN_DIRECTION_EVIDENCE):
    """Frames lit at under ``lit_share`` of the pixels whose fitted normal faces their light
    (n . l > ``facing``): a light that did not fire, a frame captured in the dark."""
    albedo = np.linalg.norm(b, axis=1, keepdims=True)
    faces = (b @ lights.T) > facing * albedo
    count = faces.sum(axis=0)
    lit = ((base > 0) & faces).sum(axis=0)
    return [int(k) for k in np.flatnonzero((count >= min_facing) & (lit < lit_share * count))]


def column_quantiles(values, mask, quantiles=(0.5,), dtype=np.float64):
    """Quantiles (list of (K,), linear interpolation) of each column of ``values`` (N, K) over
    ``mask`` (N, K) bool, NaN where a column's mask is empty: one sort for all of them
    (np.nanmedian goes column by column, twice as slow here). ``dtype`` float32 halves the
    sort's time where a robust scale needs no more."""
    ordered = np.sort(np.where(mask, values, np.inf).astype(dtype), axis=0)
    count = mask.sum(axis=0)
    cols = np.arange(values.shape[1])
    found = []
    for q in quantiles:
        pos = np.maximum(count - 1, 0) * q
        low, high = np.floor(pos).astype(int), np.ceil(pos).astype(int)
        below, above = ordered[low, cols].astype(np.float64), ordered[high, cols].astype(np.float64)
        with np.errstate(invalid="ignore"):   # an empty column: inf - inf, replaced below
            found.append(np.where(count > 0, below + (pos - low) * (above - below), np.nan))
    return found
