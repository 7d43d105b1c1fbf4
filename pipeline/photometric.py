"""Photometric stereo: surface normals from images under known lights.

>>> result = estimate_normals(images, lights, mask=None, method="biquadratic")

Methods are registered by name in :data:`METHODS` (one dispatcher, :func:`estimate_normals`):

``biquadratic`` (default)
    The paper's per-pixel relaxed biquadratic model (Sec. 5) with robust observation selection
    and a shared-shape prior; see :mod:`pipeline.ps_biquadratic` and the README for the rule
    and the measurements behind its defaults. Under a narrow light cone, where sharp specular
    peaks show the normals' slant to be off, the lights' polar angles are corrected once
    (:mod:`pipeline.ps_anchor`, option ``specular_anchor``; reported in ``result.options``).
    When the object fails the single-material check (:func:`single_material_check`) on that
    automatic narrow-cone path, every pixel falls back to the paper's darkest-fraction rule
    without the prior (``result.options["shape_check"]["fallback"]``).
``lambert``
    Lambertian least squares on all valid observations (the classic baseline).
``lambert-low``
    Lambertian least squares on the observations the biquadratic method selects.
any other registered reflectance model (``bicubic``, ``bilinear``, and the models of
:mod:`pipeline.reflectance` such as ``lafortune``, ``cook-torrance``, ``ward``)
    The paper's alternation: fix n, fit the model; fix rho, solve n linearly.

All work is vectorised over pixels and done in chunks of ``chunk_size`` pixels, so memory
stays bounded by the input stack plus a few chunk-sized arrays. Chunks run on ``workers``
threads with one BLAS thread each; a method's shared context (the biquadratic shared shape) is
fitted on one of them while the others start selecting observations. The default chunk (2048 pixels)
keeps a chunk's (N, K) arrays near the cores' caches: measured faster than 8192.
"""

import os
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
from threadpoolctl import threadpool_limits

from .errors import InputError
from .near_lights import PointLights, observations_at
from .ps_anchor import anchor_scale, first_verdict, highlight_mismatch
from .ps_biquadratic import _powers, _shared_state, alternate_shared, fit_pixel_shapes, fit_shared_shape, \
    gauss_newton_normals, half_vectors, to_paper_order, unit
from .ps_lambert import lambert_weighted
from .ps_select import select_darkest, select_robust, shadow_weights

__all__ = ["estimate_normals", "PhotometricResult", "METHODS", "STATUS", "STATUS_NAMES"]

STATUS = {"background": 0, "ok": 1, "shadowed": 2, "too_few": 3, "not_converged": 4, "lambert_fallback": 5}
STATUS_NAMES = {code: name for name, code in STATUS.items()}
MIN_OBS = 3


@dataclass
class PhotometricResult:
    """Output of :func:`estimate_normals`.

    Attributes
    ----------
    normals : ndarray (H, W, 3) float32
        Unit normals, camera frame; zero outside the mask and where status says no estimate.
    mask : ndarray (H, W) bool
        Pixels that were processed.
    status : ndarray (H, W) uint8
        Codes of :data:`STATUS` (ok, shadowed, too_few, not_converged, lambert_fallback).
    albedo : ndarray (H, W) float32
        Diffuse scale (|b|), in units of the input intensities.
    params : ndarray (H, W, P) float32
        Reflectance parameters per pixel (biquadratic: A..I of Eq. 2, relative to albedo).
    residual : ndarray (H, W) float32
        Root-mean-square residual over the used observations, relative to the albedo.
    used : ndarray (H, W) uint16
        Number of observations used per pixel.
    """

    normals: np.ndarray
    mask: np.ndarray
    status: np.ndarray
    albedo: np.ndarray
    params: np.ndarray
    residual: np.ndarray
    used: np.ndarray
    method: str = ""
    options: dict = field(default_factory=dict)
    seconds: float = 0.0
    shared_shape: np.ndarray = None


# ----------------------------------------------------------------------------- validation
def _check_inputs(images, lights, mask, valid):
    images = np.asarray(images)
    if images.ndim != 3:
        raise InputError(f"images must be a (K, H, W) stack of grey linear images, got shape {images.shape}")
    k, height, width = images.shape
    if k < 3:
        raise InputError(f"photometric stereo needs at least 3 images, got {k}")
    if isinstance(lights, PointLights):
        return images, _check_point_lights(lights, images.shape), *_check_mask_valid(images, mask, valid)
    lights = np.asarray(lights, dtype=float)
    if lights.shape[0] != k:
        raise InputError(f"{lights.shape[0]} light directions for {k} images")
    if lights.shape not in ((k, 3), (k, height, width, 3)):
        raise InputError(f"lights must be (K, 3) or (K, H, W, 3), got {lights.shape} for images {images.shape}")
    finite = np.isfinite(lights).reshape(k, -1).all(axis=1)
    if not finite.all():
        raise InputError(f"light {int(np.argmin(finite))} has a non-finite direction")
    norms = np.linalg.norm(lights, axis=-1).reshape(k, -1)
    if (norms < 1e-9).any():
        raise InputError(f"light {int(np.argmax((norms < 1e-9).any(axis=1)))} has a zero direction vector")
    lights = lights / np.linalg.norm(lights, axis=-1, keepdims=True)
    shared = lights if lights.ndim == 2 else lights.reshape(k, -1, 3).mean(axis=1)
    _check_rank(shared)
    return images, lights, *_check_mask_valid(images, mask, valid)


def _check_rank(shared):
    if np.linalg.matrix_rank(shared, tol=1e-6) < 3:
        raise InputError("light directions have rank < 3 (coplanar lights): normals are not determined")


def _check_point_lights(lights, shape):
    k, height, width = shape
    if len(lights) != k:
        raise InputError(f"{len(lights)} light positions for {k} images")
    if lights.shape != (height, width):
        raise InputError(f"near lights are for images {lights.shape}, the images are {(height, width)}")
    _check_rank(lights.central_directions)
    return lights


def _check_mask_valid(images, mask, valid):
    k, height, width = images.shape
    if mask is None:
        # Image by image: images > 0 at once would be a (K, H, W) temporary.
        mask = np.zeros((height, width), bool)
        for image in images:
            mask |= image > 0
    mask = np.asarray(mask, dtype=bool)
    if mask.shape != (height, width):
        raise InputError(f"mask shape {mask.shape} does not match the images' {(height, width)}")
    if not mask.any():
        raise InputError("the mask has no pixels")
    if valid is not None:
        valid = np.asarray(valid, dtype=bool)
        if valid.shape != images.shape:
            raise InputError(f"valid shape {valid.shape} does not match the images' {images.shape}")
    # One image at a time: images[:, mask] would copy the whole masked stack (peak memory).
    for i in range(k) if images.dtype.kind == "f" else ():
        if not np.isfinite(images[i][mask]).all():
            raise InputError(f"image {i} has non-finite pixel values inside the mask")
    return mask, valid


# ----------------------------------------------------------------------------- dispatcher
def estimate_normals(images, lights, mask=None, method="biquadratic", *, valid=None, chunk_size=2048,
                     workers=None, progress=None, **options):
    """Estimate surface normals per pixel.

    Parameters
    ----------
    images : ndarray (K, H, W)
        Linear grey images, light intensities divided out.
    lights : ndarray (K, 3) or (K, H, W, 3), or PointLights
        Unit directions toward the lights, camera frame (per pixel for near lights), or near
        point lights (:class:`pipeline.near_lights.PointLights`), whose per-pixel directions
        and inverse-square falloff are computed chunk by chunk (the falloff is divided out).
    mask : ndarray (H, W) bool, optional
        Pixels to process; default: pixels lit in some image.
    method : str
        A name in :data:`METHODS` or a registered reflectance model.
    valid : ndarray (K, H, W) bool, optional
        False for observations that must not be used (saturated pixels).
    chunk_size : int
        Pixels processed at once (memory per chunk is about chunk_size x K x 200 bytes).
    workers : int, optional
        Threads working on chunks at once (default: the number of cores).
    progress : callable, optional
        Called with the number of pixels finished after each chunk.
    **options
        Method options (see each method's function, e.g. :func:`biquadratic_method`), and
        ``specular_anchor`` ('auto', True or False): correct the lights' polar angles where sharp
        specular peaks show the normals' slant to be off (:mod:`pipeline.ps_anchor`; 'auto' =
        the biquadratic method under a narrow light cone). Its outcome is in the result's
        ``options`` (``cone_scale``, 1.0 when unchanged, ``anchor``, ``mismatch_deg``,
        ``highlight_pixels``); a corrected run costs up to three estimations.

    Returns
    -------
    PhotometricResult
    """
    start = time.perf_counter()
    images, lights, mask, valid = _check_inputs(images, lights, mask, valid)
    solver = _method(method)
    near = lights if isinstance(lights, PointLights) else None
    if near is not None:
        lights = near.central_directions
    options = resolve_selection(lights, options)
    specular_anchor = options.pop("specular_anchor", "auto")
    anchor = _anchor_wanted(method, specular_anchor, options, lights, near)

    runs = []

    def solve(run_lights):
        # Progress is reported for the first run only: its total is the mask's pixel count.
        runs.append(run_lights)
        return _run(solver, images, run_lights, near, mask, valid, chunk_size, workers,
                    progress if len(runs) == 1 else None, anchor, options)

    if anchor:
        (out, shared), info = _anchored(solve, lights, insist=specular_anchor is True)
        options.update(info)
    else:
        out, shared = solve(lights)[0]
    if shared["shape_check"] is not None:
        options["shape_check"] = shared["shape_check"]
    if shared["select"]:  # the darkest-fraction fallback ran: report the options that did
        options.update(shared["select"], shape_prior=0.0)
    return PhotometricResult(
        normals=out["normals"], mask=mask, status=out["status"], albedo=out["albedo"], params=out["params"],
        residual=out["residual"], used=out["used"], method=method, options=options,
        seconds=time.perf_counter() - start, shared_shape=shared["shape_paper"])


def _anchored(solve, lights, insist=False):
    """``anchor_scale`` on ``solve``, except after the darkest-fraction fallback.

    The fallback (``_Biquadratic.prepare``) is known only after the first solve. Its normals
    are then measured and reported (as the tiled stage reports them, from the same first
    verdict) but not corrected unless the caller insists (``specular_anchor=True``): the
    one measured false correction of the anchor came from a darkest-rule solve, and an object
    that failed the one-material check is where a local specular bias is likeliest to pass for
    a global one.
    """
    first = solve(lights)
    if first[0][1]["select"] and not insist:
        info = first_verdict(first[1])
        if info["anchor"] == "to correct":
            info["anchor"] = "not corrected: darkest fallback"
        return first[0], info
    replay = [first]
    return anchor_scale(lambda run_lights: replay.pop() if replay else solve(run_lights), lights)


def _anchor_wanted(method, specular_anchor, options, lights, near):
    """Whether to anchor the light cone on specular peaks (:mod:`pipeline.ps_anchor`).

    'auto': for the biquadratic method with robust selection (the narrow-cone case, where the
    slant is nearly ambiguous) and directional lights shared by all pixels. True: for any
    method, still only with shared directional lights (the correction scales their polar
    angles). False: never.
    """
    if specular_anchor not in ("auto", True, False):
        raise InputError(f"specular_anchor must be 'auto', True or False, got {specular_anchor!r}")
    if near is not None or np.asarray(lights).ndim != 2 or specular_anchor is False:
        return False
    # 'auto' follows the narrow-cone default path only: robust selection (no explicit t_low)
    return specular_anchor is True or (method == "biquadratic" and options.get("selection") == "robust"
                                       and options.get("t_low") is None)


def _run(solver, images, lights, near, mask, valid, chunk_size, workers, progress, anchor, options):
    """One estimation over all chunks: ((output arrays, shared shape), highlight mismatches)."""
    k = images.shape[0]
    flat_images = images.reshape(k, -1)
    flat_lights = None if lights.ndim == 2 else lights.reshape(k, -1, 3)
    flat_valid = None if valid is None else valid.reshape(k, -1)
    pixels = np.flatnonzero(mask)

    def gather(idx):
        obs = flat_images[:, idx].T.astype(np.float64)
        obs_valid = None if flat_valid is None else flat_valid[:, idx].T
        if near is not None:
            obs, obs_lights = observations_at(near, obs, idx)
            return obs, obs_valid, obs_lights
        obs_lights = lights if flat_lights is None else np.ascontiguousarray(flat_lights[:, idx].transpose(1, 0, 2))
        return obs, obs_valid, obs_lights

    out = {}
    mismatch = []
    lock = threading.Lock()
    pieces = [pixels[i:i + chunk_size] for i in range(0, len(pixels), chunk_size)]
    chunks = iter(pieces)
    phases = solver if hasattr(solver, "select") else _OnePhase(solver)

    def finish(idx, picked):
        chunk = phases.fit(picked, context=context, **options)
        obs, obs_valid, obs_lights = picked["obs"], picked["valid"], picked["lights"]
        # Measured here, on the chunk's observations already in memory (no second gather).
        found = highlight_mismatch(obs, np.nan_to_num(chunk["b"]), obs_lights, valid=obs_valid) if anchor else None
        with lock:
            if not out:
                out.update(_allocate(mask.shape, chunk["params"].shape[1]))
            _scatter(out, idx, chunk)
            if found is not None:
                mismatch.append(found)
        if progress:
            progress(len(idx))

    def work():
        # Chunks are selected ahead while the shared context is being prepared (selection
        # never waits for it), up to LOOKAHEAD_BYTES of them, then fitted; one worker per core.
        held = []
        while True:
            with lock:
                idx = next(chunks, None)
            if idx is None:
                break
            held.append((idx, phases.select(*gather(idx), context=context, **options)))
            if context.ready() or sum(p["obs"].nbytes for _, p in held) >= LOOKAHEAD_BYTES:
                for item in held:
                    finish(*item)
                held.clear()
        for item in held:
            finish(*item)

    # numpy releases the GIL in its array loops, so chunks overlap on several cores.
    n_workers = max(1, min(workers or os.cpu_count() or 1, len(pieces)))
    # One BLAS thread per worker, even with one worker: the products here are thin
    # ((N, K) @ (K, <= 9)), so BLAS threads only spin, which measured several times slower
    # (and worse still on a busy machine), besides oversubscribing the cores.
    with threadpool_limits(1), ThreadPoolExecutor(n_workers) as pool:
        # Submitted first, so a worker takes it before any chunk; the other workers select
        # chunks meanwhile.
        context = _Context(pool.submit(solver.prepare, gather, pixels, **options)
                           if hasattr(solver, "prepare") else None)
        for future in [pool.submit(work) for _ in range(n_workers)]:
            future.result()
    shared = {key: context.get(key) for key in ("shape_paper", "shape_check", "select")}
    return (out, shared), (np.concatenate(mismatch) if mismatch else np.zeros(0))


#: Bytes of observations (float64) a worker holds selected ahead while the shared context is
#: prepared; the selection's weights make about three times that. 32 MiB is 20 chunks of 2048
#: pixels x 96 lights, which on that object takes the wall time from 0.46 to 0.42 s (2 cores).
LOOKAHEAD_BYTES = 32 * 2**20


class _OnePhase:
    """A method with no selection phase of its own, run whole in :meth:`fit`."""

    def __init__(self, solver):
        self.solver = solver

    def select(self, obs, valid, lights, context=None, **_):
        return {"obs": obs, "valid": valid, "lights": lights}

    def fit(self, picked, context=None, **options):
        return self.solver(picked["obs"], picked["valid"], picked["lights"], context=context, **options)


class _Context:
    """A method's prepared context (a dict), computed in the background; ``get`` waits for it."""

    def __init__(self, future):
        self._future = future

    def ready(self):
        return self._future is None or self._future.done()

    def get(self, key, default=None):
        return default if self._future is None else self._future.result().get(key, default)

    def known(self):
        """The context if it is ready, else an empty dict (never waits)."""
        return self._future.result() if self._future is not None and self._future.done() else {}


def _known(context):
    """What a context (a plain dict, a :class:`_Context` or None) holds already, without waiting."""
    return context.known() if isinstance(context, _Context) else (context or {})


def _allocate(shape, n_params):
    h, w = shape
    return {"normals": np.zeros((h, w, 3), np.float32), "status": np.zeros((h, w), np.uint8),
            "albedo": np.zeros((h, w), np.float32), "params": np.zeros((h, w, n_params), np.float32),
            "residual": np.zeros((h, w), np.float32), "used": np.zeros((h, w), np.uint16)}


def _scatter(out, idx, chunk):
    rows, cols = np.unravel_index(idx, out["status"].shape)
    b = chunk["b"]
    albedo = np.linalg.norm(b, axis=1)
    ok = np.isfinite(b).all(axis=1) & (albedo > 0) & (chunk["status"] != STATUS["too_few"]) \
        & (chunk["status"] != STATUS["shadowed"])
    normals = np.where(ok[:, None], b / np.where(ok, albedo, 1.0)[:, None], 0.0)
    out["normals"][rows, cols] = normals
    out["albedo"][rows, cols] = np.where(ok, albedo, 0.0)
    out["status"][rows, cols] = chunk["status"]
    out["params"][rows, cols] = np.where(ok[:, None], np.nan_to_num(chunk["params"]), 0.0)
    used = np.maximum(chunk["used"], 1)
    rms = np.sqrt(np.maximum(chunk["rss"], 0) / used) / np.where(ok, albedo, 1.0)
    out["residual"][rows, cols] = np.where(ok, np.nan_to_num(rms), 0.0)
    out["used"][rows, cols] = chunk["used"]


#: The shared-shape prior assumes one material. It is used only when one shape leaves at most
#: this many times the residual that free per-pixel shapes leave, over what their extra
#: parameters alone explain. Measured on the 2,000-pixel samples: DiLiGenT ball 1.3, cat 2.1;
#: the simulated two-material object under a DiLiGenT cone 6.7 and 26 (where the prior cost
#: 7.95 vs 5.72 and 14.7 vs 2.3 degrees).
ONE_MATERIAL_RATIO = 4.0
#: ... and only tested when pixels have this many selected observations (median): three times
#: the 12 unknowns of a free pixel, so its fit leaves residual to compare (DiLiGenT: 85-91).
MIN_CHECK_OBS = 36


def single_material_check(obs, weights, b, b_shared, shape, lights, h, y):
    """Whether one biquadratic shape explains the sampled pixels about as well as free ones.

    Parameters
    ----------
    obs, weights : ndarray (N, K)
        A sample of pixels and their selected observations.
    b : ndarray (N, 3)
        Their initial albedo-scaled normals; ``b_shared`` the ones fitted with ``shape`` (3, 3).
    lights, h, y
        As for :func:`pipeline.ps_biquadratic.alternate_shared` (or per pixel).

    Returns
    -------
    dict
        ``ratio``: residual with the shared shape over the residual with free per-pixel shapes;
        ``expected``: that ratio from the parameter counts alone (3 vs 12 per pixel) under pure
        noise; ``one_material``: ratio <= :data:`ONE_MATERIAL_RATIO` x expected, or True with
        ``tested`` False when the pixels have fewer than :data:`MIN_CHECK_OBS` observations.
    """
    y_arr = np.asarray(y, float)
    y3 = _powers(y_arr, 2)
    shared = _shared_state(obs, weights, b_shared, shape, lights, h, y3)[0]
    if lights.ndim == 2:
        free = float(np.nansum(alternate_shared(obs, weights, b, lights, h, y_arr)[2]))
    else:  # per-pixel lights: the same alternation, with the per-pixel steps
        # (free shapes at the initial normals alone leave more residual: on the two-material
        # object of tests/pipeline/test_shape_check.py the ratio read 3.47 there, 6.24 alternated)
        b_free, coeffs, rss = b.copy(), np.zeros((len(obs), 3, 3)), np.zeros(len(obs))
        _Biquadratic._alternate(obs, weights, b_free, coeffs, rss, np.arange(len(obs)), lights, h, y_arr,
                                None, 0.0, 10, 1e-6)
        free = float(np.nansum(rss))
    used = np.sum(weights > 0, axis=1)
    expected = float(np.sum(np.maximum(used - 3, 1)) / np.sum(np.maximum(used - 12, 1)))
    ratio = shared / max(free, 1e-300)
    check = {"ratio": round(ratio, 4), "expected": round(expected, 4),
             "one_material": bool(ratio <= ONE_MATERIAL_RATIO * expected)}
    if np.median(used) < MIN_CHECK_OBS:
        # free shapes all but interpolate so few observations: the ratio then measures how far
        # the material is from biquadratic, not how many materials there are; keep the prior
        check.update(one_material=True, tested=False)
    return check


# ----------------------------------------------------------------------------- methods
METHODS = {}


def register_method(name):
    def deco(func):
        METHODS[name] = func
        return func
    return deco


def _method(name):
    if name in METHODS:
        return METHODS[name]
    from .reflectance import MODELS
    if name in MODELS:
        return _make_generic(name)
    from .reflectance import MODELS as known
    raise InputError(f"unknown photometric stereo method {name!r}; known: "
                     f"{', '.join(sorted(set(METHODS) | set(known)))}")


def _base_status(weights, base):
    used = weights.sum(axis=1)
    status = np.full(len(weights), STATUS["ok"], np.uint8)
    status[used < MIN_OBS] = STATUS["too_few"]
    status[base.sum(axis=1) == 0] = STATUS["shadowed"]
    return status, used


WIDE_SPREAD_DEG = 45.0
WIDE_T_LOW = 0.35
WIDE_T_SHADOW = 0.02
#: The narrow-cone fallback when the object fails the single-material check: the paper's
#: darkest-fraction rule with its wide-cone value (one value of the paper's 20-40 % for both).
#: The rule is worse conditioned under a narrow cone than robust selection with the prior, but
#: a prior fitted to two materials biases both. Measured (tests/pipeline/test_shape_check.py's
#: object, 64 lights in a 42-degree cone; mean error, noisy / noise-free): sharp lobes, default
#: 2.62 / 2.45, t_low 0.25-0.4: 0.44-0.62 / 0.03-0.07; broad lobes, default 5.98 / 5.94, t_low
#: 0.25-0.4: 1.37-1.59 / 0.89-1.32 degrees. No value of the range wins on all four.
FALLBACK_T_LOW = WIDE_T_LOW


def light_spread_deg(lights):
    """90th percentile of the lights' angles from their mean direction, in degrees."""
    shared = lights if lights.ndim == 2 else lights.reshape(lights.shape[0], -1, 3).mean(axis=1)
    mean = shared.mean(axis=0)
    mean = mean / max(np.linalg.norm(mean), 1e-12)
    return float(np.percentile(np.degrees(np.arccos(np.clip(shared @ mean, -1, 1))), 90))


def resolve_selection(lights, options):
    """Turn ``selection='auto'`` (the default) into concrete options from the light geometry.

    Wide light sets (spread > 45 degrees, e.g. domes): the paper's darkest-fraction rule
    (t_low 0.35, inside the paper's 20-40 %) after a 2 % shadow threshold (lights that reach
    grazing angles make dim observations informative), with independent per-pixel fits; the
    darkest observations then surround each
    normal, and a broad specular lobe, which covers most observations, is left out by
    intensity. Narrow cones (DiLiGenT, about 40 degrees): that rule is ill-conditioned (the
    darkest lights all sit on one side), so robust residual-based rejection and the shared-shape
    prior are used; if the object fails the single-material check, the prior is dropped and
    every pixel uses the darkest ``fallback_t_low`` fraction instead (default
    :data:`FALLBACK_T_LOW`, None for no fallback). Explicit ``t_low``/``shape_prior``/``selection``
    options always win; an explicit ``selection`` or ``t_low`` also turns the fallback off.
    """
    options = dict(options)
    if options.get("selection", "auto") != "auto" or options.get("t_low") is not None:
        options.setdefault("selection", "robust")
        if options["selection"] == "auto":
            options["selection"] = "robust"
        options.pop("fallback_t_low", None)   # the caller chose the selection
        return options
    if light_spread_deg(np.asarray(lights, float)) > WIDE_SPREAD_DEG:
        options.update(selection="darkest", t_low=WIDE_T_LOW)
        options.setdefault("shape_prior", 0.0)
        options.setdefault("t_shadow", WIDE_T_SHADOW)
        options.pop("fallback_t_low", None)
    else:
        options["selection"] = "robust"
        fraction = options.setdefault("fallback_t_low", FALLBACK_T_LOW)
        if fraction is not None and not 0 < fraction <= 1:
            raise InputError(f"fallback_t_low must be in (0, 1] or None, got {fraction}")
    return options


def _select(obs, valid, lights, t_low=None, t_shadow=0.1, reject_k=2.5, selection="robust", **_):
    """Base (non-shadowed) and selected weights plus the Lambertian start b."""
    base = shadow_weights(obs, valid, t_shadow)
    if t_low is None:
        weights, b = select_robust(obs, lights, base, k_high=reject_k, k_low=reject_k)
    else:
        if not 0 < t_low <= 1:
            raise InputError(f"t_low must be in (0, 1], got {t_low}")
        weights = select_darkest(obs, base, t_low)
        b = lambert_weighted(obs, lights, weights)
    return base, weights, b


@register_method("lambert")
def lambert_method(obs, valid, lights, context=None, **_):
    """Lambertian least squares on every valid observation."""
    weights = np.ones_like(obs) if valid is None else valid.astype(obs.dtype)
    b = lambert_weighted(obs, lights, weights)
    status, used = _base_status(weights, weights)
    rss = np.sum(weights * (obs - _shading(b, lights)) ** 2, axis=1)
    return {"b": b, "status": status, "used": used, "rss": rss, "params": np.linalg.norm(b, axis=1)[:, None]}


@register_method("lambert-low")
def lambert_low_method(obs, valid, lights, context=None, **options):
    """Lambertian least squares on the selected (low-frequency) observations."""
    base, weights, b = _select(obs, valid, lights, **options)
    status, used = _base_status(weights, base)
    rss = np.sum(weights * (obs - _shading(b, lights)) ** 2, axis=1)
    return {"b": b, "status": status, "used": used, "rss": rss, "params": np.linalg.norm(b, axis=1)[:, None]}


def _shading(b, lights):
    return b @ lights.T if lights.ndim == 2 else np.einsum("ni,nki->nk", b, lights)


class _Biquadratic:
    """The default method; see the module docstring and :func:`biquadratic_method`."""

    def prepare(self, gather, pixels, shape_prior=0.01, sample_pixels=2000, seed=0, fallback_t_low=None,
                **options):
        """Fit the shared shape on a fixed random subsample of the object's pixels.

        Returns the context every chunk is solved with (the tiled stage computes it once and
        hands the same dict to every tile): ``shape`` (3, 3) and ``shape_paper`` (9,) when the
        prior is used, ``shape_check`` (:func:`single_material_check`), and ``select``, the
        selection options of the darkest-fraction fallback when the check failed and
        ``fallback_t_low`` is set (by :func:`resolve_selection`, on the automatic narrow-cone path).
        """
        if shape_prior is None or shape_prior <= 0 or options.get("shared_shape") is False:
            return {}
        rng = np.random.default_rng(seed)
        take = np.sort(rng.choice(len(pixels), min(sample_pixels, len(pixels)), replace=False))
        obs, valid, lights = gather(pixels[take])
        base, weights, b = _select(obs, valid, lights, **options)
        good = weights.sum(axis=1) >= 12
        if good.sum() < 20:
            return {}
        h, y = half_vectors(lights)
        sel = (lambda a: a[good]) if lights.ndim == 3 else (lambda a: a)
        shape, b_shared = fit_shared_shape(obs[good], weights[good], b[good], sel(lights), sel(h), sel(y),
                                           iterations=12)
        if not np.isfinite(shape).all():
            return {}
        if options.get("shape_check") is False:  # the caller insists on the prior
            return {"shape": shape, "shape_paper": to_paper_order(shape)}
        check = single_material_check(obs[good], weights[good], b[good], b_shared, shape, sel(lights), sel(h),
                                      sel(y))
        if not check["one_material"]:
            if not fallback_t_low:
                return {"shape_check": check}
            return {"shape_check": dict(check, fallback=f"darkest t_low {fallback_t_low:g}"),
                    "select": {"selection": "darkest", "t_low": float(fallback_t_low)}}
        return {"shape": shape, "shape_paper": to_paper_order(shape), "shape_check": check}

    def __call__(self, obs, valid, lights, context=None, **options):
        return self.fit(self.select(obs, valid, lights, context=context, **options), context=context, **options)

    def select(self, obs, valid, lights, context=None, **options):
        """Phase one of a chunk, which never waits for the shared shape: its observations'
        selection. Returns what :meth:`fit` takes."""
        switch = _known(context).get("select")
        base, weights, b = _select(obs, valid, lights, **{**options, **(switch or {})})
        return {"obs": obs, "valid": valid, "lights": lights, "base": base, "weights": weights, "b": b,
                "switched": switch is not None}

    def fit(self, picked, context=None, shape_prior=0.01, max_iter=10, tol=1e-6, min_model_obs=12,
            fallback_t_low=None, **options):
        """Phase two: the model fit of a :meth:`select`-ed chunk (waits for the shared shape)."""
        obs, valid, lights = picked["obs"], picked["valid"], picked["lights"]
        base, weights, b = picked["base"], picked["weights"], picked["b"]
        prior = (context or {}).get("shape")   # may wait for the shared shape
        if not picked["switched"] and (context or {}).get("select"):
            # the context was not ready when this chunk selected, and the check failed
            base, weights, b = _select(obs, valid, lights, **{**options, **context.get("select")})
        status, used = _base_status(weights, base)
        h, y = half_vectors(lights)
        coeffs = np.zeros((len(obs), 3, 3))
        coeffs[:, 0, 0] = 1.0
        rss = np.sum(weights * (obs - _shading(b, lights)) ** 2, axis=1)
        fit = used >= min_model_obs
        status[(used >= MIN_OBS) & ~fit] = STATUS["lambert_fallback"]
        active = np.flatnonzero(fit)
        ridge = shape_prior if prior is not None else 1e-10
        if lights.ndim == 2:
            b_fit, c_fit, rss_fit, moving = alternate_shared(obs[active], weights[active], b[active], lights, h, y,
                                                             prior=prior, shape_prior=ridge, max_iter=max_iter,
                                                             tol=tol)
            b[active], coeffs[active] = b_fit, c_fit
            rss[active] = np.where(np.isnan(rss_fit), rss[active], rss_fit)
            active = active[moving]
        else:
            active = self._alternate(obs, weights, b, coeffs, rss, active, lights, h, y, prior, ridge, max_iter, tol)
        status[active] = STATUS["not_converged"]
        return {"b": b, "status": status, "used": used, "rss": rss, "params": to_paper_order(coeffs)}

    @staticmethod
    def _alternate(obs, weights, b, coeffs, rss, active, lights, h, y, prior, ridge, max_iter, tol):
        """The alternation for per-pixel lights; updates b, coeffs, rss; returns the pixels still moving."""
        scale = np.sum(weights * obs**2, axis=1) + 1e-300
        for _ in range(max_iter):
            if active.size == 0:
                break
            sub = _rows(active, lights, h, y)
            c = fit_pixel_shapes(obs[active], weights[active], b[active], *sub, prior=prior, shape_prior=ridge)
            b_new, before, after = gauss_newton_normals(obs[active], weights[active], b[active], c, *sub)
            better = np.isfinite(after) & (after <= before * (1 + 1e-9))
            b[active[better]] = b_new[better]
            coeffs[active] = c
            rss[active] = np.where(better, after, before)
            done = ~better | (np.abs(before - after) <= tol * scale[active])
            active = active[~done]
        return active


def _rows(idx, lights, h, y):
    if lights.ndim == 2:
        return lights, h, y
    return lights[idx], h[idx], y[idx]


METHODS["biquadratic"] = _Biquadratic()


def biquadratic_method(obs, valid, lights, **options):
    """Options of the default method.

    Parameters
    ----------
    selection : {'auto', 'robust', 'darkest'}
        'auto' (default) picks from the light geometry, see :func:`resolve_selection`.
    t_low : float, optional
        The paper's rule: keep the darkest ``t_low`` fraction (0-1) of each pixel's
        non-shadowed observations. Default None (robust selection, or 0.35 for wide lights).
    t_shadow : float
        Observations below this fraction of the pixel's 90th-percentile intensity are shadows
        (default 0.1).
    reject_k : float
        Robust rejection threshold in robust standard deviations (default 2.5).
    shape_prior : float
        Strength of the pull toward the object's shared shape (default 0.01; 0 = the paper's
        independent per-pixel fit).
    fallback_t_low : float, optional
        Set by :func:`resolve_selection` on the automatic narrow-cone path (default
        :data:`FALLBACK_T_LOW`; None turns the fallback off): when the object fails the
        single-material check, every pixel keeps its darkest ``fallback_t_low`` fraction and is
        fitted without the prior.
    max_iter, tol
        Alternation limit (10) and convergence threshold: relative change of the pixel's
        residual (1e-6; the paper stops at an absolute change of 1e-7).
    specular_anchor : {'auto', True, False}
        Handled by :func:`estimate_normals` (not by this per-chunk function): correct the
        lights' polar angles from sharp specular peaks, see :mod:`pipeline.ps_anchor`.
    """
    return METHODS["biquadratic"](obs, valid, lights, context={}, **options)


def _make_generic(name):
    from .reflectance import Geometry, get_model

    model = get_model(name)

    def generic(obs, valid, lights, context=None, max_iter=20, tol=1e-7, **options):
        base, weights, b = _select(obs, valid, lights, **options)
        status, used = _base_status(weights, base)
        n = unit(b)
        params = None
        rss = np.zeros(len(obs))
        prev = None
        for _ in range(max_iter):
            geom = Geometry.from_vectors(n, lights)
            shading = np.maximum(geom.nl, 0.0)
            params = model.fit(geom, obs, shading=shading, weights=weights)
            rho = model.evaluate(params, geom)
            b = lambert_weighted(obs, lights, weights, factor=rho)
            n = unit(b)
            geom = Geometry.from_vectors(n, lights)
            rss = np.sum(weights * (obs - model.evaluate(params, geom) * np.maximum(geom.nl, 0)) ** 2, axis=1)
            if prev is not None and np.all(np.abs(prev - rss) <= tol * (np.sum(weights * obs**2, axis=1) + 1e-300)):
                break
            prev = rss
        # b's scale is arbitrary here (rho carries the albedo); report |b| as 1 x mean rho.
        albedo = np.nanmean(np.where(weights > 0, model.evaluate(params, Geometry.from_vectors(n, lights)), np.nan), axis=1)
        return {"b": n * np.nan_to_num(albedo, nan=1.0)[:, None], "status": status, "used": used, "rss": rss,
                "params": np.asarray(params).reshape(len(obs), -1)}

    return generic
