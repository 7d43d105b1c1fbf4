"""Photometric stereo's dispatcher: surface normals from images under known lights.

>>> result = estimate_normals(images, lights, mask=None, method="biquadratic")

:func:`estimate_normals` checks its inputs, turns the options into a :class:`SolvePlan`
(:func:`plan_solve`: the method from :data:`pipeline.photometric.methods.METHODS`, the
observation selection from the light geometry, whether to anchor the lights on specular
peaks), runs the chunk engine (:func:`pipeline.photometric.engine.run_chunks`) once, or up to
three times when the specular anchor corrects the lights (:mod:`pipeline.photometric.anchor`),
and returns a :class:`PhotometricResult`. The tiled stage (:mod:`pipeline.photometric.tiles`)
makes the same plan and the same result from its tiles.
"""

import os
import time
from dataclasses import dataclass, field, replace

import numpy as np

from ..core.errors import InputError
from ..core.jit import single_threaded
from .anchor import anchor_scale, anchor_wanted, first_verdict
from .consensus import consensus_record, refine_run
from .engine import CHUNK_SIZE, KeptSelection, gatherer, prepare_context, run_chunks
from .flags import PackedFlags
from .frame_gains import FrameCheck, check_frames
from .methods import STATUS, check_method_options, get_method, method_traits
from .near_lights import PointLights
from .outline import outline_check
from .selection import DARKEST_LEVERAGE_MAX, SURROUND_SAMPLE, darkest_leverage, resolve_selection
from .uncertainty import UNCERTAIN_DEG, uncertainty_map, uncertainty_summary

__all__ = ["estimate_normals", "PhotometricResult", "SolvePlan", "plan_solve", "check_plan_frames",
           "check_plan_selection", "check_lights",
           "result_from_maps"]


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
        Codes of :data:`pipeline.photometric.STATUS` (ok, shadowed, too_few, not_converged,
        lambert_fallback, shared_shape, ill_posed, uncertain: an ``ok`` pixel whose expected
        error is over ``uncertain_deg``; its normal is kept).
    albedo : ndarray (H, W) float32
        Diffuse scale (|b|), in units of the input intensities.
    params : ndarray (H, W, P) float32
        Reflectance parameters per pixel (biquadratic: A..I of Eq. 2, relative to albedo).
    residual : ndarray (H, W) float32
        Root-mean-square residual over the used observations, relative to the albedo.
    used : ndarray (H, W) uint16
        Number of observations used per pixel.
    lit : ndarray (H, W) uint16
        Number of observations above the shadow threshold per pixel (the ones the selection
        chose from; ``used`` for methods that use every valid observation).
    leverage : ndarray (H, W) float32
        :func:`pipeline.photometric.lambert.normal_leverage`: the normal's angular standard
        deviation (radians) per unit of noise relative to the albedo, from the lights each pixel
        used; NaN where there is no normal.
    uncertainty : ndarray (H, W) float32 or None
        Each pixel's expected angular error in degrees (:mod:`pipeline.photometric.uncertainty`),
        NaN where there is no normal; None when it cannot be estimated (``options["uncertainty"]``
        says why).
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
    lit: np.ndarray = None
    leverage: np.ndarray = None
    uncertainty: np.ndarray = None


@dataclass
class SolvePlan:
    """What an estimation runs, decided once from the method, the lights and the options.

    Attributes
    ----------
    method : str
        The method's name; ``solver`` the registered method itself.
    lights : ndarray (K, 3) or (K, H, W, 3)
        Unit directions toward the lights, camera frame (for near lights: their central
        directions, which the selection rule and the summaries use).
    near : PointLights or None
        Near point lights, whose per-pixel directions the engine computes chunk by chunk.
    options : dict
        The method's options after :func:`pipeline.photometric.selection.resolve_selection`.
    anchor : bool
        Whether to anchor the lights on specular peaks; ``insist`` whether the caller asked for
        it (``specular_anchor=True``), which also corrects an object that failed the single-material
        check.
    frame_gains : {'auto', True, False}
        How the frames' brightness is checked (:mod:`pipeline.photometric.frame_gains`);
        ``gains`` (K,) the frames' gains the solve divides by (None: as given) and
        ``gain_check`` the check's record, both set by :func:`check_plan_frames`.
    neighbour_consensus : bool
        Whether the method's option ``neighbour_consensus`` asks for the neighbours' vote on the
        selection (:mod:`pipeline.photometric.consensus`); it runs under the robust selection only
        (:attr:`votes`).
    """

    method: str
    solver: object
    lights: np.ndarray
    near: PointLights = None
    options: dict = field(default_factory=dict)
    anchor: bool = False
    insist: bool = False
    frame_gains: object = "auto"
    uncertain_deg: float = UNCERTAIN_DEG
    given: dict = None
    specular_anchor: object = "auto"
    gains: np.ndarray = None
    gain_check: dict = None
    neighbour_consensus: bool = False

    @property
    def votes(self):
        """Whether the run votes: ``neighbour_consensus`` asked for, with the robust selection."""
        return self.neighbour_consensus and self.options.get("selection") == "robust"

    @property
    def solver_lights(self):
        """The lights as the engine's gatherer takes them: the near lights, else the directions."""
        return self.near if self.near is not None else self.lights


def check_lights(lights, count, shape):
    """Validated lights for ``count`` images of ``shape`` (H, W): unit directions or PointLights.

    Raises InputError for a count or shape that does not match, a zero or non-finite direction,
    or lights of rank < 3 (coplanar: the normals are not determined).
    """
    if count < 3:
        raise InputError(f"photometric stereo needs at least 3 lights, got {count}")
    if isinstance(lights, PointLights):
        if len(lights) != count:
            raise InputError(f"{len(lights)} light positions for {count} images")
        if lights.shape != tuple(shape):
            raise InputError(f"near lights are for images {lights.shape}, the images are {tuple(shape)}")
        _check_rank(lights.central_directions)
        return lights
    lights = np.asarray(lights, dtype=float)
    if lights.shape[0] != count:
        raise InputError(f"{lights.shape[0]} light directions for {count} images")
    if lights.shape not in ((count, 3), (count, *shape, 3)):
        raise InputError(f"lights must be (K, 3) or (K, H, W, 3), got {lights.shape} for {count} images "
                         f"of {tuple(shape)}")
    finite = np.isfinite(lights).reshape(count, -1).all(axis=1)
    if not finite.all():
        raise InputError(f"light {int(np.argmin(finite))} has a non-finite direction")
    norms = np.linalg.norm(lights, axis=-1).reshape(count, -1)
    if (norms < 1e-9).any():
        raise InputError(f"light {int(np.argmax((norms < 1e-9).any(axis=1)))} has a zero direction vector")
    lights = lights / np.linalg.norm(lights, axis=-1, keepdims=True)
    _check_rank(lights if lights.ndim == 2 else lights.reshape(count, -1, 3).mean(axis=1))
    return lights


def _check_rank(shared):
    if np.linalg.matrix_rank(shared, tol=1e-6) < 3:
        raise InputError("light directions have rank < 3 (coplanar lights): normals are not determined")


def _check_images(images, mask, valid):
    images = np.asarray(images)
    if images.ndim != 3:
        raise InputError(f"images must be a (K, H, W) stack of grey linear images, got shape {images.shape}")
    k, height, width = images.shape
    if k < 3:
        raise InputError(f"photometric stereo needs at least 3 images, got {k}")
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
        valid = valid if isinstance(valid, PackedFlags) else np.asarray(valid, dtype=bool)
        if valid.shape != images.shape:
            raise InputError(f"valid shape {valid.shape} does not match the images' {images.shape}")
    # One image at a time: images[:, mask] would copy the whole masked stack (peak memory).
    for i in range(k) if images.dtype.kind == "f" else ():
        if not np.isfinite(images[i][mask]).all():
            raise InputError(f"image {i} has non-finite pixel values inside the mask")
    return images, mask, valid


def plan_solve(method, lights, options):
    """The :class:`SolvePlan` for ``method`` with checked ``lights`` (see :func:`check_lights`)."""
    solver = get_method(method)
    near = lights if isinstance(lights, PointLights) else None
    directions = near.central_directions if near is not None else lights
    given = dict(options)
    options = resolve_selection(directions, options)
    specular_anchor = options.pop("specular_anchor", "auto")
    frame_gains = options.pop("frame_gains", "auto")
    # checked with the method's options (its declaration: above 0) before any plan is made
    uncertain_deg = options.pop("uncertain_deg", None)
    uncertain_deg = UNCERTAIN_DEG if uncertain_deg is None else float(uncertain_deg)
    consensus = options.pop("neighbour_consensus", None)
    if consensus is None:   # the method's declared default (False for a method without the option)
        consensus = method_traits(solver).options.defaults().get("neighbour_consensus", False)
    anchor = anchor_wanted(method_traits(solver).wants_anchor, specular_anchor, options, directions, near)
    return SolvePlan(method, solver, directions, near, options, anchor, specular_anchor is True, frame_gains,
                     uncertain_deg, given, specular_anchor, neighbour_consensus=bool(consensus))


def check_plan_selection(plan, gather, pixels):
    """``plan`` with the light layout's choice of the darkest-fraction rule checked on the images.

    :func:`pipeline.photometric.selection.resolve_selection` takes the paper's rule for a wide
    light set (a percentile of the layout). That rule needs the lights it keeps to determine
    each normal; a few lights of which two stray push the percentile past the limit while the
    rest sit in a narrow cone, and the 3-4 darkest of 10 then sit on one side (DiLiGenT ball's
    lights 7, 12, 41, 42, 61, 68, 69, 86, 87, 94: 8.3 degrees against Lambert's 5.2). So on a
    sample of the pixels the noise amplification of the lights it keeps is measured
    (:func:`pipeline.photometric.selection.darkest_leverage`); over
    :data:`pipeline.photometric.selection.DARKEST_LEVERAGE_MAX` the robust selection is used,
    as under a narrow cone. Only the rule the layout chose by default is checked; the verdict
    is ``options["selection_check"]``.
    """
    if plan.given is None or plan.method == "lambert" or plan.options.get("selection") != "darkest" or \
            plan.given.get("selection", "auto") != "auto" or plan.given.get("t_low") is not None:
        return plan
    rng = np.random.default_rng(0)
    sample = np.sort(rng.choice(pixels, min(SURROUND_SAMPLE, len(pixels)), replace=False))
    obs, valid, lights = gather(sample)
    leverage = darkest_leverage(obs, valid, lights, plan.options)
    check = {"layout": "wide", "darkest_leverage": round(leverage, 3), "limit": DARKEST_LEVERAGE_MAX}
    if not leverage > DARKEST_LEVERAGE_MAX:
        check["verdict"] = "darkest"
        return replace(plan, options=dict(plan.options, selection_check=check))
    check["verdict"] = "robust: the darkest observations do not determine the normals"
    options = resolve_selection(plan.lights, dict(plan.given, selection="robust"))
    for key in ("specular_anchor", "frame_gains", "uncertain_deg", "neighbour_consensus"):   # the plan's own
        options.pop(key, None)
    anchor = anchor_wanted(method_traits(plan.solver).wants_anchor, plan.specular_anchor, options, plan.lights,
                           plan.near)
    return replace(plan, options=dict(options, selection_check=check), anchor=anchor)


def check_plan_frames(plan, gather, pixels):
    """``plan`` with its frames' gains measured (:func:`pipeline.photometric.frame_gains.check_frames`
    on ``gather``, the images as given, over the object's ``pixels``) and decided."""
    # near lights: an error of the object's depth changes each frame's falloff at every pixel alike,
    # which the check would read as gains (docs/near-lights.md); their gains are checked only when
    # asked for
    plan = check_plan_selection(plan, gather, pixels)
    mode = False if plan.near is not None and plan.frame_gains == "auto" else plan.frame_gains
    # unchecked, no sample is gathered (near lights' per-pixel directions cost; the near-depth
    # search solves many times)
    check = FrameCheck.unchecked(len(plan.lights)) if mode is False else \
        check_frames(gather, pixels, plan.options, mode=mode)
    return replace(plan, gains=check.applied(), gain_check=check.record())


def estimate_normals(images, lights, mask=None, method="biquadratic", *, valid=None, chunk_size=CHUNK_SIZE,
                     workers=None, progress=None, **options):
    """Estimate surface normals per pixel.

    Parameters
    ----------
    images : ndarray (K, H, W)
        Linear grey images, light intensities divided out.
    lights : ndarray (K, 3) or (K, H, W, 3), or PointLights
        Unit directions toward the lights, camera frame (per pixel for near lights), or near
        point lights (:class:`pipeline.photometric.PointLights`), whose per-pixel directions
        and inverse-square falloff are computed chunk by chunk (the falloff is divided out).
    mask : ndarray (H, W) bool, optional
        Pixels to process; default: pixels lit in some image.
    method : str
        A name in :data:`pipeline.photometric.METHODS` (which holds every registered
        reflectance model too).
    valid : ndarray (K, H, W) bool or PackedFlags, optional
        False for observations that must not be used (saturated pixels); a
        :class:`pipeline.photometric.flags.PackedFlags` holds them in an eighth of the memory.
    chunk_size : int
        Pixels processed at once (memory per chunk is about chunk_size x K x 200 bytes).
    workers : int, optional
        Threads working on chunks at once (default: the number of cores).
    progress : callable, optional
        Called with the number of pixels finished after each chunk.
    **options
        The method's options (its declaration: :class:`pipeline.settings.BiquadraticOptions`
        for the default, :class:`pipeline.settings.SelectionOptions` for the Lambertian ones;
        an unknown name is an InputError listing the known ones), and ``specular_anchor`` ('auto', True or False): correct the lights' polar angles where
        sharp specular peaks show the normals' slant to be off (:mod:`pipeline.photometric.anchor`;
        'auto' = the biquadratic method under a narrow light cone). Its outcome is in the
        result's ``options`` (``cone_scale``, 1.0 when unchanged, ``anchor``, ``mismatch_deg``,
        ``highlight_pixels``); a corrected run costs a probe on the pixels that peaked and a
        second fit of every pixel on the first run's selection of observations. And
        ``frame_gains`` ('auto', True or False): check each frame's brightness against the
        others before the fit and rescale the frames that depart
        (:mod:`pipeline.photometric.frame_gains`; 'auto' = the frames more than 16 % and more
        than their own spread off, True = every frame, False = none; near lights only when
        True); its outcome is the result's ``options["frame_check"]``.

    Returns
    -------
    PhotometricResult
    """
    start = time.perf_counter()
    options = check_method_options(method, options)
    images, mask, valid = _check_images(images, mask, valid)
    plan = plan_solve(method, check_lights(lights, images.shape[0], images.shape[1:]), options)
    k = images.shape[0]
    flat_images = images.reshape(k, -1)
    flat_valid = valid if valid is None or isinstance(valid, PackedFlags) else valid.reshape(k, -1)
    pixels = np.flatnonzero(mask)
    plan = check_plan_frames(plan, gatherer(flat_images, flat_valid, plan.solver_lights), pixels)
    runs, probes, votes = [], [], []
    # the anchor's corrected run keeps the first run's selection (reuse_selection); the
    # neighbours' vote reads the selection of the run it refines
    kept = KeptSelection(pixels, k) if plan.anchor or plan.votes else None

    def run(run_lights, on=pixels, context=None, reuse=None):
        gather = gatherer(flat_images, flat_valid, plan.near if plan.near is not None else run_lights,
                          gains=plan.gains)
        # a probe (some pixels only) measures the anchor's slope on the first pass: it does not vote
        vote = plan.votes and on is pixels
        keep = kept if not runs else KeptSelection(pixels, k) if vote else None
        done = run_chunks(plan.solver, gather, on, mask.shape, plan.options, anchor=plan.anchor,
                          chunk_size=chunk_size, workers=workers, context=context,
                          progress=progress if on is pixels and not runs else None, keep=keep, reuse=reuse)
        if vote and keep.complete():
            # the anchor's mismatches stay the first pass's (as a tile's: the vote refines normals only)
            veto = refine_run(plan.solver, gather, keep, done.maps, plan.options, done.context,
                              chunk_size=chunk_size, workers=workers)
            votes.append(consensus_record(veto.observations, veto.pixels.size, len(pixels)))
        return done

    def later_context(run_lights, reuse=None):
        # The anchor's runs after the first (other lights) prepare before their chunks, on every
        # core: the corrected run selects nothing anew (the first run's selection is kept), the
        # probe's chunks are few. Both keep the first run's single-material verdict rather than
        # testing again (about a third of a preparation). Their shared shape starts from the last
        # run's (warm): the lights differ by a few percent of their polar angles.
        gather = gatherer(flat_images, flat_valid, run_lights, gains=plan.gains)
        options = dict(plan.options, threads=workers or os.cpu_count() or 1)
        check = runs[0].shared.get("shape_check")
        if check is not None and "fallback" not in check:
            options["shape_check"] = False
        if reuse is not None:
            options["chosen"] = reuse.get
        options["warm"] = (probes or runs)[-1].context
        with single_threaded():
            context = prepare_context(plan.solver, gather, pixels, options)
        return dict(context, shape_check=check) if options.get("shape_check") is False and context else context

    def solve(run_lights):
        # Progress is reported for the first run only: its total is the mask's pixel count.
        # a later run (the corrected one) keeps the first run's selection, when it made one
        reuse = kept if runs and kept is not None and kept.complete() else None
        done = run(run_lights, context=later_context(run_lights, reuse) if runs else None, reuse=reuse)
        runs.append(done)
        return (done.maps, done.shared), done.mismatch

    def probe(run_lights):
        # a probe only measures how the mismatch answers the cone's scale: the pixels that peaked
        # at the first lights are enough, with the shared shape fitted again for these lights (with
        # the first lights' shape the normals barely follow the scale). It selects afresh: its
        # median mismatch is the secant's slope, which the kept selection would bias
        # (docs/photometric-stereo.md, "Constants")
        probes.append(run(run_lights, on=np.sort(runs[0].peaks), context=later_context(run_lights)))
        return probes[-1].mismatch

    options = dict(plan.options, frame_check=plan.gain_check)
    if plan.anchor:
        (out, shared), info = _anchored(solve, plan.lights, insist=plan.insist, probe=probe)
        options.update(info)
    else:
        out, shared = solve(plan.lights)[0]
    if votes:   # the vote of the run whose maps are returned (the last)
        options["neighbour_consensus"] = votes[-1]
    return result_from_maps(out, mask, method, options, shared, seconds=time.perf_counter() - start, lights=k,
                            uncertain_deg=plan.uncertain_deg)


def result_from_maps(maps, mask, method, options, shared, seconds=0.0, *, lights, uncertain_deg=UNCERTAIN_DEG):
    """The :class:`PhotometricResult` of filled maps and a method's shared context.

    ``shared`` holds the context's ``shape_paper`` and ``shape_check``: the check is reported in
    ``options["shape_check"]``, and after its fallback the options say that the shared shape was
    not used. ``options["outline_check"]`` is :func:`pipeline.photometric.outline.outline_check`
    of the normals. ``lights`` (the number solved with) decides whether the uncertainty map can
    be estimated; ``options["uncertainty"]`` holds its summary, or why there is none. An ``ok``
    pixel whose expected error is over ``uncertain_deg`` degrees is marked ``uncertain`` (its
    normal is kept: integration and the mesh still use it).
    """
    options = dict(options, outline_check=outline_check(maps["normals"], mask))
    leverage = maps.get("leverage")
    uncertainty, reason = uncertainty_map(maps["normals"], maps["status"], maps["residual"], leverage, mask,
                                          lights, maps["used"])
    options["uncertainty"] = reason or uncertainty_summary(uncertainty, mask, uncertain_deg)
    if uncertainty is not None:
        with np.errstate(invalid="ignore"):
            over = (maps["status"] == STATUS["ok"]) & (uncertainty > uncertain_deg)
        maps = dict(maps, status=np.where(over, np.uint8(STATUS["uncertain"]), maps["status"]))
    if shared.get("shape_check") is not None:
        options["shape_check"] = shared["shape_check"]
        if "fallback" in shared["shape_check"]:
            options["shared_shape"] = False
    return PhotometricResult(
        normals=maps["normals"], mask=mask, status=maps["status"], albedo=maps["albedo"], params=maps["params"],
        residual=maps["residual"], used=maps["used"], method=method, options=options, seconds=seconds,
        shared_shape=shared.get("shape_paper"), lit=maps["lit"], leverage=leverage, uncertainty=uncertainty)


def _anchored(solve, lights, insist=False, probe=None):
    """``anchor_scale`` on ``solve``, except when the object failed the single-material check.

    The check (:meth:`pipeline.photometric.biquadratic.Biquadratic.prepare`) is known only after
    the first solve. Its normals are then measured and reported (as the tiled stage reports
    them, from the same first verdict) but not corrected unless the caller insists
    (``specular_anchor=True``): an object of several materials is where a local specular bias is
    likeliest to pass for a global one (the one measured false correction of the anchor came
    from such an object).
    """
    first = solve(lights)
    if "fallback" in (first[0][1]["shape_check"] or {}) and not insist:
        info = first_verdict(first[1])
        if info["anchor"] == "to correct":
            info["anchor"] = "not corrected: several materials"
        return first[0], info
    replay = [first]
    return anchor_scale(lambda run_lights: replay.pop() if replay else solve(run_lights), lights, probe=probe)
