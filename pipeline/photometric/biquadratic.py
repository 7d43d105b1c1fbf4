"""The default method: the paper's relaxed biquadratic model (Eq. 2) per pixel, with psrig's
observation selection and a shared-shape prior.

A chunk runs in two phases. :meth:`Biquadratic.select` picks each pixel's observations
(:mod:`pipeline.photometric.selection`) and never waits; :meth:`Biquadratic.fit` fits
each pixel's normal and 9 coefficients jointly (:mod:`pipeline.photometric.pixel_fit`), its
shape pulled toward a multiple of the object's shared shape, which
:meth:`Biquadratic.prepare` fits once per image on a pixel sample
(:mod:`pipeline.photometric.shared_shape`). When the object fails the single-material check,
every pixel is pulled toward a constant reflectance (:data:`LAMBERT_SHAPE`) instead, with the
same selection. The rules and the measurements behind them: docs/photometric-stereo.md.
"""

import concurrent.futures as futures

import numpy as np

from ..settings.normals import SHAPE_PRIOR, BiquadraticOptions
from .model import half_vectors, to_paper_order
from .pixel_fit import MAX_ITER, TOL_DEG, fit_pixels
from .methods import METHODS, MIN_OBS, STATUS, base_status, facing_away, no_normal, shading
from .selection import reuse_selection, select_observations
from .shared_shape import fit_shared_shape, single_material_check

__all__ = ["Biquadratic", "biquadratic_method", "LAMBERT_SHAPE"]

#: The prior shape when the object has no shared one (several materials, wide light sets):
#: rho constant. Its pull, scale-free like the shared shape's, keeps a pixel's falloff near
#: Lambertian unless its observations say otherwise; without it a wide light set leaves many
#: pixels unconverged (docs/photometric-stereo.md, "Constants").
LAMBERT_SHAPE = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
#: the prior's strength that holds a pixel to a multiple of the shared shape (status shared_shape)
SHAPE_ONLY = 1e6
#: pixels of the image the shared shape is fitted on (a fixed random sample), its
#: Levenberg-Marquardt steps, and the observations a sampled pixel needs to take part: a larger
#: sample or more steps change no object's error by more than 0.02 degree (docs, "Constants")
SAMPLE_PIXELS = 1000
SHAPE_ITERATIONS = 8
#: steps of a shape fitted again under slightly other lights (the specular anchor's probe and
#: corrected run), started from the earlier shape and the sample's earlier normals: the lights
#: differ by a few percent, so a few steps reach the cold fit's root at a fraction of its cost
WARM_ITERATIONS = 3
MIN_SHAPE_OBS = 5
#: a model is fitted at a pixel when its observations exceed the fit's effective parameters
#: (the normal's 2 plus the trace of the coefficients' hat matrix) by this many
SPARE_OBS = 3


class Biquadratic:
    """The default method; see the module docstring and :func:`biquadratic_method`."""

    #: the method's options (:class:`pipeline.core.options.Options`)
    options = BiquadraticOptions
    #: its coefficients render rho (the registration check renders frames from them)
    renders_rho = True
    #: 'auto' anchors its lights on specular peaks under a narrow cone (:mod:`.anchor`)
    wants_anchor = True

    def prepare(self, gather, pixels, shape_prior=SHAPE_PRIOR, sample_pixels=SAMPLE_PIXELS, seed=0,
                min_shape_obs=MIN_SHAPE_OBS, threads=1, chosen=None, warm=None, **options):
        """Fit the shared shape on a fixed random subsample of the object's pixels.

        Returns the context every chunk is solved with (the tiled stage computes it once and
        hands the same dict to every tile): ``shape`` (3, 3) and ``shape_paper`` (9,) when the
        shared shape is used, and ``shape_check`` (:func:`single_material_check`), which holds
        ``fallback`` when the object failed it and its pixels get the Lambertian prior instead.
        ``threads`` > 1 splits the sample's selection and the shape's terms over that many
        threads (for a preparation that nothing else runs beside: the anchor's later runs).
        ``chosen(idx)`` (optional) gives the observations (n, K) bool an earlier run selected
        at flat pixels ``idx``: the sample keeps them (:func:`reuse_selection`). ``warm``
        (optional) is the context an earlier preparation returned under slightly other lights:
        the shape starts from its shape and the sample's normals (``sample_b`` (S, 3), NaN where
        a sampled pixel took no part), for :data:`WARM_ITERATIONS` steps.
        """
        if shape_prior is None or shape_prior <= 0 or options.get("shared_shape") is False:
            return {}
        rng = np.random.default_rng(seed)
        take = np.sort(rng.choice(len(pixels), min(sample_pixels, len(pixels)), replace=False))
        obs, valid, lights = gather(pixels[take])
        base, weights, b = _select_sample(obs, valid, lights, threads, options) if chosen is None else \
            reuse_selection(obs, valid, lights, chosen(pixels[take]), **options)
        good = weights.sum(axis=1) >= min_shape_obs
        if good.sum() < 20:
            return {}
        h, y = half_vectors(lights)
        sel = (lambda a: a[good]) if lights.ndim == 3 else (lambda a: a)
        start, b_start, iterations = None, b, SHAPE_ITERATIONS
        if warm and warm.get("shape") is not None and len(warm.get("sample_b", ())) == len(take):
            start, iterations = warm["shape"], WARM_ITERATIONS
            b_start = np.where(np.isfinite(warm["sample_b"]), warm["sample_b"], b)
        shape, b_shared = fit_shared_shape(obs[good], weights[good], b_start[good], sel(lights), sel(h), sel(y),
                                           iterations=iterations, threads=threads, start=start)
        if not np.isfinite(shape).all():
            return {}
        sample_b = np.full((len(take), 3), np.nan)
        sample_b[good] = b_shared
        if options.get("shape_check") is False:  # the caller insists on the prior
            return {"shape": shape, "shape_paper": to_paper_order(shape), "sample_b": sample_b}
        check = single_material_check(obs[good], weights[good], b[good], b_shared, shape, sel(lights), sel(h),
                                      sel(y))
        if not check["one_material"]:
            return {"shape_check": dict(check, fallback="lambertian prior")}
        return {"shape": shape, "shape_paper": to_paper_order(shape), "shape_check": check, "sample_b": sample_b}

    def __call__(self, obs, valid, lights, context=None, **options):
        return self.fit(self.select(obs, valid, lights, context=context, **options), context=context, **options)

    def select(self, obs, valid, lights, context=None, chosen=None, **options):
        """Phase one of a chunk, which never waits for the shared shape: its observations'
        selection, or with ``chosen`` (N, K) bool the one an earlier run made
        (:func:`reuse_selection`). Returns what :meth:`fit` takes."""
        base, weights, b = select_observations(obs, valid, lights, **options) if chosen is None else \
            reuse_selection(obs, valid, lights, chosen, **options)
        return {"obs": obs, "valid": valid, "lights": lights, "base": base, "weights": weights, "b": b}

    def fit(self, picked, context=None, shape_prior=SHAPE_PRIOR, max_iter=MAX_ITER, tol_deg=TOL_DEG, spare_obs=SPARE_OBS,
            min_shape_obs=MIN_SHAPE_OBS, **options):
        """Phase two: the model fit of a :meth:`select`-ed chunk (waits for the shared shape).

        Each pixel takes the richest model its observations determine: the biquadratic with the
        prior where its observations exceed the fit's effective parameters by ``spare_obs``,
        else the shared shape alone (a multiple of the object's shape, 3 parameters), else the
        Lambertian fit of the selected observations.
        """
        obs, lights = picked["obs"], picked["lights"]
        base, weights, b = picked["base"], picked["weights"], picked["b"]
        prior = (context or {}).get("shape")   # may wait for the shared shape
        status, used = base_status(weights, base, lights)
        h, y = half_vectors(lights)
        coeffs = np.zeros((len(obs), 3, 3))
        coeffs[:, 0, 0] = 1.0
        rss = np.full(len(obs), np.nan)
        status[status == STATUS["ok"]] = STATUS["lambert_fallback"]
        models = [(LAMBERT_SHAPE if prior is None else prior, shape_prior or 0.0, STATUS["ok"])]
        if prior is not None:
            models.append((prior, SHAPE_ONLY, STATUS["shared_shape"]))
        todo = np.flatnonzero((used >= max(min_shape_obs, MIN_OBS + 1)) & (status == STATUS["lambert_fallback"]))
        for shape, strength, code in models:
            if todo.size == 0:
                break
            rows = (lambda a: a) if todo.size == len(obs) else (lambda a: a[todo])   # every pixel: no copies
            sub = (lights, h, y) if lights.ndim == 2 else (rows(lights), rows(h), rows(y))
            # with 11 + spare_obs observations or more every model is determined: no dof needed
            b_fit, c_fit, rss_fit, moving, dof = fit_pixels(rows(obs), rows(weights), rows(b), *sub, prior=shape,
                                                            shape_prior=strength, max_iter=max_iter,
                                                            tol_deg=tol_deg, dof_below=11 + spare_obs)
            # a model whose normal faces away from the camera is not taken: the next simpler one is
            take = np.isfinite(rss_fit) & ~facing_away(b_fit) & (used[todo] - dof >= spare_obs)
            idx = todo[take]
            b[idx], coeffs[idx], rss[idx] = b_fit[take], c_fit[take], rss_fit[take]
            status[idx] = np.where(moving[take], STATUS["not_converged"], code)
            todo = todo[~take]
        lambert = np.flatnonzero(np.isnan(rss))   # the pixels left with their Lambertian fit
        if lambert.size:
            sub = lights if lights.ndim == 2 else lights[lambert]
            rss[lambert] = np.sum(weights[lambert] * (obs[lambert] - shading(b[lambert], sub)) ** 2, axis=1)
        return {"b": b, "status": no_normal(status, b), "used": used, "lit": base.sum(axis=1), "rss": rss,
                "params": to_paper_order(coeffs)}


def _select_sample(obs, valid, lights, threads, options):
    """select_observations of the sample's pixels, in ``threads`` parts at once (a pixel's
    selection depends on that pixel alone)."""
    if threads <= 1 or len(obs) < 128:
        return select_observations(obs, valid, lights, **options)
    def select(rows):
        return select_observations(obs[rows], None if valid is None else valid[rows],
                                   lights[rows] if lights.ndim == 3 else lights, **options)

    with futures.ThreadPoolExecutor(threads) as pool:
        done = list(pool.map(select, np.array_split(np.arange(len(obs)), threads)))
    return tuple(np.concatenate([part[k] for part in done]) for k in range(3))


METHODS.register("biquadratic", Biquadratic())


def biquadratic_method(obs, valid, lights, **options):
    """The default method on one chunk: ``obs`` (N, K), ``valid`` (N, K) or None, ``lights``
    (K, 3) or (N, K, 3); returns the chunk's maps (see :mod:`pipeline.photometric.methods`).

    ``options`` are :class:`pipeline.settings.BiquadraticOptions` (each with its default and
    help there), and the fit's ``max_iter`` and ``tol_deg``: Levenberg-Marquardt steps per
    pixel at most (:data:`MAX_ITER`) and the turn of the normal by its Gauss-Newton step below
    which a pixel stops (:data:`TOL_DEG` degrees); a pixel whose step is still larger after
    ``max_iter`` steps is ``not_converged``. The specular anchor and the frame checks are
    :func:`pipeline.photometric.estimate_normals`' (:class:`pipeline.settings.EstimateOptions`).
    """
    return METHODS["biquadratic"](obs, valid, lights, context={}, **BiquadraticOptions.check(options))
