"""Session-relative paths of the files that stages hand to each other (see docs/design.md).

One name per file, so a stage that writes a file and the stages that read it cannot disagree
on where it lies. Paths are POSIX-style and relative to the session folder
(:meth:`pipeline.core.session.Session.path` resolves and checks them).
"""

__all__ = ["LIGHTS", "EXCLUDE", "LIGHTS_LP", "OBJECT_MASK", "SPHERE_MASK", "NORMALS", "NORMALS_MASK", "ALBEDO", "RESIDUAL", "UNCERTAINTY", "STATUS_MAP",
           "OBSERVATIONS", "LIT_OBSERVATIONS", "PREDICTION", "PREDICTION_IMAGES", "ERROR_MAP", "EVAL", "DEPTH", "MESH", "MESH_OBJ", "MESH_TEXTURE", "SHADED", "INTEGRATION",
           "REPORT", "TRUTH_LIGHTS", "TRUTH_NORMALS", "TRUTH_NORMALS_PNG", "TRUTH_MASK", "DECODE_SCRATCH",
           "TILES_SCRATCH", "SCRATCH", "linear_frame", "saturation_frame"]

def linear_frame(frame_id):
    """decode stage -> every later one: the decoded float32 EXR of one frame."""
    return f"linear/{frame_id}.exr"


def saturation_frame(frame_id):
    """decode stage -> every later one: the saturation mask PNG of one frame."""
    return f"linear/{frame_id}_sat.png"


#: decode stage: the mean reference frames of one run (removed when it ends)
DECODE_SCRATCH = "linear/.decode"

#: calibrate stage (or an importer) -> normals, report, eval: the lights in use
LIGHTS = "calibration/lights.yaml"
#: the user -> calibrate (says), normals (leaves out): lights left out by hand; no stage writes it
EXCLUDE = "calibration/exclude.yaml"
#: the same lights as an RTI .lp file
LIGHTS_LP = "calibration/lights.lp"
#: an object mask given at import
OBJECT_MASK = "calibration/object_mask.png"
#: a sphere mask given at import -> calibrate (instead of finding the spheres)
SPHERE_MASK = "calibration/sphere_mask.png"

#: normals stage -> integrate, report, eval
NORMALS = "normals/normals.exr"
NORMALS_MASK = "normals/mask.png"
ALBEDO = "normals/albedo.exr"
RESIDUAL = "normals/residual.exr"
#: each pixel's expected angular error in degrees, channel "uncertainty" (NaN: no normal);
#: absent when the run could not estimate it
UNCERTAINTY = "normals/uncertainty.exr"
STATUS_MAP = "normals/status.png"
#: per pixel, the number of observations the fit used (16-bit)
OBSERVATIONS = "normals/observations.png"
#: per pixel, the number of its observations above the shadow threshold (16-bit)
LIT_OBSERVATIONS = "normals/lit.png"
#: normals stage -> report, eval: the held-out-light prediction (pipeline.photometric.prediction)
PREDICTION = "normals/prediction.yaml"
#: its worst light's captured and predicted images on the sample grid (float EXR)
PREDICTION_IMAGES = "normals/prediction.exr"
#: eval -> report
ERROR_MAP = "normals/error.png"
EVAL = "normals/eval.yaml"

#: tiled normals stage (pipeline.photometric.tiles): the stack and tiles of one run
TILES_SCRATCH = "normals/.tiles"
#: every stage's scratch folder: the next writer removes a killed run's (Session.acquire)
SCRATCH = (DECODE_SCRATCH, TILES_SCRATCH)

#: integrate stage -> report, eval
DEPTH = "depth/depth.exr"
MESH = "depth/mesh.ply"
MESH_OBJ = "depth/mesh.obj"
#: the albedo as the OBJ's texture (mesh.mtl beside it names it)
MESH_TEXTURE = "depth/albedo.png"
SHADED = "depth/shaded.png"
INTEGRATION = "depth/integration.yaml"

#: report stage
REPORT = "report/index.html"

#: ground truth of simulated and imported sessions
TRUTH_LIGHTS = "truth/lights.yaml"
TRUTH_NORMALS = "truth/normals.exr"
TRUTH_NORMALS_PNG = "truth/normals.png"
TRUTH_MASK = "truth/mask.png"
