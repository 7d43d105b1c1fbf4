"""The default method: the paper's relaxed biquadratic model (Eq. 2) per pixel, with psrig's
observation selection and a shared-shape prior.

A chunk runs in two phases. :meth:`Biquadratic.select` picks each pixel's observations
(:mod:`pipeline.photometric.selection`) and never waits; :meth:`Biquadratic.fit` alternates
the 9 shape parameters and a Gauss-Newton normal step (:mod:`pipeline.photometric.alternation`)
with each pixel pulled toward albedo x the object's shared shape, which
:meth:`Biquadratic.prepare` fits once per image on a pixel sample
(:mod:`pipeline.photometric.shared_shape`). When the object fails the single-material check on
the automatic narrow-cone path, every pixel falls back to the paper's darkest-fraction rule
without the prior. The rules and the measurements behind them: docs/photometric-stereo.md.
"""

import numpy as np

from .alternation import alternate_per_pixel, alternate_shared, half_vectors, to_paper_order
from .engine import known_context
from .methods import METHODS, MIN_OBS, STATUS, base_status, shading
from .selection import select_observations
from .shared_shape import fit_shared_shape, single_material_check

__all__ = ["Biquadratic", "biquadratic_method"]


class Biquadratic:
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
        base, weights, b = select_observations(obs, valid, lights, **options)
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
        switch = known_context(context).get("select")
        base, weights, b = select_observations(obs, valid, lights, **{**options, **(switch or {})})
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
            base, weights, b = select_observations(obs, valid, lights, **{**options, **context.get("select")})
        status, used = base_status(weights, base)
        h, y = half_vectors(lights)
        coeffs = np.zeros((len(obs), 3, 3))
        coeffs[:, 0, 0] = 1.0
        rss = np.sum(weights * (obs - shading(b, lights)) ** 2, axis=1)
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
            active = alternate_per_pixel(obs, weights, b, coeffs, rss, active, lights, h, y, prior, ridge, max_iter,
                                         tol)
        status[active] = STATUS["not_converged"]
        return {"b": b, "status": status, "used": used, "rss": rss, "params": to_paper_order(coeffs)}


METHODS.register("biquadratic", Biquadratic())


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
        lights' polar angles from sharp specular peaks, see :mod:`pipeline.photometric.anchor`.
    """
    return METHODS["biquadratic"](obs, valid, lights, context={}, **options)
