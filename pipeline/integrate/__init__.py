"""Surface integration: depth maps and meshes from normal maps.

>>> from pipeline.integrate import integrate_normals
>>> depth = integrate_normals(normals, mask, K=None, method="smooth")   # (H, W), NaN outside

Where things live: :mod:`.solve` (the dispatcher and the method registry :data:`METHODS`),
:mod:`.grid` (the least-squares system over the masked pixels), :mod:`.bilateral` (the smooth
and the discontinuity-preserving solvers), :mod:`.pcg` (BiNI's conjugate gradients, compiled),
:mod:`.mesh` (PLY meshes and shaded renders), :mod:`.stage` (the ``integrate`` stage).
Measurements: docs/integration.md.
"""

from .mesh import write_depth_mesh, write_shaded
from .solve import METHODS, IntegrationResult, check_intrinsics, integrate_normals, integrate_normals_full
from .stage import INTEGRATE, IntegrateStage, integrate_files, integrate_session, read_intrinsics, write_depth_outputs

__all__ = ["integrate_normals", "integrate_normals_full", "IntegrationResult", "METHODS", "check_intrinsics",
           "integrate_session", "integrate_files", "read_intrinsics", "write_depth_outputs", "write_depth_mesh",
           "write_shaded", "IntegrateStage", "INTEGRATE"]
