"""The ``integrate`` stage: normals/normals.exr + normals/mask.png -> depth/.

Writes ``depth/depth.exr`` (float32, NaN outside the mask; in the unit of ``--pixel-size`` /
``--distance`` when one is given, else pixels or relative depth: ``depth_unit`` in
integration.yaml), ``depth/mesh.ply`` (vertex colour from the albedo, per-vertex ``quality``
from ``normals/uncertainty.exr`` when the normals stage wrote one), ``depth/mesh.obj`` with
``mesh.mtl`` and the albedo texture ``albedo.png``,
``depth/shaded.png`` and ``depth/integration.yaml`` (method, projection, components and the
statement that offsets / scales between components are unknown, the mesh's unit and the faces
left out across depth jumps), then records the stage.
:func:`write_depth_outputs` is shared with ``psrig integrate --out DIR``.
"""

import time
from pathlib import Path

import numpy as np
import yaml

from ..core.atomic import atomic_write_text
from ..core.errors import InputError, StageError
from ..core.imageio import read_image, read_mask, write_image
from ..core.memory import BASE_BYTES, budget_bytes, check_budget
from ..core.paths import (ALBEDO, DEPTH, INTEGRATION, MESH, MESH_OBJ, MESH_TEXTURE, NORMALS, NORMALS_MASK, SHADED,
                     UNCERTAINTY)
from ..settings.integrate import IntegrateOptions
from ..core.stage import Stage
from .mesh import MAX_SLOPE_DEG, albedo_colours, build_mesh, write_obj, write_ply, write_shaded
from .solve import check_intrinsics, integrate_normals_full

__all__ = ["integrate_session", "integrate_memory", "write_depth_outputs", "read_intrinsics", "integrate_files",
           "mesh_units", "NORMALS", "MASK", "OUTPUTS", "MESH_KEYS", "IntegrateStage", "INTEGRATE"]

MASK = NORMALS_MASK
OUTPUTS = (DEPTH, MESH, MESH_OBJ, "depth/mesh.mtl", MESH_TEXTURE, SHADED, INTEGRATION)
#: options of the mesh, not of the integration method: the length of a pixel (orthographic) or
#: the object's distance (perspective), the unit's name, and the slope of a depth jump
MESH_KEYS = ("pixel_size", "distance", "unit", "max_slope_deg")
_UNCOLOURED = tuple(rel for rel in OUTPUTS if rel not in (MESH_TEXTURE, "depth/mesh.mtl"))


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


def mesh_units(K=None, pixel_size=None, distance=None, unit=None):
    """The mesh's scale and unit name from what is known of the scene.

    Parameters
    ----------
    K : ndarray (3, 3), optional
    pixel_size : float, optional
        Orthographic only: the length one pixel covers on the object.
    distance : float, optional
        Perspective only: the object's distance from the camera along the axis (the integrated
        depth has geometric mean 1 per component, so this is its scale).
    unit : str, optional
        The unit of ``pixel_size`` or ``distance`` (default 'mm').

    Returns
    -------
    (scale or None, unit name)
    """
    if pixel_size is not None and distance is not None:
        raise InputError("give --pixel-size (orthographic) or --distance (perspective, with --K), not both")
    if pixel_size is not None:
        if K is not None:
            raise InputError("--pixel-size applies to orthographic integration; with --K give --distance")
        value, name = pixel_size, "--pixel-size"
    elif distance is not None:
        if K is None:
            raise InputError("--distance needs --K (perspective); orthographic meshes take --pixel-size")
        value, name = distance, "--distance"
    else:
        if unit is not None:
            raise InputError("--unit needs --pixel-size or --distance")
        return None, ("px" if K is None else "up to scale")
    if not np.isfinite(value) or value <= 0:
        raise InputError(f"{name} {value}: must be a positive length")
    return float(value), unit or "mm"


def write_depth_outputs(folder, result, normals, K=None, info=None, albedo=None, uncertainty=None, **mesh_options):
    """Write depth.exr, mesh.ply, mesh.obj (+ mesh.mtl, albedo.png), shaded.png and
    integration.yaml into ``folder``.

    Parameters
    ----------
    result : IntegrationResult
    normals : ndarray (H, W, 3)
        The integrated normals, used as the mesh's vertex normals.
    info : dict, optional
        Extra keys for integration.yaml (input files, ...).
    albedo : ndarray (H, W) or (H, W, C), optional
        Vertex colours and the OBJ's texture; none without it.
    uncertainty : ndarray (H, W), optional
        The normals' expected angular error (degrees): the PLY's per-vertex ``quality``.
    mesh_options
        ``pixel_size``, ``distance``, ``unit`` (:func:`mesh_units`), ``max_slope_deg``.

    Returns
    -------
    dict
        The integration.yaml content.
    """
    folder = Path(folder)
    scale, unit = mesh_units(K, mesh_options.get("pixel_size"), mesh_options.get("distance"), mesh_options.get("unit"))
    slope = float(mesh_options.get("max_slope_deg") or MAX_SLOPE_DEG)
    # with a length given (--pixel-size / --distance), depth.exr is in its unit like the meshes
    write_image(folder / "depth.exr", (result.depth * (scale or 1.0)).astype(np.float32), bits=32)
    mesh = build_mesh(result.depth, K, normals, albedo, scale=scale, unit=unit, max_slope_deg=slope,
                      uncertainty=uncertainty)
    comments = [f"unit {unit}", "vertex colour: albedo, sRGB" if albedo is not None else "no colour"]
    if mesh.quality is not None:
        comments.append("vertex quality: expected angular error of the normal, degrees (-1: unknown)")
    write_ply(folder / "mesh.ply", mesh.vertices, mesh.normals, mesh.faces, mesh.colours, comments, mesh.quality)
    texture = None
    if albedo is not None:
        texture = Path(MESH_TEXTURE).name
        rgb = albedo_colours(albedo)[0]
        rgb[~np.isfinite(result.depth)] = 0
        write_image(folder / texture, rgb, bits=8)
    write_obj(folder / "mesh.obj", mesh, texture, comments)
    write_shaded(folder / "shaded.png", result.depth, K)
    warnings = list(result.warnings)
    if mesh.dropped:
        warnings.append(f"mesh: {mesh.dropped} of {mesh.dropped + len(mesh.faces)} faces left out across depth "
                        f"jumps (steeper than {slope:g} deg and than the normals say): the surface is split there")
    summary = {
        "method": result.method,
        "projection": "perspective" if result.perspective else "orthographic",
        "depth": (f"positive distance along the optical axis, in {unit} (geometric mean the --distance "
                  "given, per component)" if result.perspective and scale else
                  "positive distance along the optical axis, up to scale (geometric mean 1 per "
                  "component)" if result.perspective else
                  f"height toward the camera in {unit} (pixels times --pixel-size), up to offset (mean 0 "
                  "per component)" if scale else
                  "height toward the camera in pixel units, up to offset (mean 0 per component)"),
        "depth_unit": unit if scale else ("px" if not result.perspective else "relative"),
        "K": None if K is None else np.asarray(K).tolist(),
        "pixels": int(np.isfinite(result.depth).sum()),
        "components": result.n_components,
        "offsets_between_components": "unknown" if result.n_components > 1 else "n/a",
        "iterations": result.iterations,
        "rounds": result.outer_iterations,
        "seconds": round(result.seconds, 3),
        "mesh": {"vertices": len(mesh.vertices), "faces": len(mesh.faces), "unit": unit, "scale": scale,
                 "max_slope_deg": slope, "faces_left_out_at_jumps": mesh.dropped,
                 "colour": "albedo (sRGB)" if albedo is not None else None,
                 "quality": "expected angular error, degrees" if mesh.quality is not None else None},
        "warnings": warnings,
    }
    summary.update(info or {})
    atomic_write_text(folder / "integration.yaml", yaml.safe_dump(summary, sort_keys=False))
    return summary


#: bytes the integration holds per object pixel (the sparse system, its preconditioner, the
#: solver's vectors, the mesh) and per image pixel (normals, albedo, depth); measured peaks are
#: below this (docs/big-captures.md)
OBJECT_BYTES = 800
IMAGE_BYTES = 100


def integrate_memory(mask):
    """Estimated peak bytes of the integrate stage for ``mask`` (H, W) bool."""
    return BASE_BYTES + int(mask.sum()) * OBJECT_BYTES + mask.size * IMAGE_BYTES


def integrate_session(session, *, K=None, method="smooth", force=False, invalid="drop", memory=None, **options):
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
        Passed to the method, but for :data:`MESH_KEYS`, which go to the mesh
        (:func:`write_depth_outputs`).
    memory : int or str, optional
        The memory budget (:func:`pipeline.core.memory.budget_bytes`; default a share of the
        available memory): a session whose estimated peak (:func:`integrate_memory`) exceeds
        it is refused before the solve, and the record keeps ``memory``.

    Returns
    -------
    IntegrationResult or None
        None when the stage was skipped as current.
    """
    for rel in (NORMALS, MASK):
        if not session.path(rel).is_file():
            raise StageError(f"{session.path(rel)}: missing; run `psrig normals` first")
    K = None if K is None else check_intrinsics(K)
    options = {k: v for k, v in dict(options, invalid=invalid).items() if v is not None}
    mesh_options = {k: options.pop(k) for k in MESH_KEYS if k in options}
    mesh_units(K, **{k: v for k, v in mesh_options.items() if k != "max_slope_deg"})  # refuse before solving
    # the mesh's options are recorded with the method's, so that `psrig run` keeps them
    params = {"method": method, "K": None if K is None else K.tolist(), "options": {**options, **mesh_options}}
    rels = [NORMALS, MASK] + [rel for rel in (ALBEDO, UNCERTAINTY) if session.path(rel).is_file()]
    inputs = session.hash_inputs(rels)
    if not force and session.stage_is_current("integrate", params, inputs):
        return None
    start = time.perf_counter()
    budget = budget_bytes(memory)
    needs = integrate_memory(read_mask(session.path(MASK)))
    check_budget(f"{session.root}: integrate", needs, budget,
                 "give more with --memory, or integrate a binned session (psrig decode --bin 2)")
    normals, mask = _read_inputs(session)
    result = integrate_files(normals, mask, K, method, str(session.path(NORMALS)), **options)
    result.warnings = [_why_no_normal(session, w) for w in result.warnings]
    albedo = read_image(session.path(ALBEDO)) if ALBEDO in inputs else None
    if albedo is not None and albedo.shape[:2] != mask.shape:
        raise InputError(f"{session.path(ALBEDO)}: size {albedo.shape[:2]} differs from {NORMALS} {mask.shape}")
    uncertainty = read_image(session.path(UNCERTAINTY))[:, :, 0] if UNCERTAINTY in inputs else None
    if uncertainty is not None and uncertainty.shape != mask.shape:
        raise InputError(f"{session.path(UNCERTAINTY)}: size {uncertainty.shape} differs from {NORMALS} {mask.shape}")
    summary = write_depth_outputs(session.path("depth"), result, normals, K,
                                  {"inputs": {rel: inputs[rel] for rel in rels}}, albedo, uncertainty, **mesh_options)
    result.warnings = summary["warnings"]  # the mesh's too, for whoever prints them
    session.record_stage("integrate", params, inputs, list(OUTPUTS if albedo is not None else _UNCOLOURED),
                         seconds=time.perf_counter() - start, components=result.n_components,
                         offsets_between_components="unknown" if result.n_components > 1 else "n/a",
                         iterations=result.iterations, mesh=summary["mesh"], warnings=summary["warnings"],
                         memory={"budget_gb": round(budget / 2 ** 30, 2), "estimate_gb": round(needs / 2 ** 30, 2)})
    return result


#: statuses of the normals stage that leave a pixel without a normal (pipeline.photometric.STATUS)
_NO_NORMAL = ("shadowed", "too_few", "ill_posed")


def _why_no_normal(session, warning):
    """A 'dropped ... non-finite or zero normals' warning with the normals stage's reasons, so
    that its count adds up with what the normals line said (which warns only of the statuses
    above their share limits)."""
    if "have non-finite or zero normals" not in warning:
        return warning
    counts = (session.stage("normals") or {}).get("status_counts") or {}
    reasons = [f"{name} {counts[name]}" for name in _NO_NORMAL if counts.get(name)]
    if not reasons:
        return warning
    return warning + f" (the normals stage gave them none: {', '.join(reasons)}, by its status counts)"


def _read_inputs(session):
    normals = read_image(session.path(NORMALS))
    if normals.shape[2] < 3:
        raise InputError(f"{session.path(NORMALS)}: expected 3 channels (x, y, z), found {normals.shape[2]}")
    mask = read_mask(session.path(MASK))
    if mask.shape != normals.shape[:2]:
        raise InputError(f"{session.path(MASK)}: size {mask.shape} differs from {NORMALS} {normals.shape[:2]}")
    return normals[:, :, :3], mask


class IntegrateStage(Stage):
    """The ``integrate`` stage (:class:`pipeline.core.stage.Stage`): :func:`integrate_session`."""

    name = "integrate"
    Options = IntegrateOptions
    reads = (NORMALS, MASK, f"{ALBEDO} (the meshes' colour, when present)")

    def check(self, options):
        # K (intrinsics, an array read from --K) is the stage's input beside its declared options
        rest = {k: v for k, v in options.items() if k != "K"}
        return {**IntegrateOptions.check(rest, where=self.name), **({"K": options["K"]} if "K" in options else {})}

    def work(self, session, options, *, force, jobs):
        result = integrate_session(session, force=force, **options)   # its warnings are in its record
        return result is not None, ""

    def replay(self, record):
        params = (record or {}).get("params")
        if not params:
            return {}
        kwargs = {"method": params.get("method", "smooth"),
                  **{k: v for k, v in (params.get("options") or {}).items() if k != "invalid"}}
        if params.get("K") is not None:
            kwargs["K"] = np.asarray(params["K"], float)
        return kwargs


#: the stage object the runner and the scheduler run
INTEGRATE = IntegrateStage()
