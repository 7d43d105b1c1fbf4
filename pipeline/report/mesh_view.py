"""The report's interactive 3-D view of the integrated surface.

The mesh is the integrate stage's own (:func:`pipeline.integrate.mesh.build_mesh`: the same
faces, split at the same depth jumps, shaded with the photometric normals, coloured by the
albedo), over the depth map averaged in blocks so that it has at most :data:`MAX_VERTICES`
vertices (16-bit indices; a few MB of page at most). It is written as a script,
``mesh.js`` (``window.PSRIG_MESHES[key] = {...}``, base64 arrays), beside a copy of the viewer,
``viewer.js`` (:file:`viewer.js` in this package: WebGL, or a 2-D canvas where WebGL is
missing). Scripts, unlike fetched data, load from ``file://``: the view works from disk.
"""

import base64
import json
from pathlib import Path

import numpy as np

from ..core.atomic import atomic_write_text
from ..integrate.mesh import build_mesh
from .images import shrink

__all__ = ["mesh_payload", "write_mesh_view", "write_view_files", "viewer_source", "MAX_VERTICES", "VIEWER"]

MAX_VERTICES = 60000
#: the viewer, shipped with psrig (package data)
VIEWER = Path(__file__).with_name("viewer.js")


def viewer_source():
    """The viewer's JavaScript."""
    return VIEWER.read_text(encoding="utf-8")


def _b64(array):
    return base64.b64encode(np.ascontiguousarray(array).tobytes()).decode("ascii")


def _reduce(depth, normals, albedo, step):
    side = int(np.ceil(max(depth.shape) / step))
    small = shrink(depth[:, :, None], side)[:, :, 0]
    n = None if normals is None else shrink(normals, side)
    if n is not None:
        with np.errstate(invalid="ignore", divide="ignore"):
            n = n / np.linalg.norm(n, axis=2, keepdims=True)
    a = None if albedo is None else shrink(albedo, side)
    return small, n, a


def mesh_payload(depth, normals=None, albedo=None, K=None):
    """The viewer's data for a depth map, or None when it has fewer than 4 finite pixels.

    Parameters
    ----------
    depth : ndarray (H, W)
        NaN outside the surface; heights in pixels (orthographic) or depth (with ``K``).
    normals : ndarray (H, W, 3), optional
    albedo : ndarray (H, W[, C]), optional
    K : ndarray (3, 3), optional

    Returns
    -------
    dict
        ``positions`` (float32, centred, longest side 2), ``normals`` (int8 x 127), ``colours``
        (uint8 or None), ``indices`` (uint16), all base64; ``vertices``, ``faces``, ``step``
        (pixels per vertex side).
    """
    depth = np.asarray(depth, np.float64)
    count = int(np.isfinite(depth).sum())
    if count < 4:
        return None
    step = max(1, int(np.ceil(np.sqrt(count / MAX_VERTICES))))
    while True:
        small, n, a = _reduce(depth, normals, albedo, step)
        scale_K = None
        if K is not None:
            scale_K = np.array(K, float)
            scale_K[:2] /= step
        # orthographic heights are in pixels: a block of ``step`` pixels is one unit now
        mesh = build_mesh(small if K is not None else small / step, scale_K, n, a)
        if len(mesh.vertices) <= 65535:
            break
        step += 1
    points = mesh.vertices
    centre = (points.min(axis=0) + points.max(axis=0)) / 2
    extent = max(float(np.ptp(points, axis=0).max()), 1e-12)
    positions = ((points - centre) * (2.0 / extent)).astype(np.float32)
    return {"positions": _b64(positions),
            "normals": _b64(np.clip(np.round(mesh.normals * 127), -127, 127).astype(np.int8)),
            "colours": None if mesh.colours is None else _b64(mesh.colours.astype(np.uint8)),
            "indices": _b64(mesh.faces.astype(np.uint16)), "vertices": len(points), "faces": len(mesh.faces),
            "step": step}


def write_mesh_view(folder, key, payload):
    """Write ``folder/mesh_<key>.js`` and ``folder/viewer.js``; returns their file names."""
    return write_view_files(folder, "PSRIG_MESHES", f"mesh_{key}.js", key, payload, VIEWER)


def write_view_files(folder, variable, data_name, key, payload, viewer):
    """Write a view's data, ``folder/data_name`` (``payload`` as ``window.<variable>[key]``: a
    script the page loads from disk, where a fetch of JSON is not allowed), and its viewer
    script (the file ``viewer``) beside it; returns their file names."""
    folder = Path(folder)
    script = (f"window.{variable} = window.{variable} || {{}};\n"
              f"window.{variable}[{json.dumps(key)}] = {json.dumps(payload)};\n")
    atomic_write_text(folder / data_name, script)
    atomic_write_text(folder / viewer.name, viewer.read_text(encoding="utf-8"))
    return data_name, viewer.name
