"""A session's fitted reflectance model, read back, evaluated under any light and exported.

- :mod:`.model`: :func:`read_model` (normals, albedo, Eq. 2's coefficients of ``normals/``) and
  :func:`shade`, the numpy reference of the report's relighting view;
- :mod:`.export`: ``psrig export SESSION --relight DIR`` (:func:`export_relight`).
"""

from .export import export_relight
from .model import MATERIAL, MODES, FittedModel, read_model, shade

__all__ = ["FittedModel", "read_model", "shade", "MODES", "MATERIAL", "export_relight"]
