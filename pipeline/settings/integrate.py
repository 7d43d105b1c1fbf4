"""Options of the ``integrate`` stage (:mod:`pipeline.integrate`).

The stage record keeps them as ``method``, ``K`` and ``options`` (the method's and the mesh's
settings); ``psrig run`` spells the method ``--integrate-method``.
"""

from dataclasses import dataclass

from ..core.memory import DEFAULT_SHARE
from ..core.options import Options, option

__all__ = ["IntegrateOptions", "MAX_SLOPE_DEG", "INTEGRATION_METHODS"]

#: no mesh face across a depth step steeper than this (and than the normals say), degrees
MAX_SLOPE_DEG = 80.0
#: the integration methods psrig ships (:data:`pipeline.integrate.METHODS` may hold more)
INTEGRATION_METHODS = ("smooth", "bilateral")


@dataclass(frozen=True)
class IntegrateOptions(Options):
    """What ``psrig integrate`` and ``psrig run`` set of the integration and its meshes."""

    kind = "integrate option"
    method: str = option("smooth", f"{' or '.join(INTEGRATION_METHODS)}: smooth least squares, or "
                                   "discontinuity-preserving bilateral", metavar="NAME")
    k: float = option(None, "bilateral sharpness (larger keeps more discontinuities)", kind=float, above=0.0,
                      default_text="the method's")
    pixel_size: float = option(None, "orthographic: the length one pixel covers on the object; the meshes are "
                                     "then in --unit instead of pixels", kind=float, above=0.0, metavar="LENGTH")
    distance: float = option(None, "perspective (--K): the object's distance from the camera; the meshes are then "
                                   "in --unit instead of up to scale", kind=float, above=0.0, metavar="LENGTH")
    unit: str = option(None, "unit of --pixel-size or --distance", kind=str, metavar="NAME", default_text="mm")
    max_slope_deg: float = option(None, "no face across a depth step steeper than this (and than the normals say)",
                                  kind=float, above=0.0, high=90.0, flag="--max-slope", metavar="DEG",
                                  default_text=f"{MAX_SLOPE_DEG:g}")
    memory: str = option(None, "memory budget: bytes, 8G, 1500M or a share of the available memory such as 60%; a "
                               "session estimated to need more is refused before the solve", kind=str,
                         metavar="SIZE", recorded=False, default_text=f"{DEFAULT_SHARE:.0%} of the available memory")
