"""The interface every reflectance model implements, and the model registry.

A model describes an isotropic BRDF rho as a function of the cosines between the normal n,
light l, view v and half vector h = (l + v) / |l + v|. Every call is batched: the leading
dimensions (typically N pixels or normals) and the observation axis K are carried through.

Image formation used throughout psrig: i = rho(geometry; params) * max(n . l, 0) (times the
light's intensity, divided out beforehand).
"""

from dataclasses import dataclass

import numpy as np

from ..core.registry import Registry

__all__ = ["Geometry", "ReflectanceModel", "LinearModel", "MODELS", "register_model", "get_model",
           "solve_batched"]

#: Reflectance models by name: one instance of each registered class
MODELS = Registry("reflectance model")


def register_model(cls):
    """Class decorator: instantiate ``cls`` and register it under ``cls.name``."""
    MODELS.register(cls.name, cls())
    return cls


def get_model(name):
    """The registered model called ``name`` (see :data:`MODELS`); the error lists the names."""
    return MODELS[name]


@dataclass
class Geometry:
    """Cosines of an observation set, each array broadcastable to (..., K).

    Attributes
    ----------
    nl, nv, nh : ndarray
        n . l, n . v and n . h.
    lh : ndarray
        l . h (= v . h), the cosine of the difference angle.
    lv : ndarray
        l . v.
    """

    nl: np.ndarray
    nv: np.ndarray
    nh: np.ndarray
    lh: np.ndarray
    lv: np.ndarray

    @classmethod
    def from_vectors(cls, normals, lights, view=(0.0, 0.0, 1.0)):
        """Cosines from unit vectors.

        Parameters
        ----------
        normals : ndarray (..., 3)
            Unit normals, camera frame.
        lights : ndarray (K, 3) or (..., K, 3)
            Unit light directions (shared, or per leading index).
        view : ndarray (3,) or (..., 3)
            Unit view direction; (0, 0, 1) for an orthographic camera.
        """
        n = np.asarray(normals, dtype=float)[..., None, :]
        lights = np.asarray(lights, dtype=float)
        v = np.asarray(view, dtype=float)
        v = v[..., None, :] if v.ndim > 1 else v
        half = lights + v
        half = half / np.maximum(np.linalg.norm(half, axis=-1, keepdims=True), 1e-12)
        return cls(
            nl=np.sum(n * lights, axis=-1),
            nv=np.sum(n * v, axis=-1),
            nh=np.sum(n * half, axis=-1),
            lh=np.sum(lights * half, axis=-1),
            lv=np.sum(lights * v, axis=-1),
        )


class ReflectanceModel:
    """Base of all reflectance models.

    Subclasses set ``name`` (registry key), ``n_params``, ``description`` and implement
    :meth:`evaluate` and :meth:`fit`.
    """

    name = ""
    n_params = 0
    description = ""
    linear = False

    def evaluate(self, params, geometry):
        """BRDF values rho (..., K) for params (..., P)."""
        raise NotImplementedError

    def fit(self, geometry, values, shading=None, weights=None):
        """Least-squares parameters (..., P) so that ``shading * rho`` matches ``values``.

        Parameters
        ----------
        geometry : Geometry
            Cosines, each (..., K).
        values : ndarray (..., K)
            Observations: image intensities, or BRDF values when ``shading`` is None.
        shading : ndarray (..., K), optional
            Factor multiplying the model (n . l in photometric stereo); 1 when None.
        weights : ndarray (..., K), optional
            Non-negative weights; 0 drops an observation (shadows, speculars).
        """
        raise NotImplementedError

    def __repr__(self):
        return f"<reflectance model {self.name!r}: {self.description}>"


class LinearModel(ReflectanceModel):
    """A model linear in its parameters: rho = basis(geometry) @ params."""

    linear = True
    ridge = 1e-9

    def basis(self, geometry):
        """Basis functions (..., K, P)."""
        raise NotImplementedError

    def evaluate(self, params, geometry):
        return np.einsum("...kp,...p->...k", self.basis(geometry), params)

    def fit(self, geometry, values, shading=None, weights=None):
        design = self.basis(geometry)
        if shading is not None:
            design = design * np.asarray(shading)[..., None]
        return solve_batched(design, values, weights, ridge=self.ridge)


def solve_batched(design, values, weights=None, ridge=1e-9):
    """Weighted least squares for a batch of small systems.

    Parameters
    ----------
    design : ndarray (..., K, P)
    values : ndarray (..., K)
    weights : ndarray (..., K), optional
    ridge : float
        Tikhonov term, relative to the mean diagonal of the normal matrix, so that systems with
        fewer usable observations than parameters still return finite (minimum-norm-like)
        solutions instead of failing.

    Returns
    -------
    ndarray (..., P)
    """
    values = np.asarray(values, dtype=float)
    weighted = design if weights is None else design * np.asarray(weights)[..., None]
    normal = np.swapaxes(weighted, -1, -2) @ design
    rhs = np.einsum("...kp,...k->...p", weighted, values)
    scale = np.trace(normal, axis1=-2, axis2=-1)[..., None, None] / design.shape[-1]
    normal = normal + (ridge * scale + 1e-30) * np.eye(design.shape[-1])
    return np.linalg.solve(normal, rhs[..., None])[..., 0]
