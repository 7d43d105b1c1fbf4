"""Options of the ``calibrate`` stage (:mod:`calibration`).

``psrig calibrate`` and ``psrig run`` spell them as flags of their own (``--circle`` takes one or
several outlines, ``--outline`` and ``--no-outline`` exclude each other, ``--from`` names
another session): the declaration here checks them in the API and says what the record keeps.
"""

from dataclasses import dataclass

from ..core.options import Options, option

__all__ = ["CalibrateOptions"]


@dataclass(frozen=True)
class CalibrateOptions(Options):
    """How the calibrate stage finds the spheres (or whose calibration it takes)."""

    kind = "calibrate option"
    circle: object = option(None, "sphere outline(s) (cx, cy, r), 0-based pixels", kind=object, flag="",
                            default_text="found")
    sphere_mask: str = option(None, "mask of the sphere(s), one blob per sphere", kind=str, flag="")
    outline: object = option(None, "an evenly lit photo of the sphere(s) to find them on; False: the light frames "
                                   "even when the session has outline frames", kind=object, flag="",
                             default_text="the session's outline frames, else the light frames")
    from_session: str = option(None, "use another session's calibration", kind=str, flag="")
    K: object = option(None, "3x3 intrinsics (perspective view rays)", kind=object, flag="",
                       default_text="orthographic")
