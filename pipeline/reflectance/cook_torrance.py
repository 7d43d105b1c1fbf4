"""Lambertian + microfacet specular models (paper Eq. 7) and the Cook-Torrance lobe (Eq. 3, 4).

rho = k_d / pi + k_s S(n, l, v; m). Both Cook-Torrance and Ward (:mod:`.ward`) share the batched
fit of :class:`LambertSpecular`: for a fixed roughness m the model is linear in (k_d, k_s), so the
fit profiles (k_d, k_s) out (non-negative 2x2 least squares in closed form), scans m on a log grid
and refines it by golden-section search around the best grid point. All of it is vectorised over
the batch, so a whole image (100k pixels x 30 lights) is fitted in a few seconds, and it is
global in m, which a local Levenberg-Marquardt from a Lambertian start is not.
"""

import numpy as np

from ..core.golden import golden_section
from .base import Geometry, ReflectanceModel, register_model

__all__ = ["LambertSpecular", "CookTorrance", "ROUGHNESS_RANGE"]

#: Bounds of the roughness parameter m.
ROUGHNESS_RANGE = (0.01, 1.0)
#: Cosines in denominators are clipped here so that grazing geometry stays finite.
_COS_MIN = 1e-3


class LambertSpecular(ReflectanceModel):
    """rho = k_d / pi + k_s S(geometry; m); params (..., 3) = (k_d, k_s, m).

    Subclasses implement :meth:`lobe`. ``grid_size`` roughness values are scanned and
    ``refine_steps`` golden-section steps refine the best one.
    """

    n_params = 3
    grid_size = 12
    refine_steps = 16

    def parts(self, geometry):
        """m-independent factors of the lobe: S = factor exp(-tan2 / m^2) / m^2, each (..., K)."""
        raise NotImplementedError

    def lobe(self, geometry, m):
        """Specular term S (..., K) for roughness m (broadcastable to (..., 1))."""
        factor, tan2 = self.parts(geometry)
        m2 = np.asarray(m, float) ** 2
        return factor * np.exp(-tan2 / m2) / m2

    def evaluate(self, params, geometry):
        params = np.asarray(params, float)
        m = np.clip(params[..., 2:3], *ROUGHNESS_RANGE)
        return params[..., 0:1] / np.pi + params[..., 1:2] * self.lobe(geometry, m)

    def fit(self, geometry, values, shading=None, weights=None):
        values = np.asarray(values, float)
        shading = np.ones_like(values) if shading is None else np.broadcast_to(shading, values.shape)
        w = np.ones_like(values) if weights is None else np.broadcast_to(weights, values.shape)
        w = np.where(np.isfinite(values), w, 0.0)
        values = np.nan_to_num(values)
        geometry, values, shading, w = _compact(geometry, values, shading, w)
        diffuse = shading / np.pi
        sums = (np.sum(w * diffuse * diffuse, -1), np.sum(w * diffuse * values, -1))
        factor, tan2 = self.parts(geometry)
        factor = shading * factor
        batch = values.shape[:-1]

        def profile(m):
            m2 = (m * m)[..., None]
            return _nonneg_pair(sums, diffuse, factor * np.exp(-tan2 / m2) / m2, values, w)

        grid = np.geomspace(0.02, ROUGHNESS_RANGE[1], self.grid_size)
        scores = np.stack([profile(np.full(batch, m))[2] for m in grid], axis=-1)
        best = np.argmin(scores, axis=-1)
        lo = np.log(grid[np.maximum(best - 1, 0)])
        hi = np.log(np.where(best + 1 < grid.size, grid[np.minimum(best + 1, grid.size - 1)],
                             ROUGHNESS_RANGE[1]))
        lo = np.where(best == 0, np.log(ROUGHNESS_RANGE[0]), lo)
        m = np.exp(golden_section(lambda t: profile(np.exp(t))[2], lo, hi, self.refine_steps))
        kd, ks, _ = profile(m)
        return np.stack([kd, ks, m], axis=-1)


def _compact(geometry, values, shading, w):
    """Drop the zero-weight observations of every row (padding rows to the longest).

    The fit evaluates the lobe some 30 times; when weights keep a quarter of the observations
    (T_low = 25 %), working on those alone is about 4 times faster.
    """
    keep = w != 0
    count = int(keep.sum(-1).max()) if keep.size else 0
    if values.ndim == 0 or count > 0.75 * values.shape[-1]:
        return geometry, values, shading, w
    order = np.argsort(~keep, axis=-1, kind="stable")[..., :max(count, 1)]
    take = lambda a: np.take_along_axis(np.broadcast_to(a, values.shape), order, -1)  # noqa: E731
    cosines = {k: take(getattr(geometry, k)) for k in ("nl", "nv", "nh", "lh", "lv")}
    return Geometry(**cosines), take(values), take(shading), take(w)


def _nonneg_pair(sums, a, b, v, w):
    """Non-negative least squares of v ~ kd a + ks b per batch item, closed form.

    A tiny penalty on ks^2 makes a lobe that never shows (no highlight among the samples)
    come out as ks = 0 instead of any ks with ks * S ~ 0 (e.g. 1e150 * 1e-300).

    Returns (kd, ks, weighted residual + penalty), each of the batch shape.
    """
    aa, av = sums
    ab, bv = np.sum(w * a * b, -1), np.sum(w * b * v, -1)
    bb = np.sum(w * b * b, -1) + 1e-10 * aa
    vv = np.sum(w * v * v, -1)
    det = aa * bb - ab * ab
    safe = np.abs(det) > 1e-12 * np.maximum(aa * bb, 1e-300)
    det = np.where(safe, det, 1.0)
    kd = np.where(safe, (bb * av - ab * bv) / det, -1.0)
    ks = np.where(safe, (aa * bv - ab * av) / det, -1.0)
    both = (kd >= 0) & (ks >= 0)
    # One of the two clipped to zero: keep whichever single-term fit leaves less residual.
    kd_only = np.where(aa > 1e-30, np.maximum(av, 0) / np.maximum(aa, 1e-30), 0.0)
    ks_only = np.where(bb > 1e-30, np.maximum(bv, 0) / np.maximum(bb, 1e-30), 0.0)
    res_d = vv - kd_only * (2 * av - kd_only * aa)
    res_s = vv - ks_only * (2 * bv - ks_only * bb)
    use_d = res_d <= res_s
    kd = np.where(both, kd, np.where(use_d, kd_only, 0.0))
    ks = np.where(both, ks, np.where(use_d, 0.0, ks_only))
    with np.errstate(over="ignore", invalid="ignore"):
        res = vv - 2 * (kd * av + ks * bv) + kd * kd * aa + 2 * kd * ks * ab + ks * ks * bb
    return kd, ks, np.where(np.isfinite(res), res, np.inf)


@register_model
class CookTorrance(LambertSpecular):
    """Cook-Torrance: S = D F G / (pi (n.l)(n.v)) with the paper's D (Eq. 3), Schlick F (Eq. 4).

    F is normalised by its value at normal incidence (F / rho_s, rho_s = ``fresnel0``) so that
    k_s alone sets the specular strength; G is the V-cavity masking-shadowing term.
    """

    name = "cook-torrance"
    description = "Lambertian + Cook-Torrance specular, paper Eq. 3, 4, 7 (k_d, k_s, m)"
    fresnel0 = 0.04

    def parts(self, geometry):
        nh = np.clip(np.asarray(geometry.nh, float), _COS_MIN, 1.0)
        nl = np.clip(np.asarray(geometry.nl, float), _COS_MIN, 1.0)
        nv = np.clip(np.asarray(geometry.nv, float), _COS_MIN, 1.0)
        lh = np.clip(np.asarray(geometry.lh, float), _COS_MIN, 1.0)
        nh2 = nh * nh
        f = 1.0 + (1.0 / self.fresnel0 - 1.0) * (1.0 - lh) ** 5
        g = np.minimum(1.0, 2.0 * nh * np.minimum(nv, nl) / lh)
        # D (Eq. 3) = exp(-tan^2 / m^2) / (4 m^2 (n.h)^4), since 1 - 1/(n.h)^2 = -tan^2.
        return f * g / (4.0 * np.pi * nl * nv * nh2 * nh2), (1.0 - nh2) / nh2
