"""Photometric-stereo methods by name: the registry, the status codes, and the simple methods.

A method solves one chunk of pixels: ``method(obs (N, K), valid (N, K) or None, lights (K, 3)
or (N, K, 3), context=None, **options)`` returns a dict of ``b`` (N, 3) albedo-scaled normals
(camera frame), ``status`` (N,) codes of :data:`STATUS`, ``used`` (N,) observation counts,
``rss`` (N,) residual sums of squares and ``params`` (N, P) reflectance parameters. A method
may split that into ``select`` (which never waits for a shared context) and ``fit`` phases
and fit a shared ``prepare``-d context once per image (the biquadratic method does,
:mod:`pipeline.photometric.biquadratic`); the chunk engine (:mod:`pipeline.photometric.engine`)
runs either kind.

A method says what it is with attributes rather than by its name (:func:`method_traits`):
``options``, the :class:`pipeline.core.options.Options` it takes (default
:class:`pipeline.settings.SelectionOptions`; :func:`pipeline.photometric.estimate_normals`
refuses any other name); ``renders_rho``, whether its ``params`` are the biquadratic
coefficients that render rho (the registration check renders frames from them; default
False: rho = 1); ``wants_anchor``, whether ``specular_anchor='auto'`` corrects its lights on
specular peaks under a narrow light cone (default False).

Registered here: ``lambert`` (every valid observation), ``lambert-low`` (the selected ones)
and, for every reflectance model of :mod:`pipeline.reflectance` that is not a method of its
own, the paper's alternation with that model (fix n, fit the model; fix rho, solve n). An
installed distribution adds methods under the entry-point group ``psrig.methods``.
"""

from typing import NamedTuple

import numpy as np

from ..core.errors import InputError

from ..core.registry import Registry
from ..settings.normals import AlternationOptions, EstimateOptions, SelectionOptions
from ..reflectance import MODELS, Geometry, get_model
from .model import unit
from .lambert import ILL_CONDITIONED, facing_away, ill_conditioned, lambert_weighted
from .selection import select_observations

__all__ = ["METHODS", "get_method", "STATUS", "STATUS_NAMES", "STATUS_PALETTE", "MIN_OBS", "ILL_CONDITIONED",
           "base_status", "ill_conditioned", "facing_away", "no_normal", "shading",
           "lambert_method", "lambert_low_method", "ModelAlternation", "register_model_methods", "share_text",
           "method_traits", "MethodTraits", "check_method_options"]

STATUS = {"background": 0, "ok": 1, "shadowed": 2, "too_few": 3, "not_converged": 4, "lambert_fallback": 5,
          "shared_shape": 6, "ill_posed": 7, "uncertain": 8}
STATUS_NAMES = {code: name for name, code in STATUS.items()}
#: The one colour (RGB) of each status, by name: normals/status_vis.png and the report's map and
#: legend both use it; a status without a colour here is drawn in mid grey.
STATUS_PALETTE = {"background": (0, 0, 0), "ok": (60, 170, 60), "shadowed": (40, 40, 160),
                  "too_few": (200, 160, 0), "not_converged": (220, 40, 40), "lambert_fallback": (150, 80, 200),
                  "shared_shape": (0, 160, 170), "ill_posed": (240, 120, 0), "uncertain": (230, 80, 170)}
MIN_OBS = 3

#: Photometric-stereo methods by name (``psrig normals --method NAME``; plugins under the
#: entry-point group ``psrig.methods``)
METHODS = Registry("photometric stereo method", entry_points="psrig.methods")


class MethodTraits(NamedTuple):
    """What a method says of itself (see the module docstring)."""

    options: type
    renders_rho: bool
    wants_anchor: bool


def get_method(name):
    """The method called ``name``; the error lists every method (:data:`METHODS`)."""
    return METHODS[name]


def method_traits(method):
    """The :class:`MethodTraits` of a method (a registered object), with the defaults for
    what it does not say."""
    return MethodTraits(getattr(method, "options", SelectionOptions), bool(getattr(method, "renders_rho", False)),
                        bool(getattr(method, "wants_anchor", False)))


def check_method_options(name, options):
    """``options`` for :func:`pipeline.photometric.estimate_normals` with method ``name``,
    checked against the method's declaration and :class:`pipeline.settings.EstimateOptions`;
    InputError names an unknown option and lists the known ones."""
    declared = method_traits(get_method(name)).options
    known = {**declared.specs(), **EstimateOptions.specs()}
    unknown = sorted(set(options) - set(known))
    if unknown:
        raise InputError(f"unknown option {unknown[0]!r} for the {name} method; known: {', '.join(sorted(known))}")
    declared.check({k: v for k, v in options.items() if k in declared.specs()}, where=name)
    EstimateOptions.check({k: v for k, v in options.items() if k not in declared.specs()}, where=name)
    return dict(options)


def share_text(count, total):
    """A share of pixels as a person reads it: '0.0%' only when there are none ('<0.1%' for a
    few), so a status that is present never reads as absent."""
    if count and count / max(total, 1) < 0.0005:
        return "<0.1%"
    return f"{count / max(total, 1):.1%}"


def base_status(weights, base, lights=None):
    """Status codes (N,) and observation counts (N,) from selected and non-shadowed weights.

    With ``lights`` (K, 3) or (N, K, 3), pixels whose selected lights are too close to coplanar
    to determine a normal (:func:`ill_conditioned`) are ``ill_posed``.
    """
    used = weights.sum(axis=1)
    status = np.full(len(weights), STATUS["ok"], np.uint8)
    if lights is not None:
        status[(used >= MIN_OBS) & ill_conditioned(weights, lights)] = STATUS["ill_posed"]
    status[used < MIN_OBS] = STATUS["too_few"]
    status[base.sum(axis=1) == 0] = STATUS["shadowed"]
    return status, used


def no_normal(status, b):
    """``status`` with the pixels whose b faces away from the camera marked ``ill_posed``
    (their normals are then not reported: never a normal facing away)."""
    solved = (status != STATUS["too_few"]) & (status != STATUS["shadowed"])
    return np.where(solved & facing_away(b), np.uint8(STATUS["ill_posed"]), status).astype(np.uint8)


def shading(b, lights):
    """Lambertian shading b . l (N, K) for lights (K, 3) or (N, K, 3)."""
    return b @ lights.T if lights.ndim == 2 else np.einsum("ni,nki->nk", b, lights)


@METHODS.register("lambert")
def lambert_method(obs, valid, lights, context=None, **_):
    """Lambertian least squares on every valid observation."""
    weights = np.ones_like(obs) if valid is None else valid.astype(obs.dtype)
    b = lambert_weighted(obs, lights, weights)
    status, used = base_status(weights, weights, lights)
    rss = np.sum(weights * (obs - shading(b, lights)) ** 2, axis=1)
    return {"b": b, "status": no_normal(status, b), "used": used, "lit": used, "rss": rss,
            "params": np.linalg.norm(b, axis=1)[:, None]}


@METHODS.register("lambert-low")
def lambert_low_method(obs, valid, lights, context=None, **options):
    """Lambertian least squares on the selected (low-frequency) observations."""
    base, weights, b = select_observations(obs, valid, lights, **options)
    status, used = base_status(weights, base, lights)
    rss = np.sum(weights * (obs - shading(b, lights)) ** 2, axis=1)
    return {"b": b, "status": no_normal(status, b), "used": used, "lit": base.sum(axis=1), "rss": rss,
            "params": np.linalg.norm(b, axis=1)[:, None]}


class ModelAlternation:
    """The paper's alternation with a reflectance model of :mod:`pipeline.reflectance`.

    Fix n and fit the model's parameters; fix rho and solve n linearly; stop when every
    pixel's residual changes by at most ``tol`` x its weighted sum of squares, or after
    ``max_iter`` rounds. The model is looked up when the method first runs.
    """

    options = AlternationOptions

    def __init__(self, model_name):
        self.model_name = model_name

    def __call__(self, obs, valid, lights, context=None, max_iter=20, tol=1e-7, **options):
        model = get_model(self.model_name)
        base, weights, b = select_observations(obs, valid, lights, **options)
        status, used = base_status(weights, base, lights)
        n = unit(b)
        params = None
        rss = np.zeros(len(obs))
        prev = None
        for _ in range(max_iter):
            geom = Geometry.from_vectors(n, lights)
            params = model.fit(geom, obs, shading=np.maximum(geom.nl, 0.0), weights=weights)
            rho = model.evaluate(params, geom)
            b = lambert_weighted(obs, lights, weights, factor=rho)
            n = unit(b)
            geom = Geometry.from_vectors(n, lights)
            rss = np.sum(weights * (obs - model.evaluate(params, geom) * np.maximum(geom.nl, 0)) ** 2, axis=1)
            if prev is not None and np.all(np.abs(prev - rss) <= tol * (np.sum(weights * obs**2, axis=1) + 1e-300)):
                break
            prev = rss
        # b's scale is arbitrary here (rho carries the albedo); report |b| as 1 x mean rho.
        albedo = np.nanmean(np.where(weights > 0, model.evaluate(params, Geometry.from_vectors(n, lights)), np.nan),
                            axis=1)
        b = n * np.nan_to_num(albedo, nan=1.0)[:, None]
        return {"b": b, "status": no_normal(status, b), "used": used, "lit": base.sum(axis=1), "rss": rss,
                "params": np.asarray(params).reshape(len(obs), -1)}


def register_model_methods():
    """Register :class:`ModelAlternation` for every reflectance model that names no method yet."""
    for name in MODELS:
        if name not in METHODS:
            METHODS.register(name, ModelAlternation(name))
