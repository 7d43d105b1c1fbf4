"""Light files: ``lights.yaml``, RTI ``.lp``, plain text, NumPy, MATLAB and OpenCV matrices.

>>> from pipeline.core.lightsio import read_lights, LightSet
>>> lights = read_lights("light_directions.txt", count=96)     # decided by content

Directions are unit vectors (K, 3) from the surface toward the light, camera frame (x right,
y up, z toward the camera), in frame order. Intensities are (K, C), one value per light and
colour channel (C = 1 or 3). :mod:`.core` holds :class:`LightSet` and ``lights.yaml``,
:mod:`.text` the text formats, :mod:`.arrays` the array files, :mod:`.read` the dispatch,
:mod:`.exclude` the lights left out by hand (``calibration/exclude.yaml``).
"""

from .core import LightSet, check_directions, check_intensities, flag_behind, read_lights_yaml, write_lights_yaml
from .exclude import exclusion_note, read_exclude
from .read import LIGHT_FORMATS, light_format, read_intensities, read_lights
from .text import lp_name, read_lights_text, read_lp, write_lp

__all__ = ["LightSet", "read_lights", "read_lights_text", "read_lp", "write_lp", "read_lights_yaml",
           "write_lights_yaml", "check_directions", "check_intensities", "flag_behind", "read_intensities",
           "light_format", "lp_name", "LIGHT_FORMATS", "read_exclude", "exclusion_note"]
