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

The normals stage's other methods in this family are converted: ``biquadratic-factorised`` (Eq. 1,
rho = (A1 x^2 + B1 x + C1)(A2 y^2 + B2 y + C2), the outer product of its two triples) and
``bilinear`` (x y, x, y, 1); their coefficients are absolute (the paper's alternation carries the
albedo in rho), so they are divided by the grey albedo. Any other method is drawn Lambertian
(rho = 1), and :attr:`FittedModel.family` says so. The report's
relighting view (:mod:`pipeline.report.relight_view`) and ``psrig export --relight``
(:mod:`pipeline.relight.export`) use this; :func:`shade` is the reference both are tested against.
"""

from dataclasses import dataclass

import numpy as np

from ..core.errors import InputError
from ..core.imageio import read_image, read_mask
from ..core.paths import ALBEDO, NORMALS, NORMALS_MASK

__all__ = ["FittedModel", "read_model", "shade", "MODES", "MATERIAL", "BRDF", "CONVERTED"]

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
        The normals stage's method.
    family : str
        'biquadratic' when the coefficients hold the method's fit (:data:`CONVERTED`), else
        'lambert' (A..H = 0, I = 1).
    """

    normals: np.ndarray
    mask: np.ndarray
    coefficients: np.ndarray
    albedo: np.ndarray
    method: str
    family: str = "biquadratic"

    @property
    def shape(self):
        return self.mask.shape

    def grid(self, step):
        """Every ``step``-th pixel (rows and columns): the model at those pixels, unchanged
        (sampled, not averaged: the view shows exactly the fitted values)."""
        pick = (slice(None, None, step), slice(None, None, step))
        return FittedModel(self.normals[pick], self.mask[pick], self.coefficients[pick], self.albedo[pick],
                           self.method, self.family)


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
    family = "lambert"
    if method in CONVERTED:
        if not brdf.is_file():
            raise InputError(f"{brdf}: missing (run `psrig normals` first)")
        params = read_image(brdf).astype(np.float64)
        if params.shape[2] != CONVERTED[method]:
            raise InputError(f"{brdf}: {params.shape[2]} channels, the {method} model has {CONVERTED[method]}")
        coefficients, family = _relaxed(method, params, albedo), "biquadratic"
    for name, array in (("albedo", albedo), ("brdf", coefficients)):
        if array.shape[:2] != shape:
            raise InputError(f"normals/{name}.exr: size {array.shape[:2]} differs from normals.exr's {shape}")
    mask &= np.isfinite(coefficients).all(axis=2) & np.isfinite(albedo).all(axis=2)
    zero = ~mask
    normals[zero], albedo[zero], coefficients[zero] = 0.0, 0.0, 0.0
    return FittedModel(normals, mask, coefficients, albedo, method, family)


#: the normals stage's methods whose fits are biquadratics, with their parameter counts
CONVERTED = {"biquadratic": 9, "biquadratic-factorised": 6, "bilinear": 4}


def _relaxed(method, params, albedo):
    """Eq. 2's nine coefficients (H, W, 9), relative to the albedo, of a fit of ``method``."""
    if method == "biquadratic":
        return params.astype(np.float32)
    relaxed = np.zeros(params.shape[:2] + (9,))
    if method == "biquadratic-factorised":
        # (A1, B1, C1) of x^2, x, 1 times (A2, B2, C2) of y^2, y, 1: row-major is the paper's A..I
        relaxed = (params[..., :3, None] * params[..., None, 3:]).reshape(params.shape[:2] + (9,))
    else:  # bilinear: x y, x, y, 1 -> E, F, H, I
        relaxed[..., [4, 5, 7, 8]] = params
    grey = albedo.mean(axis=2, dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(grey[..., None] > 0, relaxed / grey[..., None], 0.0).astype(np.float32)


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
