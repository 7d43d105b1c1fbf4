"""Depth maps to points, triangle meshes (binary PLY) and a shaded render.

Vertices are in the camera frame (x right, y up, z toward the camera):

- orthographic (``K=None``): x = column, y = -row, z = the height from integration;
- perspective: the pixel ray scaled by the depth, ``d K^-1 (col, row, 1)`` in OpenCV axes,
  turned into the camera frame (y and z negated), so the object lies at negative z.

Faces: two triangles per 2x2 block of masked pixels, wound counter-clockwise as seen from the
camera, so their normals face it.
"""

import numpy as np

from ..atomic import atomic_write_bytes
from ..errors import InputError
from ..imageio import write_image

__all__ = ["depth_to_points", "grid_faces", "mesh_normals", "write_ply", "write_depth_mesh",
           "shade", "write_shaded", "DEFAULT_LIGHT"]

#: Light of the shaded render: from the upper left, toward the camera (camera frame).
DEFAULT_LIGHT = (-0.4, 0.5, 0.77)


def depth_to_points(depth, K=None):
    """Camera-frame points of every pixel (NaN where the depth is NaN).

    Parameters
    ----------
    depth : ndarray (H, W)
        Height (orthographic, pixel units) or positive depth along the optical axis (K given).
    K : ndarray (3, 3), optional

    Returns
    -------
    points : ndarray (H, W, 3) float64
    """
    depth = np.asarray(depth, dtype=np.float64)
    rows, cols = np.indices(depth.shape, dtype=np.float64)
    if K is None:
        return np.stack([cols, -rows, depth], axis=2)
    pix = np.stack([cols, rows, np.ones_like(rows)], axis=2)
    rays = pix @ np.linalg.inv(np.asarray(K, dtype=np.float64)).T
    return rays * depth[:, :, None] * np.array([1.0, -1.0, -1.0])


def grid_faces(mask):
    """Triangles over a pixel mask.

    Returns
    -------
    faces : ndarray (F, 3) int32
        Indices into the masked pixels in row-major order (``np.nonzero(mask)`` order).
    """
    mask = np.asarray(mask, bool)
    index = np.full(mask.shape, -1, dtype=np.int64)
    index[mask] = np.arange(int(mask.sum()))
    top_left, top_right = index[:-1, :-1], index[:-1, 1:]
    bottom_left, bottom_right = index[1:, :-1], index[1:, 1:]
    full = mask[:-1, :-1] & mask[:-1, 1:] & mask[1:, :-1] & mask[1:, 1:]
    # (r, c) -> (r+1, c) -> (r, c+1) is counter-clockwise with y = -row
    first = np.stack([top_left[full], bottom_left[full], top_right[full]], axis=1)
    second = np.stack([top_right[full], bottom_left[full], bottom_right[full]], axis=1)
    return np.concatenate([first, second]).astype(np.int32)


def mesh_normals(points):
    """Unit normals (H, W, 3) of a point grid from central differences, facing +z (camera).

    NaN where a neighbour is missing.
    """
    if min(points.shape[:2]) < 2:  # a single row or column: no differences to take
        return np.full(points.shape, np.nan)
    d_col = np.gradient(points, axis=1)
    d_row = np.gradient(points, axis=0)
    normals = np.cross(d_row, d_col)  # rows go down (-y), columns right (+x): this is +z
    with np.errstate(invalid="ignore", divide="ignore"):
        return normals / np.linalg.norm(normals, axis=2, keepdims=True)


def write_ply(path, vertices, normals, faces):
    """Write a binary little-endian PLY (float32 x y z nx ny nz, int32 triangles) atomically.

    Parameters
    ----------
    vertices, normals : ndarray (V, 3)
    faces : ndarray (F, 3) int
    """
    vertices = np.asarray(vertices, np.float32)
    normals = np.asarray(normals, np.float32)
    if not (np.isfinite(vertices).all() and np.isfinite(normals).all()):
        raise InputError(f"{path}: refusing to write non-finite vertices or normals")
    vert = np.empty(len(vertices), dtype=[(k, "<f4") for k in ("x", "y", "z", "nx", "ny", "nz")])
    for column, key in enumerate(("x", "y", "z")):
        vert[key] = vertices[:, column]
        vert["n" + key] = normals[:, column]
    face = np.empty(len(faces), dtype=[("n", "u1"), ("v", "<i4", (3,))])
    face["n"] = 3
    face["v"] = faces
    header = ("ply\nformat binary_little_endian 1.0\ncomment psrig normal integration\n"
              f"element vertex {len(vert)}\n"
              + "".join(f"property float {k}\n" for k in ("x", "y", "z", "nx", "ny", "nz"))
              + f"element face {len(face)}\nproperty list uchar int vertex_indices\nend_header\n")
    atomic_write_bytes(path, header.encode("ascii") + vert.tobytes() + face.tobytes())


def write_depth_mesh(path, depth, K=None, normals=None):
    """Mesh of a depth map over its finite pixels, written as PLY.

    Parameters
    ----------
    depth : ndarray (H, W)
        NaN outside the surface.
    normals : ndarray (H, W, 3), optional
        Vertex normals (camera frame), e.g. the integrated normal map; where missing or
        invalid, normals of the depth itself are used.

    Returns
    -------
    (vertex count, face count)
    """
    mask = np.isfinite(depth)
    points = depth_to_points(depth, K)
    vertex_normals = _vertex_normals(points, mask, normals)
    faces = grid_faces(mask)
    write_ply(path, points[mask], vertex_normals, faces)
    return int(mask.sum()), len(faces)


def _vertex_normals(points, mask, normals):
    own = mesh_normals(points)[mask]
    if normals is not None:
        given = np.asarray(normals, np.float64)[mask]
        good = np.isfinite(given).all(axis=1) & (np.linalg.norm(given, axis=1) > 0.5)
        own[good] = given[good]
    bad = ~np.isfinite(own).all(axis=1)
    own[bad] = (0.0, 0.0, 1.0)  # isolated pixels and thin lines: no neighbours to tell
    return own


def shade(depth, K=None, light=DEFAULT_LIGHT):
    """Lambertian render of a depth map's own geometry, for a person to check.

    Returns
    -------
    image : ndarray (H, W) float32
        0..1 brightness, 0 outside the surface; pixels without a neighbour get a mid grey.
    """
    normals = mesh_normals(depth_to_points(depth, K))
    light = np.asarray(light, np.float64) / np.linalg.norm(light)
    value = np.clip(normals @ light, 0.0, 1.0)
    value = np.where(np.isfinite(value), 0.1 + 0.9 * value, 0.5)
    return np.where(np.isfinite(depth), value, 0.0).astype(np.float32)


def write_shaded(path, depth, K=None, light=DEFAULT_LIGHT):
    """Write :func:`shade` as an 8-bit grey PNG."""
    write_image(path, shade(depth, K, light), bits=8)
