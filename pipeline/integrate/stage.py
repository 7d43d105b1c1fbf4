"""The ``integrate`` stage: normals/normals.exr + normals/mask.png -> depth/.

Writes ``depth/depth.exr`` (float32, NaN outside the mask), ``depth/mesh.ply``,
``depth/shaded.png`` and ``depth/integration.yaml`` (method, projection, components and the
statement that offsets / scales between components are unknown), then records the stage.
:func:`write_depth_outputs` is shared with ``psrig integrate --out DIR``.
"""

import time
from pathlib import Path

import numpy as np
import yaml

from ..atomic import atomic_write_text
from ..errors import InputError, StageError
from ..imageio import read_image, read_mask, write_image
from ..paths import DEPTH, INTEGRATION, MESH, NORMALS, NORMALS_MASK, SHADED
from .solve import check_intrinsics, integrate_normals_full
from .mesh import write_depth_mesh, write_shaded

__all__ = ["integrate_session", "write_depth_outputs", "read_intrinsics", "integrate_files",
           "NORMALS", "MASK", "OUTPUTS"]

MASK = NORMALS_MASK
OUTPUTS = (DEPTH, MESH, SHADED, INTEGRATION)


def read_intrinsics(path):
    """Read a 3x3 intrinsics text file (whitespace or comma separated). Returns (3, 3) float64."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8").replace(",", " ")
        rows = [[float(v) for v in line.split()] for line in text.splitlines()
                if line.strip() and not line.lstrip().startswith("#")]
        K = np.array(rows, dtype=np.float64)  # ragged rows raise ValueError
    except FileNotFoundError:
        raise InputError(f"{path}: intrinsics file not found") from None
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise InputError(f"{path}: not a 3x3 matrix of numbers ({exc})") from None
    return check_intrinsics(K, where=str(path))


def integrate_files(normals, mask, K, method, where, **options):
    """Run :func:`integrate_normals_full`, prefixing input errors with ``where`` (a file)."""
    try:
        return integrate_normals_full(normals, mask, K, method, **options)
    except InputError as exc:
        raise InputError(f"{where}: {exc}") from None


def write_depth_outputs(folder, result, normals, K=None, info=None):
    """Write depth.exr, mesh.ply, shaded.png and integration.yaml into ``folder``.

    Parameters
    ----------
    result : IntegrationResult
    normals : ndarray (H, W, 3)
        The integrated normals, used as the mesh's vertex normals.
    info : dict, optional
        Extra keys for integration.yaml (input files, ...).

    Returns
    -------
    dict
        The integration.yaml content.
    """
    folder = Path(folder)
    write_image(folder / "depth.exr", result.depth.astype(np.float32), bits=32)
    vertices, faces = write_depth_mesh(folder / "mesh.ply", result.depth, K, normals)
    write_shaded(folder / "shaded.png", result.depth, K)
    summary = {
        "method": result.method,
        "projection": "perspective" if result.perspective else "orthographic",
        "depth": ("positive distance along the optical axis, up to scale (geometric mean 1 per "
                  "component)" if result.perspective else
                  "height toward the camera in pixel units, up to offset (mean 0 per component)"),
        "K": None if K is None else np.asarray(K).tolist(),
        "pixels": int(np.isfinite(result.depth).sum()),
        "components": result.n_components,
        "offsets_between_components": "unknown" if result.n_components > 1 else "n/a",
        "iterations": result.iterations,
        "rounds": result.outer_iterations,
        "seconds": round(result.seconds, 3),
        "mesh": {"vertices": vertices, "faces": faces},
        "warnings": list(result.warnings),
    }
    summary.update(info or {})
    atomic_write_text(folder / "integration.yaml", yaml.safe_dump(summary, sort_keys=False))
    return summary


def integrate_session(session, *, K=None, method="smooth", force=False, invalid="drop", **options):
    """Run the integrate stage of a session unless it is up to date.

    Parameters
    ----------
    session : Session
    K : ndarray (3, 3), optional
        Intrinsics; None for orthographic.
    method : str
        A name in :data:`pipeline.integrate.METHODS`.
    force : bool
        Run even when the stage record matches.
    invalid : {'drop', 'raise'}
        What to do with masked pixels whose normal is unusable (none, or facing away from the
        camera: photometric stereo gives such pixels in deep shadow or on the background of
        an automatic mask). 'drop' (default) leaves them out and lists them in the result's
        and the stage record's ``warnings``; 'raise' refuses them.
    options
        Passed to the method.

    Returns
    -------
    IntegrationResult or None
        None when the stage was skipped as current.
    """
    for rel in (NORMALS, MASK):
        if not session.path(rel).is_file():
            raise StageError(f"{session.path(rel)}: missing; run `psrig normals` first")
    K = None if K is None else check_intrinsics(K)
    options = dict(options, invalid=invalid)
    params = {"method": method, "K": None if K is None else K.tolist(), "options": options}
    inputs = session.hash_inputs([NORMALS, MASK])
    if not force and session.stage_is_current("integrate", params, inputs):
        return None
    start = time.perf_counter()
    normals, mask = _read_inputs(session)
    result = integrate_files(normals, mask, K, method, str(session.path(NORMALS)), **options)
    write_depth_outputs(session.path("depth"), result, normals, K,
                        {"inputs": {NORMALS: inputs[NORMALS], MASK: inputs[MASK]}})
    session.record_stage("integrate", params, inputs, list(OUTPUTS),
                         seconds=time.perf_counter() - start, components=result.n_components,
                         offsets_between_components="unknown" if result.n_components > 1 else "n/a",
                         iterations=result.iterations, warnings=list(result.warnings))
    return result


def _read_inputs(session):
    normals = read_image(session.path(NORMALS))
    if normals.shape[2] < 3:
        raise InputError(f"{session.path(NORMALS)}: expected 3 channels (x, y, z), found {normals.shape[2]}")
    mask = read_mask(session.path(MASK))
    if mask.shape != normals.shape[:2]:
        raise InputError(f"{session.path(MASK)}: size {mask.shape} differs from {NORMALS} {normals.shape[:2]}")
    return normals[:, :, :3], mask
