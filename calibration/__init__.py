"""Light calibration: chrome-sphere light directions, positions and intensities.

>>> from calibration import calibrate_lights
>>> lights = calibrate_lights(images, circle=None, mask=None)     # images (K, H, W) -> (K, 3)

Where things live: :mod:`.circle` finds and refines the sphere outlines, :mod:`.highlight` the
highlight on each frame, :mod:`.kinds` tells chrome from matte, :mod:`.geometry` turns image
points into sphere normals and mirror directions, :mod:`.positions` triangulates near lights
from two spheres, :mod:`.intensities` reads them off a matte target, :mod:`.sphere` puts it
together (:func:`calibrate_sphere`), :mod:`.overlays` draws what was found, and :mod:`.stage`
is the ``calibrate`` stage of a session. Measurements: docs/calibration.md.
"""

from .sphere import CalibrationError, SphereCalibration, calibrate_lights, calibrate_sphere
from .stage import CALIBRATE, CalibrateStage, calibrate_session, lights_without_spheres

__all__ = ["calibrate_lights", "calibrate_sphere", "SphereCalibration", "CalibrationError", "calibrate_session",
           "lights_without_spheres", "CalibrateStage", "CALIBRATE"]
