"""Photometric stereo: surface normals per pixel from images under known lights.

>>> from pipeline.photometric import estimate_normals
>>> result = estimate_normals(images, lights, mask=None, method="biquadratic")

Where things live:

- :mod:`.estimate`: the dispatcher :func:`estimate_normals` and its plan (input checks, the
  method, the selection, the specular anchor);
- :mod:`.engine`: chunks of pixels on all cores, shared by every path;
- :mod:`.methods`: the method registry :data:`METHODS`, the status codes, the Lambertian
  baselines and the paper's alternation with any reflectance model;
- :mod:`.biquadratic`: the default method; :mod:`.model` the biquadratic's building blocks,
  :mod:`.pixel_fit` each pixel's joint fit of normal and coefficients (compiled in
  :mod:`.kernels`); :mod:`.shared_shape` the object's one shape and the
  single-material check; :mod:`.selection` which observations each pixel uses;
- :mod:`.anchor`: the light cone corrected on specular peaks;
- :mod:`.frame_gains`, :mod:`.frame_directions`: each frame's brightness and light direction
  checked against the images before the fit; :mod:`.outline` the normals checked against the
  mask's outline after it (a light file with an axis the other way); :mod:`.registration`
  each frame against the normals' rendering of it (the object or camera moved), in the stage;
- :mod:`.near_lights`, :mod:`.near_depth`: near point lights, at the integrated depth;
- :mod:`.stage`: the ``normals`` stage of a session, :mod:`.summary` what it says of a run;
  :mod:`.tiles`: the same stage in pixel tiles for Dask.

The methods and the measurements behind the defaults: docs/photometric-stereo.md.
"""

import functools

from . import biquadratic  # noqa: F401  (registers the default method)
from .biquadratic import Biquadratic, biquadratic_method
from .estimate import PhotometricResult, SolvePlan, check_lights, estimate_normals, plan_solve
from .methods import METHODS, STATUS, STATUS_NAMES, get_method, register_model_methods, share_text
from .near_lights import PointLights, observations_at
from .registration import check_registration
from .selection import light_spread_deg, resolve_selection
from . import stage as _stage
from .stage import NormalsStage
from .summary import normals_summary, normals_warnings
from .tiles import SCRATCH, WHOLE_IMAGE, TilePlan, assemble_normals, plan_normals, run_tile, solve_tiled


@functools.wraps(_stage.normals_session)
def normals_session(session, **options):
    # the stage with its tiled execution for stacks over the memory budget (the tiles module
    # imports the stage's, so the stage cannot import it)
    return _stage.normals_session(session, tiled=solve_tiled, **options)


#: the normals stage the runner and the scheduler run: the serial stage with its tiled execution
NORMALS = _stage.NormalsStage(tiled=solve_tiled)

register_model_methods()

__all__ = ["share_text", "estimate_normals", "PhotometricResult", "SolvePlan", "plan_solve", "check_lights", "METHODS",
           "get_method", "STATUS", "STATUS_NAMES", "Biquadratic", "biquadratic_method", "PointLights",
           "observations_at", "light_spread_deg", "resolve_selection", "normals_session", "normals_summary",
           "normals_warnings", "check_registration", "TilePlan",
           "plan_normals", "run_tile", "assemble_normals", "WHOLE_IMAGE", "SCRATCH", "NORMALS", "NormalsStage"]
