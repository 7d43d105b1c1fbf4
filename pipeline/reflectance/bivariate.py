"""The bivariate table model rho(theta_h, theta_d) the paper compares with in Fig. 5.

Romeiro et al.'s passive reflectometry (the paper's [27]) represents an isotropic BRDF as a
discrete table over the half angle theta_h (between n and h) and the difference angle theta_d
(between l and h). The paper builds it "by taking one slice of the 3-D discrete BRDF table
rho(theta_h, theta_d, phi_d) and averaging over phi_d": :meth:`BivariateTable.from_material`
does that from a material's BRDF (an analytic model or a MERL file): it evaluates the BRDF at
:data:`PHI_D` difference azimuths per cell, over the cells' centres, keeps the geometries above
both horizons (n . l > 0 and n . v > 0) and averages. Cells with none are filled from the
nearest cell that has some. The table is indexed like MERL's: theta_h on a square-root scale
(cells denser near the specular peak), theta_d uniform; looked up by bilinear interpolation.

It is not fitted to an image: it is the best a bivariate table can hold of the material, with
``bins_h x bins_d`` parameters per colour channel (8100 by default) against the biquadratic's 9.
"""

import numpy as np
from scipy import ndimage

from ..core.errors import InputError
from .base import Geometry

__all__ = ["BivariateTable", "BINS_H", "BINS_D", "PHI_D"]

BINS_H = 90
BINS_D = 90
#: difference azimuths averaged per cell (over 0 .. 2 pi)
PHI_D = 72


def _half_diff_geometry(theta_h, theta_d, phi_d):
    """Geometry (and the above-horizon flag) of half/difference angles (Rusinkiewicz), any
    broadcastable shapes: n = z, h in the x-z plane at theta_h, l and v the difference vector
    and its mirror about h rotated with it."""
    st, ct = np.sin(theta_d), np.cos(theta_d)
    dx, dy = st * np.cos(phi_d), st * np.sin(phi_d)
    sh, ch = np.sin(theta_h), np.cos(theta_h)
    nl = -dx * sh + ct * ch          # z of R_y(theta_h) d
    nv = dx * sh + ct * ch           # z of R_y(theta_h) (-dx, -dy, ct)
    shape = np.broadcast_shapes(np.shape(nl), np.shape(dy))
    geometry = Geometry(nl=np.broadcast_to(nl, shape), nv=np.broadcast_to(nv, shape),
                        nh=np.broadcast_to(ch, shape), lh=np.broadcast_to(ct, shape),
                        lv=np.broadcast_to(np.cos(2 * theta_d), shape))
    return geometry, (geometry.nl > 0) & (geometry.nv > 0)


class BivariateTable:
    """rho(theta_h, theta_d): a (bins_h, bins_d, C) table and its lookup.

    Parameters
    ----------
    table : ndarray (bins_h, bins_d, C)
        BRDF values at the cells' centres: theta_h = (u^2) pi / 2 with u = (i + 0.5) / bins_h,
        theta_d = (j + 0.5) / bins_d x pi / 2.
    """

    name = "bivariate"
    description = "bivariate table rho(theta_h, theta_d), phi_d averaged (Romeiro et al., paper Fig. 5)"

    def __init__(self, table):
        table = np.asarray(table, float)
        if table.ndim == 2:
            table = table[..., None]
        if table.ndim != 3 or not np.isfinite(table).all():
            raise InputError(f"bivariate table: expected finite (bins_h, bins_d, C), got shape {table.shape}")
        self.table = table

    @property
    def n_params(self):
        """Table cells per colour channel."""
        return int(self.table.shape[0] * self.table.shape[1])

    @staticmethod
    def centres(bins_h=BINS_H, bins_d=BINS_D):
        """theta_h (bins_h,) and theta_d (bins_d,) of the cells' centres, radians."""
        u = (np.arange(bins_h) + 0.5) / bins_h
        return u * u * np.pi / 2, (np.arange(bins_d) + 0.5) / bins_d * np.pi / 2

    @classmethod
    def from_material(cls, material, bins_h=BINS_H, bins_d=BINS_D, phi_d=PHI_D):
        """The table of ``material`` (a function Geometry (...) -> BRDF (..., C)), phi_d averaged."""
        theta_h, theta_d = cls.centres(bins_h, bins_d)
        phi = (np.arange(phi_d) + 0.5) / phi_d * 2 * np.pi
        geometry, above = _half_diff_geometry(theta_h[:, None, None], theta_d[None, :, None], phi[None, None, :])
        values = np.asarray(material(geometry), float)                  # (bins_h, bins_d, phi_d, C)
        if values.ndim == 3:
            values = values[..., None]
        keep = above[..., None] & np.isfinite(values)
        counts = keep.sum(axis=2)
        table = np.where(counts > 0, np.where(keep, values, 0.0).sum(axis=2) / np.maximum(counts, 1), np.nan)
        empty = counts == 0
        if empty.all():
            raise InputError("bivariate table: the material has no value above the horizon")
        for c in range(table.shape[2]):
            if empty[..., c].any():
                nearest = ndimage.distance_transform_edt(empty[..., c], return_distances=False, return_indices=True)
                table[..., c] = table[..., c][tuple(nearest)]
        return cls(table)

    def evaluate(self, geometry):
        """BRDF values (..., C) at ``geometry`` (its nh and lh), by bilinear interpolation."""
        bins_h, bins_d = self.table.shape[:2]
        theta_h = np.arccos(np.clip(np.asarray(geometry.nh, float), -1, 1))
        theta_d = np.arccos(np.clip(np.asarray(geometry.lh, float), -1, 1))
        theta_h, theta_d = np.broadcast_arrays(theta_h, theta_d)
        i = np.sqrt(np.clip(theta_h / (np.pi / 2), 0, 1)) * bins_h - 0.5
        j = np.clip(theta_d / (np.pi / 2), 0, 1) * bins_d - 0.5
        i = np.clip(i, 0, bins_h - 1)
        j = np.clip(j, 0, bins_d - 1)
        i0, j0 = np.minimum(np.floor(i).astype(int), bins_h - 2), np.minimum(np.floor(j).astype(int), bins_d - 2)
        fi, fj = (i - i0)[..., None], (j - j0)[..., None]
        t = self.table
        return ((1 - fi) * (1 - fj) * t[i0, j0] + fi * (1 - fj) * t[i0 + 1, j0]
                + (1 - fi) * fj * t[i0, j0 + 1] + fi * fj * t[i0 + 1, j0 + 1])
