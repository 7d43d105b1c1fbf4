"""Held-out-light prediction: does the fitted model predict photographs it was not given?

Without ground truth, the one honest check of a reflectance fit is whether it predicts an image
it was not fitted to. The lights are split into :data:`FOLDS` folds (interleaved by azimuth, so
every fold spans the hemisphere and every training set stays balanced); for each fold the
normals are solved again without its lights, on a regular grid of at most
:data:`SAMPLE_PIXELS` object pixels (every ``stride``-th pixel of the object's box, so the
sample is itself a small image), by the biquadratic method (with the stage's options) and by
Lambertian least squares on the same selection of observations (``lambert-low``: the two
differ only in the model). Each model then renders the held-back frames from its own fit
(albedo x rho(n . h, l . h) x max(n . l, 0); rho = 1 for Lambert), and the prediction is
scored against the captured frame over the pixels that are lit (captured above
:data:`LIT_FRACTION` of the sample's bright level), unsaturated and solved by both fits:
relative RMS error, sqrt(sum (predicted - captured)^2 / sum captured^2), per held-back light
and pooled over all of them.

The specular anchor is off in the refits (it corrects the lights' cone, which the held-back
lights' rendering would then have to follow); near lights are scored with their per-pixel
directions and falloff at the depth the stage solved at.
"""

import time

import numpy as np

from ..core.errors import InputError
from ..settings.normals import FOLDS
from .estimate import estimate_normals
from .model import half_vectors
from .near_lights import PointLights

__all__ = ["held_out_prediction", "light_folds", "sample_window", "render", "prediction_line", "read_prediction",
           "MIN_LIGHTS",
           "FOLDS", "SAMPLE_PIXELS", "LIT_FRACTION", "MIN_PIXELS", "LAMBERT_METHOD"]

#: fewer lights than this leave too few to fit once some are held back: the check is refused
MIN_LIGHTS = 6
#: object pixels of the sample grid at most: the scores are sums over every lit observation of
#: the grid, steady well below this; the refits' cost grows with it (docs, "Held-out lights")
SAMPLE_PIXELS = 8_000
#: an observation counts as lit above this fraction of the sample's bright level (99.5th
#: percentile of the unsaturated observations): shadows are not predictions of a BRDF
LIT_FRACTION = 0.02
#: a light scored on fewer pixels than this is listed but not ranked (no worst light from it)
MIN_PIXELS = 50
#: the Lambertian side: least squares on the biquadratic's own selection of observations
LAMBERT_METHOD = "lambert-low"
#: options of the stage that the Lambertian refit shares (its selection of observations)
_SELECTION_OPTIONS = ("t_low", "t_shadow", "reject_k")


def light_folds(directions, folds=FOLDS):
    """Fold index (K,) of each light: lights sorted by azimuth, dealt round-robin."""
    directions = np.asarray(directions, float)
    order = np.argsort(np.arctan2(directions[:, 1], directions[:, 0]), kind="stable")
    fold = np.empty(len(directions), int)
    fold[order] = np.arange(len(directions)) % folds
    return fold


def sample_window(mask, max_pixels=SAMPLE_PIXELS):
    """(rows, cols) slices of a grid over ``mask``'s box with at most ``max_pixels`` mask pixels,
    and its stride (pixels)."""
    rows, cols = np.nonzero(mask)
    box = (rows.min(), rows.max() + 1, cols.min(), cols.max() + 1)
    stride = max(1, int(np.floor(np.sqrt(rows.size / max_pixels))))
    while True:
        window = (slice(box[0], box[1], stride), slice(box[2], box[3], stride))
        if int(mask[window].sum()) <= max_pixels:
            return window, stride
        stride += 1


def render(normals, albedo, lights, params=None):
    """The model's prediction (N, K) of pixels with ``normals`` (N, 3) and ``albedo`` (N,).

    ``lights`` are unit directions (K, 3) or per pixel (N, K, 3); ``params`` (N, 9) the
    biquadratic coefficients in the paper's order A..I (relative to the albedo), or None for
    Lambert. Light intensities (and near lights' falloff) are divided out, as the fit saw them.
    """
    n = np.asarray(normals, np.float64)
    lights = np.asarray(lights, np.float64)
    h, y = half_vectors(lights)
    if lights.ndim == 2:
        s, x = n @ lights.T, n @ h.T
        y = np.broadcast_to(y, s.shape)
    else:
        s, x = np.einsum("nc,nkc->nk", n, lights), np.einsum("nc,nkc->nk", n, h)
    value = np.maximum(s, 0.0) * np.asarray(albedo, np.float64)[:, None]
    if params is None:
        return value
    c = np.asarray(params, np.float64).reshape(-1, 3, 3)[:, ::-1, ::-1]    # C[a, b] multiplies x^a y^b
    ypow = np.stack([np.ones_like(y), y, y * y], axis=-1)                  # (N, K, 3)
    q = [np.einsum("nb,nkb->nk", c[:, a, :], ypow) for a in range(3)]
    return value * (q[0] + x * (q[1] + x * q[2]))


def _grid_lights(lights, window, inside, shape):
    """Directions toward the lights at the grid's object pixels: (K, 3) directional, or (N, K, 3)
    with the falloff (N, K) for near lights (falloff None for directional ones)."""
    if not isinstance(lights, PointLights):
        return np.asarray(lights, float), None
    rows = np.arange(shape[0])[window[0]]
    cols = np.arange(shape[1])[window[1]]
    flat = (rows[:, None] * shape[1] + cols[None, :])[inside]
    return lights.at(flat)


def held_out_prediction(images, valid, lights, mask, *, options=None, folds=FOLDS, sample_pixels=SAMPLE_PIXELS,
                        workers=None):
    """Relative RMS error of each model's prediction of frames held back from its fit.

    Parameters
    ----------
    images : ndarray (K, H, W)
        The grey frames the stage solved from, light intensities divided out.
    valid : ndarray (K, H, W) bool or None
        False for saturated observations.
    lights : ndarray (K, 3), or PointLights
        The lights the stage solved with (near lights at the depth it kept).
    mask : ndarray (H, W) bool
        Object pixels.
    options : dict, optional
        The stage's solver options (the biquadratic refits take them, the anchor and the neighbours' vote off).
    folds : int
        Folds over the lights (at most one light per fold below ``folds`` lights).
    sample_pixels : int
        Object pixels of the sample grid at most.

    Returns
    -------
    dict
        ``verdict`` 'checked' or 'not checked' (with ``reason``); when checked: ``folds``,
        ``stride`` (px), ``pixels`` (of the grid), ``lit_fraction``, ``lambert_method``,
        ``overall`` {'biquadratic_pct', 'lambert_pct', 'observations'}, ``lights``: one entry
        per light (``light`` its index in ``images``, ``fold``, ``pixels``, ``biquadratic_pct``,
        ``lambert_pct``; the errors None where it has fewer than :data:`MIN_PIXELS`),
        ``worst_light`` (the biquadratic's worst ranked light) and ``seconds``; and the key
        ``images`` (not for the record): captured, biquadratic and Lambert (h, w) float32 of the
        worst light over the grid (0 off the scored pixels).
    """
    start = time.perf_counter()
    count = len(images)
    if count < MIN_LIGHTS:
        return {"verdict": "not checked",
                "reason": f"{count} lights: too few to hold any back (at least {MIN_LIGHTS} needed)"}
    mask = np.asarray(mask, bool)
    if not mask.any():
        return {"verdict": "not checked", "reason": "no object pixels"}
    window, stride = sample_window(mask, sample_pixels)
    inside = mask[window]
    every = (slice(None),) + window
    small = np.asarray(images[every], np.float32)
    usable = np.ones(small.shape, bool) if valid is None else np.asarray(valid[every], bool)
    directions, falloff = _grid_lights(lights, window, inside, mask.shape)
    if falloff is not None:
        small[:, inside] /= falloff.T.astype(np.float32)
        grid_lights = np.zeros(small.shape + (3,))
        grid_lights[:, ~inside] = lights.central_directions[:, None, :]
        grid_lights[:, inside] = directions.transpose(1, 0, 2)
    else:
        grid_lights = directions
    central = lights.central_directions if isinstance(lights, PointLights) else directions
    folds = max(2, min(int(folds), count))
    fold = light_folds(central, folds)
    captured = small[:, inside]                                  # (K, N)
    seen = usable[:, inside]
    predicted = {name: np.full(captured.shape, np.nan) for name in ("biquadratic", "lambert")}
    options = dict(options or {})
    # the refits are the model's check on a sample grid: without the anchor, and without the
    # neighbours' vote (pipeline.photometric.consensus), whose neighbours the grid's stride spaces out
    biquadratic_options = dict(options, specular_anchor=False, neighbour_consensus=False)
    lambert_options = {k: options[k] for k in _SELECTION_OPTIONS if options.get(k) is not None}
    try:
        for f in range(folds):
            held = fold == f
            train = ~held
            chosen = grid_lights[train]
            for name, method, given in (("biquadratic", "biquadratic", biquadratic_options),
                                        ("lambert", LAMBERT_METHOD, lambert_options)):
                fit = estimate_normals(small[train], chosen, inside, method=method, valid=usable[train],
                                       workers=workers, **given)
                n = fit.normals[inside]
                solved = np.linalg.norm(n, axis=1) > 0.5
                towards = directions[held] if falloff is None else directions[:, held]
                params = fit.params[inside] if name == "biquadratic" else None
                value = render(n, fit.albedo[inside], towards, params).T          # (held, N)
                value[:, ~solved] = np.nan
                predicted[name][held] = value
    except InputError as err:
        return {"verdict": "not checked", "reason": f"a fold could not be fitted: {err}"}
    bright = captured[seen]
    level = LIT_FRACTION * float(np.percentile(bright, 99.5)) if bright.size else 0.0
    scored = seen & (captured > level) & np.isfinite(predicted["biquadratic"]) & np.isfinite(predicted["lambert"])
    pixels = scored.sum(axis=1)
    sums = {name: np.where(scored, (value - captured) ** 2, 0.0).sum(axis=1) for name, value in predicted.items()}
    power = np.where(scored, captured.astype(np.float64) ** 2, 0.0).sum(axis=1)
    ranked = pixels >= MIN_PIXELS
    if not ranked.any():
        return {"verdict": "not checked", "reason": f"no light has {MIN_PIXELS} lit, unsaturated, solved pixels"}

    def pct(error, total):
        return round(100.0 * float(np.sqrt(error / total)), 2) if total > 0 else None

    per_light = []
    for k in range(count):
        entry = {"light": k, "fold": int(fold[k]), "pixels": int(pixels[k])}
        for name in predicted:
            entry[f"{name}_pct"] = pct(sums[name][k], power[k]) if ranked[k] else None
        per_light.append(entry)
    overall = {f"{name}_pct": pct(sums[name][ranked].sum(), power[ranked].sum()) for name in predicted}
    overall["observations"] = int(pixels[ranked].sum())
    errors = np.where(ranked, sums["biquadratic"] / np.maximum(power, 1e-300), -1.0)
    worst = int(np.argmax(errors))
    pictures = {}
    for name, value in (("captured", captured), ("biquadratic", predicted["biquadratic"]),
                        ("lambert", predicted["lambert"])):
        picture = np.zeros(inside.shape, np.float32)
        picture[inside] = np.where(scored[worst], value[worst], 0.0)
        pictures[name] = picture
    return {"verdict": "checked", "folds": folds, "stride": stride, "pixels": int(inside.sum()),
            "lit_fraction": LIT_FRACTION, "lambert_method": LAMBERT_METHOD, "overall": overall,
            "lights": per_light, "worst_light": worst, "seconds": round(time.perf_counter() - start, 2),
            "images": pictures}


def read_prediction(session):
    """``normals/prediction.yaml`` of ``session`` as a dict, or None when the normals stage wrote
    none (an older run, or ``--holdout-folds 0``)."""
    from ..core.paths import PREDICTION
    from ..core.yamlio import load_yaml

    path = session.path(PREDICTION)
    if not path.is_file():
        return None
    found = load_yaml(path.read_text(encoding="utf-8"))
    if not isinstance(found, dict) or "verdict" not in found:
        raise InputError(f"{path}: not a held-out prediction record (no 'verdict'); rerun `psrig normals --force`")
    return found


def prediction_line(found):
    """The one line a person reads of :func:`held_out_prediction`'s record ('' without one)."""
    if not found:
        return ""
    if found.get("verdict") != "checked":
        return f"held-out lights: not checked ({found.get('reason', 'no reason given')})"
    bq, lam = found["overall"]["biquadratic_pct"], found["overall"]["lambert_pct"]
    # one decimal unless it would show two different errors as the same
    digits = 1 if f"{bq:.1f}" != f"{lam:.1f}" else 2
    return f"held-out lights: biquadratic predicts within {bq:.{digits}f} % RMS, Lambert {lam:.{digits}f} %"
