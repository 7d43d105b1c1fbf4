"""The fitted reflectance model of a session, read back and evaluated under any light.

The normals stage writes, per pixel, a unit normal (``normals/normals.exr``), an albedo
(``normals/albedo.exr``, RGB or grey, linear, light intensities divided out) and the relaxed
biquadratic's nine coefficients A..I of the paper's Eq. 2 relative to the albedo
(``normals/brdf.exr``, channels :data:`pipeline.photometric.stage.PAPER_NAMES`). The image of
the object under a distant light l (unit, camera frame: x right, y up, z toward the camera;
view v = (0, 0, 1)) is, per colour channel c::

    h = (l + v) / |l + v|,  x = n . h,  y = l . h
    rho = A x^2 y^2 + B x^2 y + C x^2 + D x y^2 + E x y + F x + G y^2 + H y + I
    I_c = albedo_c * rho * max(n . l, 0)

(rho = 1 for a session fitted with another method than the biquadratic: Lambert). The report's
relighting view (:mod:`pipeline.report.relight_view`) and ``psrig export --relight``
(:mod:`pipeline.relight.export`) use this; :func:`shade` is the reference both are tested against.
"""

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..imageio import read_image, read_mask
from ..paths import ALBEDO, NORMALS, NORMALS_MASK

__all__ = ["FittedModel", "read_model", "shade", "MODES", "MATERIAL", "BRDF"]

BRDF = "normals/brdf.exr"
#: what :func:`shade` draws: the fitted model, its diffuse part (albedo x n . l), the normals
#: under a fixed material (:data:`MATERIAL`)
MODES = ("model", "diffuse", "normals")
#: the fixed material of mode 'normals': grey diffuse plus a Blinn-Phong lobe, so that the
#: shape shows apart from the albedo (as the RTI viewers' specular enhancement does)
MATERIAL = {"diffuse": 0.7, "specular": 0.3, "exponent": 40.0}


@dataclass
class FittedModel:
    """A session's fitted model (full resolution, or a grid of it).

    Attributes
    ----------
    normals : ndarray (H, W, 3) float32
        Unit normals, camera frame; zero outside ``mask``.
    mask : ndarray (H, W) bool
        Pixels with a fitted normal.
    coefficients : ndarray (H, W, 9) float32
        A..I of Eq. 2 relative to the albedo (Lambert: 0 except I = 1).
    albedo : ndarray (H, W, 3) float32
        Linear RGB albedo (grey repeated), light intensities divided out.
    method : str
        The normals stage's method; ``biquadratic`` says that the coefficients are fitted.
    """

    normals: np.ndarray
    mask: np.ndarray
    coefficients: np.ndarray
    albedo: np.ndarray
    method: str

    @property
    def shape(self):
        return self.mask.shape

    def grid(self, step):
        """Every ``step``-th pixel (rows and columns): the model at those pixels, unchanged
        (sampled, not averaged: the view shows exactly the fitted values)."""
        pick = (slice(None, None, step), slice(None, None, step))
        return FittedModel(self.normals[pick], self.mask[pick], self.coefficients[pick], self.albedo[pick],
                           self.method)


def read_model(session):
    """The session's :class:`FittedModel`; InputError naming the file when one is missing or
    does not match the others."""
    for rel in (NORMALS, ALBEDO, NORMALS_MASK):
        if not session.path(rel).is_file():
            raise InputError(f"{session.path(rel)}: missing (run `psrig normals` first)")
    normals = read_image(session.path(NORMALS))[:, :, :3].astype(np.float32)
    shape = normals.shape[:2]
    mask = read_mask(session.path(NORMALS_MASK)) & (np.linalg.norm(normals, axis=2) > 0.5)
    albedo = read_image(session.path(ALBEDO)).astype(np.float32)
    albedo = np.repeat(albedo[:, :, :1], 3, axis=2) if albedo.shape[2] < 3 else albedo[:, :, :3]
    method = ((session.stage("normals") or {}).get("params") or {}).get("method", "biquadratic")
    coefficients = np.zeros(shape + (9,), np.float32)
    coefficients[:, :, 8] = 1.0
    brdf = session.path(BRDF)
    if method == "biquadratic":
        if not brdf.is_file():
            raise InputError(f"{brdf}: missing (run `psrig normals` first)")
        coefficients = read_image(brdf).astype(np.float32)
        if coefficients.shape[2] != 9:
            raise InputError(f"{brdf}: {coefficients.shape[2]} channels, the biquadratic has 9 (A..I)")
    for name, array in (("albedo", albedo), ("brdf", coefficients)):
        if array.shape[:2] != shape:
            raise InputError(f"normals/{name}.exr: size {array.shape[:2]} differs from normals.exr's {shape}")
    mask &= np.isfinite(coefficients).all(axis=2) & np.isfinite(albedo).all(axis=2)
    zero = ~mask
    normals[zero], albedo[zero], coefficients[zero] = 0.0, 0.0, 0.0
    return FittedModel(normals, mask, coefficients, albedo, method)


def shade(normals, coefficients, albedo, light, mode="model"):
    """Linear RGB (N, 3) of pixels under the distant ``light`` (3,), by :data:`MODES` ``mode``.

    Parameters
    ----------
    normals : ndarray (N, 3)
        Unit normals, camera frame.
    coefficients : ndarray (N, 9)
        A..I of Eq. 2 (paper order), relative to the albedo.
    albedo : ndarray (N, 3)
        Linear RGB albedo.
    light : sequence of 3 floats
        Direction toward the light (normalised here), camera frame.
    mode : str
        'model' albedo x rho x max(n . l, 0); 'diffuse' albedo x max(n . l, 0); 'normals' the
        fixed :data:`MATERIAL` (grey, no albedo).

    Returns
    -------
    ndarray (N, 3) float64
        In the albedo's units (light intensity 1).
    """
    if mode not in MODES:
        raise InputError(f"shade: unknown mode {mode!r}; known: {', '.join(MODES)}")
    n = np.asarray(normals, np.float64)
    light = np.asarray(light, np.float64)
    light = light / np.linalg.norm(light)
    h = light + np.array([0.0, 0.0, 1.0])
    h = h / max(np.linalg.norm(h), 1e-12)
    s = np.maximum(n @ light, 0.0)
    if mode == "normals":
        x = np.maximum(n @ h, 0.0)
        grey = MATERIAL["diffuse"] * s + np.where(s > 0, MATERIAL["specular"] * x ** MATERIAL["exponent"], 0.0)
        return np.repeat(grey[:, None], 3, axis=1)
    value = s
    if mode == "model":
        x, y = n @ h, float(light @ h)
        c = np.asarray(coefficients, np.float64)
        ypow = np.array([y * y, y, 1.0])
        # paper order: A..C multiply x^2 (y^2, y, 1), D..F x, G..I 1
        rho = (c[:, 0:3] @ ypow) * x * x + (c[:, 3:6] @ ypow) * x + c[:, 6:9] @ ypow
        value = s * rho
    return np.asarray(albedo, np.float64) * value[:, None]
