"""Every stage's and method's options, declared once (numpy-free, so the parser stays fast).

Each module declares the options of one stage as frozen dataclasses of :class:`pipeline.core.options.Options`
(a default, one line of help, how a value is checked): the stage's command-line flags, the same
flags on ``psrig run``, validation in the Python API, and the stage record all come from these
declarations. The defaults that the code decides from the data (a shadow threshold that depends
on the light layout) are declared as None with the rule stated in their help.

- :mod:`.normals`: the photometric-stereo methods' options and the ``normals`` stage's;
- :mod:`.decode`, :mod:`.calibrate`, :mod:`.integrate`, :mod:`.report`: those stages'.
"""

from .calibrate import CalibrateOptions
from .decode import DecodeOptions
from .integrate import IntegrateOptions
from .report import ReportOptions
from .normals import (BiquadraticOptions, AlternationOptions, EstimateOptions, NormalsOptions, SelectionOptions,
                      REJECT_K, SHAPE_PRIOR, T_SHADOW, WIDE_SPREAD_DEG, WIDE_T_LOW, WIDE_T_SHADOW)

__all__ = ["SelectionOptions", "EstimateOptions", "BiquadraticOptions", "AlternationOptions", "NormalsOptions",
           "IntegrateOptions", "DecodeOptions", "CalibrateOptions", "ReportOptions", "T_SHADOW", "WIDE_T_SHADOW", "WIDE_T_LOW", "WIDE_SPREAD_DEG", "REJECT_K",
           "SHAPE_PRIOR"]
