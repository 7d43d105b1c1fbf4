"""Reflectance models, registered by name, with one interface (see :mod:`.base`).

>>> from pipeline.reflectance import get_model, Geometry
>>> model = get_model("biquadratic")
"""

from .base import MODELS, Geometry, LinearModel, ReflectanceModel, get_model, register_model, solve_batched
from . import polynomial  # noqa: F401  (registers lambert, bilinear, biquadratic, bicubic)
from . import ashikhmin, cook_torrance, factorised, lafortune, ward  # noqa: F401  (register the rest)

__all__ = ["MODELS", "Geometry", "LinearModel", "ReflectanceModel", "get_model", "register_model",
           "solve_batched"]
