"""Each frame's registration against the solved normals: a frame taken after the object or the
camera moved.

Photometric stereo assumes that pixel (r, c) sees the same surface point in every frame. A rig
bumped mid-capture, an object that settled on its stand or a camera that crept breaks that for
some frames, and nothing in a per-pixel fit says so: the robust selection leaves the moved
frames' observations out where they disagree most (edges, texture) and keeps them where the
shading is smooth, and the normals come out blurred and biased by a degree or more
(docs/photometric-stereo.md, "Frames that moved"; ``benchmarks/registration.py``).

The check renders every frame from the solved model (normals, albedo and the biquadratic
coefficients, :func:`predict_frames`) and registers each observed frame to its prediction: one
translation and one gain per frame, by robust (Tukey-weighted) Gauss-Newton on the image
gradients, coarse to fine (:func:`frame_shifts`). A frame is named when its shift departs from
the frames' median by more than :data:`MIN_SHIFT_PX` *and* by more than :data:`SPREAD_FACTOR`
times the frames' median departure: the solved model is itself a blend of every frame, and how
well shading pins position depends on the object (a textureless sphere's shading moves with its
light almost as it moves with the object); the departures measured on DiLiGenT are in
docs/photometric-stereo.md.

The normals stage (``align_frames``, default 'auto') then aligns the named frames by their
shift and solves again, where the object pins position well (the right frames' median departure
at most :data:`ALIGN_PRECISION`); aligning does better than leaving the frames out, whose lights
left are lopsided (docs). Captures are never changed: only the
stack in memory is. Directional lights only (near lights' per-pixel
directions are not rebuilt here). Images larger than :data:`WORK_PIXELS` around the object are
registered on every n-th pixel (shifts still in full-resolution pixels; :data:`MIN_SHIFT_PX` in
pixels of that grid).
"""

import cv2
import numpy as np
from scipy import ndimage

from .methods import get_method, method_traits
from .model import half_vectors
from .near_lights import PointLights

__all__ = ["check_registration", "predict_frames", "frame_shifts", "moved_frames", "align_frames", "alignable",
           "MIN_SHIFT_PX", "SPREAD_FACTOR", "WORK_PIXELS", "SAMPLE_PIXELS", "MIN_FRAMES", "RESOLVES", "ALIGN_PRECISION"]

#: a frame is named only when it departs from the others by more than this many pixels of the
#: grid it is registered on (full resolution, or every n-th pixel of a large object: a shift is
#: measured to a fraction of that grid's pixel, not of the camera's) ...
MIN_SHIFT_PX = 0.5
#: ... and by more than this many times the frames' median departure
SPREAD_FACTOR = 4.0
#: pixels of the object's box (with :data:`MARGIN`) registered at most; larger boxes are strided
WORK_PIXELS = 60_000
#: pixels per frame and pyramid level that the sums run over (a fixed random sample of the box)
SAMPLE_PIXELS = 6_000
#: the box around the mask, pixels: a moved outline must stay inside it
MARGIN = 8
#: (downsampling, Gauss-Newton steps) from coarse to fine: shifts up to about 10 px converge
LEVELS = ((4, 3), (2, 3), (1, 3))
#: fewer frames than this give no median worth departing from
MIN_FRAMES = 6
#: solves without the moved frames, at most (see :func:`check_registration`)
RESOLVES = 2
#: moved frames are aligned only where the right frames depart from their median by at most this
#: (px): textured objects pin position far better than this, a plain sphere's shading only to a
#: pixel or two, where aligning by the measured shifts costs (docs, "Constants")
ALIGN_PRECISION = 0.1
_TUKEY = 4.685


def predict_frames(result, lights, box, step=1):
    """The solved model rendered under each light: (K, h, w) float32 over ``box``.

    Parameters
    ----------
    result : PhotometricResult
        Its normals, albedo and, for the biquadratic method, its coefficients (``params``, the
        paper's order); other methods are rendered Lambertian (the gain and the robust
        weights of :func:`frame_shifts` absorb the difference).
    lights : ndarray (K, 3)
        Unit directions toward the lights, camera frame.
    box : (row0, row1, col0, col1)
        The window rendered; every ``step``-th pixel of it.

    Returns
    -------
    ndarray (K, h, w)
        albedo x rho(n . h, l . h) x max(n . l, 0), the observations' model (light
        intensities divided out; rho = 1 for methods whose coefficients do not render it); 0 off the mask.
    """
    rows, cols = slice(box[0], box[1], step), slice(box[2], box[3], step)
    inside = np.asarray(result.mask)[rows, cols]
    n = result.normals[rows, cols][inside].astype(np.float32)
    albedo = result.albedo[rows, cols][inside].astype(np.float32)
    lights = np.asarray(lights, np.float32)
    value = np.maximum(n @ lights.T, 0.0)
    if method_traits(get_method(result.method)).renders_rho:
        value *= _shape(result.params[rows, cols][inside], n, lights)
    value *= albedo[:, None]
    out = np.zeros((len(lights),) + inside.shape, np.float32)
    out[:, inside] = value.T
    return out


def _shape(params, n, lights):
    """rho (N, K) of the biquadratic coefficients ``params`` (N, 9), the paper's order."""
    coeffs = params.reshape(-1, 3, 3)[:, ::-1, ::-1].astype(np.float32)
    h, y = half_vectors(lights)
    ypow = np.stack([np.ones_like(y), y, y * y], axis=1).astype(np.float32)
    x = n @ h.astype(np.float32).T
    rho = coeffs[:, 2, :] @ ypow.T           # Horner's rule in x
    rho *= x
    rho += coeffs[:, 1, :] @ ypow.T
    rho *= x
    rho += coeffs[:, 0, :] @ ypow.T
    return rho


def _shrink(stack, factor):
    if factor == 1:
        return stack
    size = (max(8, stack.shape[2] // factor), max(8, stack.shape[1] // factor))
    return np.stack([cv2.resize(frame, size, interpolation=cv2.INTER_AREA) for frame in stack])


def frame_shifts(images, predicted, region, valid=None, levels=LEVELS, sample=SAMPLE_PIXELS, seed=0):
    """Each frame's translation and gain onto its prediction: images[k](x + d_k) ~ g_k predicted[k](x).

    Parameters
    ----------
    images, predicted : ndarray (K, h, w)
        Observed frames and the model's (same window).
    region : ndarray (h, w) bool
        The pixels that count (the mask, widened).
    valid : ndarray (K, h, w) bool, optional
        False for observations not to use (saturated).

    Returns
    -------
    shifts : ndarray (K, 2)
        d_k in pixels of the window, (columns right, rows down).
    gains : ndarray (K,)
    """
    count = len(images)
    shifts, gains = np.zeros((count, 2)), np.ones(count)
    rng = np.random.default_rng(seed)
    images = images.astype(np.float32, copy=False)
    for factor, steps in levels:
        seen, model = _shrink(images, factor), _shrink(predicted, factor)
        inside = region if factor == 1 else _shrink(region[None].astype(np.float32), factor)[0] > 0.99
        idx = np.flatnonzero(inside)
        if idx.size < 50:
            continue
        if idx.size > sample:
            idx = np.sort(rng.choice(idx, sample, replace=False))
        usable = None if valid is None else \
            (_shrink(valid.astype(np.float32), factor).reshape(count, -1)[:, idx] > 0.99)
        grad_rows, grad_cols = np.gradient(model, axis=(1, 2))
        flat = [a.reshape(count, -1)[:, idx] for a in (model, grad_cols, grad_rows)]
        for _ in range(steps):
            step = _gauss_newton(_warped(seen, shifts / factor)[:, idx], *flat, gains, usable)
            shifts += factor * step[:, :2]
            gains += step[:, 2]
    return shifts, gains


def _warped(stack, shifts):
    """Each frame sampled at x + shift (bilinear), (K, h * w)."""
    h, w = stack.shape[1:]
    return np.stack([cv2.warpAffine(frame, np.float32([[1, 0, dx], [0, 1, dy]]), (w, h),
                                    flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REPLICATE)
                     for frame, (dx, dy) in zip(stack, shifts)]).reshape(len(stack), -1)


def _gauss_newton(seen, model, grad_cols, grad_rows, gains, usable):
    """One robust step (K, 3) of (d_cols, d_rows, gain) for r = seen - g model (0 for a frame
    with no gradient to go by).

    The Jacobian uses the model's gradients for the warped frame's (at the solution they agree
    up to the gain), so they are computed once per level."""
    g = gains.astype(np.float32)[:, None]
    resid = seen - g * model
    scale = 1.4826 * np.median(np.abs(resid), axis=1) + 1e-9
    weight = resid / (_TUKEY * scale.astype(np.float32)[:, None])
    weight *= weight
    weight = np.maximum(1.0 - weight, 0.0) ** 2
    if usable is not None:
        weight *= usable
    columns = (g * grad_cols, g * grad_rows, -model)
    normal, rhs = np.empty((len(seen), 3, 3)), np.empty((len(seen), 3))
    for i, ci in enumerate(columns):
        weighted = weight * ci
        rhs[:, i] = -np.sum(weighted * resid, axis=1)
        for j in range(i, 3):
            normal[:, i, j] = normal[:, j, i] = np.sum(weighted * columns[j], axis=1)
    normal += (1e-9 * np.trace(normal, axis1=1, axis2=2) + 1e-30)[:, None, None] * np.eye(3)
    with np.errstate(all="ignore"):
        step = np.linalg.solve(normal, rhs[..., None])[..., 0]
    return np.where(np.isfinite(step), step, 0.0)


def moved_frames(shifts, keep=None, min_shift=MIN_SHIFT_PX, factor=SPREAD_FACTOR):
    """The frames (indices) whose shift (K, 2) departs from the reference frames' median (``keep``
    (K,) bool, default all), every frame's departure from it (K,), and the threshold (px): the
    larger of ``min_shift`` and ``factor`` x the reference frames' median departure."""
    keep = np.ones(len(shifts), bool) if keep is None else keep
    departure = np.linalg.norm(shifts - np.median(shifts[keep], axis=0), axis=1)
    threshold = max(min_shift, factor * float(np.median(departure[keep])))
    return np.flatnonzero(departure > threshold), departure, threshold


def check_registration(images, result, lights, valid=None, resolve=None):
    """Whether every frame sees the object where the others do (see the module docstring).

    Parameters
    ----------
    images : ndarray (K, H, W)
        The frames the normals were solved from (light intensities divided out; memory-mapped
        is fine: only a window of the object's box is read).
    result : PhotometricResult
    lights : ndarray (K, 3), or PointLights
        The directions the normals were solved with, camera frame; near lights are not checked
        (their per-pixel directions are not rebuilt for the rendering).
    valid : ndarray (K, H, W) bool, optional
        False for saturated observations.
    resolve : callable, optional
        ``resolve(keep)`` -> PhotometricResult, the same solve on the frames ``keep`` (K,) bool.
        When frames are named, the check renders the frames again from a solve without them
        and registers every frame anew (at most :data:`RESOLVES` times): normals solved from
        moved frames too are a blend, against which a third of the frames moved by 2.2 px read
        0.7-1.4 px off (DiLiGenT cat), and only 14 of the 36 were named.

    Returns
    -------
    dict
        ``verdict`` 'consistent', 'moved' or 'not checked' (with ``reason``); when checked,
        ``threshold_px``, ``median_departure_px``, ``largest_px`` and ``moved``: {frame index:
        [d_cols, d_rows]} (px, full resolution, against the median of the frames not moved),
        ``run_from``: the first moved frame when the moved frames are every frame from it to
        the last (the capture's order), ``resolves`` (solves without the moved frames) and
        ``grid_px`` (the registration's grid: every n-th pixel).
    """
    if isinstance(lights, PointLights) or np.ndim(lights) != 2:
        return {"verdict": "not checked", "reason": "near lights"}
    lights = np.asarray(lights)
    if len(lights) < MIN_FRAMES:
        return {"verdict": "not checked", "reason": f"fewer than {MIN_FRAMES} frames"}
    mask = np.asarray(result.mask, bool)
    region = ndimage.binary_dilation(mask, iterations=MARGIN) if mask.any() else mask
    rows, cols = np.nonzero(region)
    if rows.size < 400:
        return {"verdict": "not checked", "reason": "object too small"}
    box = (rows.min(), rows.max() + 1, cols.min(), cols.max() + 1)
    stride = max(1, int(np.ceil(np.sqrt((box[1] - box[0]) * (box[3] - box[2]) / WORK_PIXELS))))
    window = (slice(box[0], box[1], stride), slice(box[2], box[3], stride))
    every = (slice(None),) + window
    seen = np.asarray(images[every], np.float32)
    usable = None if valid is None else np.asarray(valid[every])

    def register(solved):
        return stride * frame_shifts(seen, predict_frames(solved, lights, box, stride), region[window], usable)[0]

    min_shift = MIN_SHIFT_PX * stride
    shifts = register(result)
    moved, departure, threshold = moved_frames(shifts, min_shift=min_shift)
    resolves = 0
    while moved.size and resolve is not None and resolves < RESOLVES and len(lights) - moved.size >= MIN_FRAMES:
        keep = np.ones(len(lights), bool)
        keep[moved] = False
        shifts = register(resolve(keep))
        resolves += 1
        again, departure, threshold = moved_frames(shifts, keep, min_shift=min_shift)
        settled = np.array_equal(again, moved)
        moved = again
        if settled:
            break
    keep = np.ones(len(lights), bool)
    keep[moved] = False
    offsets = shifts - np.median(shifts[keep] if keep.any() else shifts, axis=0)
    found = {"verdict": "moved" if moved.size else "consistent", "threshold_px": round(threshold, 2),
             "median_departure_px": round(float(np.median(departure[keep] if keep.any() else departure)), 3),
             "largest_px": round(float(departure.max()), 2), "resolves": resolves, "grid_px": stride,
             "moved": {int(k): [round(float(v), 2) for v in offsets[k]] for k in moved}}
    if moved.size >= 2 and moved[-1] == len(lights) - 1 and np.all(np.diff(moved) == 1):
        found["run_from"] = int(moved[0])
    return found


def alignable(found, precision=ALIGN_PRECISION):
    """Whether :func:`check_registration`'s ``found`` names frames whose shifts are worth undoing."""
    return bool((found or {}).get("moved")) and found.get("median_departure_px", np.inf) <= precision


def align_frames(images, valid, moved):
    """Copies of ``images`` (K, H, W) and ``valid`` (K, H, W) bool or None with the frames of
    ``moved`` ({index: [d_cols, d_rows]}, :func:`check_registration`) shifted back onto the
    others (bilinear; pixels shifted in from beyond the image are marked not valid)."""
    images = np.array(images, copy=True)
    valid = np.ones(images.shape, bool) if valid is None else np.array(valid, copy=True)
    h, w = images.shape[1:]
    for k, (dx, dy) in moved.items():
        back = np.float32([[1, 0, dx], [0, 1, dy]])
        flags = cv2.WARP_INVERSE_MAP
        images[k] = cv2.warpAffine(images[k], back, (w, h), flags=cv2.INTER_LINEAR | flags,
                                   borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        inside = cv2.warpAffine(np.ones((h, w), np.uint8), back, (w, h), flags=cv2.INTER_NEAREST | flags,
                                borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        seen = cv2.warpAffine(valid[k].astype(np.uint8), back, (w, h), flags=cv2.INTER_NEAREST | flags,
                              borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        valid[k] = (seen > 0) & (inside > 0)
    return images, valid
