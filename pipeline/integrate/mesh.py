"""Depth maps to points, triangle meshes (binary PLY, OBJ) and a shaded render.

Vertices are in the camera frame (x right, y up, z toward the camera):

- orthographic (``K=None``): x = column, y = -row, z = the height from integration, all times
  the length of a pixel when it is known (``scale``), else in pixels;
- perspective: the pixel ray scaled by the depth, ``d K^-1 (col, row, 1)`` in OpenCV axes,
  turned into the camera frame (y and z negated), so the object lies at negative z; the depth
  times ``scale`` (e.g. so that the object lies at its known distance), else up to scale.

Faces: two triangles per 2x2 block of masked pixels, wound counter-clockwise as seen from the
camera, so their normals face it, except across a depth jump (:func:`split_faces`): where the
integrated surface is steeper than ``max_slope_deg`` and than its own normals say, the two
pixels lie on different surfaces and no face joins them.
"""

from dataclasses import dataclass

import numpy as np

from ..core.atomic import atomic_path, atomic_write_bytes, atomic_write_text
from ..core.errors import InputError
from ..core.gamma import encode_gamma
from ..core.imageio import write_image
from ..settings.integrate import MAX_SLOPE_DEG

__all__ = ["depth_to_points", "grid_faces", "split_faces", "mesh_normals", "albedo_colours", "Mesh",
           "build_mesh", "write_ply", "write_obj", "write_depth_mesh", "shade", "write_shaded",
           "DEFAULT_LIGHT", "MAX_SLOPE_DEG", "NORMAL_SLACK"]

#: Light of the shaded render: from the upper left, toward the camera (camera frame).
DEFAULT_LIGHT = (-0.4, 0.5, 0.77)
#: An edge steeper than this (degrees from facing the camera) may be a depth jump ... (declared
#: with the stage's options)
#: ... and is one when it is also this many times steeper than its end points' normals say.
NORMAL_SLACK = 3.0


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


def split_faces(points, faces, normals=None, max_slope_deg=MAX_SLOPE_DEG, slack=NORMAL_SLACK, perspective=False):
    """The faces that join no two points across a depth jump.

    An edge is a jump when its slope along the line of sight (depth step over lateral step)
    exceeds tan(``max_slope_deg``) and, where vertex normals are given, ``slack`` times the
    steepest slope its two end points' normals give: a silhouette's steep ring, which the
    normals explain, keeps its faces; the step to an object behind, or the spikes that the
    background of an automatic mask integrates to, do not.

    Parameters
    ----------
    points : ndarray (V, 3)
        Vertices, camera frame.
    faces : ndarray (F, 3) int
    normals : ndarray (V, 3), optional
        Unit vertex normals from photometric stereo (not from the depth itself, which would
        explain every jump); NaN where unknown (such an end explains nothing).
    max_slope_deg, slack : float
    perspective : bool
        The line of sight runs to the camera centre (the origin), not along z.

    Returns
    -------
    kept : ndarray (F,) bool
    """
    points = np.asarray(points, np.float64)
    faces = np.asarray(faces, np.int64)
    if len(faces) == 0:
        return np.zeros(0, bool)
    limit = np.tan(np.radians(max_slope_deg))
    kept = np.ones(len(faces), bool)
    for a, b in ((0, 1), (1, 2), (2, 0)):
        pa, pb = points[faces[:, a]], points[faces[:, b]]
        view = np.broadcast_to([0.0, 0.0, 1.0], pa.shape)
        if perspective:
            mid = -(pa + pb) / 2
            view = mid / np.maximum(np.linalg.norm(mid, axis=1, keepdims=True), 1e-300)
        step = pb - pa
        along = np.abs(np.einsum("ij,ij->i", step, view))
        lateral = np.linalg.norm(step - along[:, None] * view, axis=1)
        slope = along / np.maximum(lateral, 1e-300)
        jump = slope > limit
        if normals is not None:
            cosines = np.abs(np.stack([np.einsum("ij,ij->i", normals[faces[:, i]], view) for i in (a, b)]))
            with np.errstate(divide="ignore", invalid="ignore"):
                tangents = np.sqrt(np.clip(1 - cosines ** 2, 0, None)) / cosines
            explained = np.nan_to_num(np.fmax(tangents[0], tangents[1]), nan=0.0)
            jump &= slope > slack * explained
        kept &= ~jump
    return kept


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


def albedo_colours(albedo, white=None):
    """Display colours of an albedo: (..., 3) uint8 sRGB, ``white`` (default: the 99.5th
    percentile of the finite values) mapped to 255; grey albedo gives grey colours.

    Returns
    -------
    colours : ndarray (..., 3) uint8
    white : float
    """
    albedo = np.asarray(albedo, np.float64)
    if albedo.ndim == 1 or albedo.shape[-1] not in (1, 3):
        albedo = albedo[..., None]
    finite = albedo[np.isfinite(albedo) & (albedo > 0)]
    if white is None:
        white = float(np.percentile(finite, 99.5)) if finite.size else 1.0
    scaled = np.nan_to_num(albedo / max(white, 1e-12))
    codes = (encode_gamma(scaled, "srgb") * 255 + 0.5).astype(np.uint8)
    return np.broadcast_to(codes, codes.shape[:-1] + (3,)).copy(), float(white)


@dataclass
class Mesh:
    """A triangle mesh over the pixels of a depth map.

    Attributes
    ----------
    vertices, normals : ndarray (V, 3) float64
        Camera frame; unit normals.
    faces : ndarray (F, 3) int32
    pixels : ndarray (V, 2) int
        The (row, column) of each vertex: texture coordinates come from it.
    shape : (H, W)
        The depth map's size.
    colours : ndarray (V, 3) uint8, optional
        sRGB albedo.
    dropped : int
        Faces left out across depth jumps.
    unit : str
        'px', 'up to scale', or the unit of ``scale`` (e.g. 'mm').
    quality : ndarray (V,) float32, optional
        Each vertex's expected angular error of its normal (degrees; -1 where unknown), the PLY's
        per-vertex ``quality``.
    """

    vertices: np.ndarray
    normals: np.ndarray
    faces: np.ndarray
    pixels: np.ndarray
    shape: tuple
    colours: np.ndarray = None
    dropped: int = 0
    unit: str = "px"
    quality: np.ndarray = None


def build_mesh(depth, K=None, normals=None, albedo=None, *, scale=None, unit=None, max_slope_deg=MAX_SLOPE_DEG,
               uncertainty=None):
    """The mesh of a depth map over its finite pixels, split at depth jumps.

    Parameters
    ----------
    depth : ndarray (H, W)
        NaN outside the surface.
    K : ndarray (3, 3), optional
    normals : ndarray (H, W, 3), optional
        Vertex normals (camera frame), e.g. the integrated normal map; where missing or
        invalid, normals of the depth itself are used. They also tell steep surfaces from
        depth jumps (:func:`split_faces`).
    albedo : ndarray (H, W) or (H, W, 3), optional
        Vertex colours (:func:`albedo_colours`).
    scale : float, optional
        Length of one unit of the result (orthographic: a pixel; perspective: a unit of the
        integrated depth) in ``unit``.
    unit : str, optional
        Name of the length unit of ``scale`` (default 'px' orthographic, 'up to scale'
        perspective when no scale is given).
    uncertainty : ndarray (H, W), optional
        Expected angular error of each pixel's normal (degrees, NaN where unknown): the
        vertices' ``quality`` (-1 where unknown).

    Returns
    -------
    Mesh
    """
    depth = np.asarray(depth, np.float64)
    mask = np.isfinite(depth)
    points = depth_to_points(depth, K)
    vertex_normals, given = _vertex_normals(points, mask, normals)
    if scale is not None:
        points = points * float(scale)
    vertices = points[mask]
    faces = grid_faces(mask)
    kept = split_faces(vertices, faces, given, max_slope_deg, perspective=K is not None)
    colours = None if albedo is None else albedo_colours(np.asarray(albedo)[mask])[0]
    if unit is None:
        unit = "px" if K is None else "up to scale"
    quality = None
    if uncertainty is not None:
        quality = np.asarray(uncertainty, np.float32)[mask]
        quality = np.where(np.isfinite(quality), quality, np.float32(-1.0))
    return Mesh(vertices, vertex_normals, faces[kept], np.argwhere(mask), depth.shape, colours,
                int((~kept).sum()), unit, quality)


def _vertex_normals(points, mask, normals):
    """Unit normals (V, 3) of the masked points, and the given ones alone (NaN where invalid)."""
    own = mesh_normals(points)[mask]
    given = None
    if normals is not None:
        given = np.asarray(normals, np.float64)[mask]
        good = np.isfinite(given).all(axis=1) & (np.linalg.norm(given, axis=1) > 0.5)
        given = np.where(good[:, None], given / np.where(good, np.linalg.norm(given, axis=1), 1)[:, None], np.nan)
        own[good] = given[good]
    bad = ~np.isfinite(own).all(axis=1)
    own[bad] = (0.0, 0.0, 1.0)  # isolated pixels and thin lines: no neighbours to tell
    return own, given


def _check_finite(path, *arrays):
    if not all(np.isfinite(a).all() for a in arrays):
        raise InputError(f"{path}: refusing to write non-finite vertices or normals")


def write_ply(path, vertices, normals, faces, colours=None, comments=(), quality=None):
    """Write a binary little-endian PLY atomically: float32 x y z nx ny nz, uchar red green
    blue when ``colours`` are given, float32 quality when ``quality`` is (MeshLab colours by
    it: Filters > Color Creation > Colorize by vertex Quality), int32 triangles.

    Parameters
    ----------
    vertices, normals : ndarray (V, 3)
    faces : ndarray (F, 3) int
    colours : ndarray (V, 3) uint8, optional
    comments : sequence of str
        Header comments (units, where the colours come from).
    quality : ndarray (V,), optional
        Per-vertex scalar (psrig: the normal's expected angular error in degrees).
    """
    vertices = np.asarray(vertices, np.float32)
    normals = np.asarray(normals, np.float32)
    _check_finite(path, vertices, normals)
    fields = [(k, "<f4") for k in ("x", "y", "z", "nx", "ny", "nz")]
    if colours is not None:
        fields += [(k, "u1") for k in ("red", "green", "blue")]
    if quality is not None:
        fields.append(("quality", "<f4"))
    vert = np.empty(len(vertices), dtype=fields)
    for column, key in enumerate(("x", "y", "z")):
        vert[key] = vertices[:, column]
        vert["n" + key] = normals[:, column]
    if colours is not None:
        for column, key in enumerate(("red", "green", "blue")):
            vert[key] = np.asarray(colours)[:, column]
    if quality is not None:
        vert["quality"] = np.asarray(quality, np.float32)
    face = np.empty(len(faces), dtype=[("n", "u1"), ("v", "<i4", (3,))])
    face["n"] = 3
    face["v"] = faces
    header = ("ply\nformat binary_little_endian 1.0\ncomment psrig normal integration\n"
              + "".join(f"comment {c}\n" for c in comments)
              + f"element vertex {len(vert)}\n"
              + "".join(f"property {'float' if t == '<f4' else 'uchar'} {k}\n" for k, t in fields)
              + f"element face {len(face)}\nproperty list uchar int vertex_indices\nend_header\n")
    atomic_write_bytes(path, header.encode("ascii") + vert.tobytes() + face.tobytes())


#: rows formatted at a time by :func:`_lines` and :func:`_faces`: the Python floats of a
#: whole mesh's ``tolist`` and its text held at once cost about a kilobyte per vertex
LINES_PER_PIECE = 1 << 16


def _lines(prefix, array, fmt):
    """Text of lines ``prefix v0 v1 ...`` of a 2-D array, in pieces of :data:`LINES_PER_PIECE`
    lines, each formatted in one C-level pass (np.savetxt formats row by row in Python, several
    times slower on a million vertices)."""
    array = np.asarray(array)
    if len(array) == 0:
        return
    line = f"{prefix} " + " ".join([fmt] * array.shape[1]) + "\n"
    for start in range(0, len(array), LINES_PER_PIECE):
        piece = array[start:start + LINES_PER_PIECE]
        yield (line * len(piece)) % tuple(piece.ravel().tolist())


def write_obj(path, mesh, texture=None, comments=()):
    """Write a Wavefront OBJ atomically: ``v x y z r g b`` (the albedo as vertex colour, 0..1,
    the extension MeshLab and Blender read), ``vn``, and, with ``texture``, ``vt`` per pixel and a
    material file beside it (``mesh.mtl``) whose ``map_Kd`` is the albedo picture.

    Parameters
    ----------
    path : Path
    mesh : Mesh
    texture : str, optional
        File name (beside ``path``) of the albedo picture, the size of the depth map.
    comments : sequence of str
    """
    _check_finite(path, mesh.vertices, mesh.normals)
    text = [["# psrig normal integration\n"] + [f"# {c}\n" for c in comments]]
    vertex = mesh.vertices
    if mesh.colours is not None:
        vertex = np.hstack([vertex, mesh.colours / 255.0])
    if texture:
        mtl = path.with_suffix(".mtl")
        text.append([f"mtllib {mtl.name}\nusemtl albedo\n"])
        atomic_write_text(mtl, f"# psrig: the albedo as a texture\nnewmtl albedo\nKa 0 0 0\nKd 1 1 1\n"
                               f"Ks 0 0 0\nillum 1\nmap_Kd {texture}\n")
    text += [_lines("v", vertex, "%.6g"), _lines("vn", mesh.normals, "%.5f")]
    ref = mesh.faces + 1
    if texture:
        h, w = mesh.shape
        uv = np.stack([(mesh.pixels[:, 1] + 0.5) / w, 1 - (mesh.pixels[:, 0] + 0.5) / h], axis=1)
        text += [_lines("vt", uv, "%.6f"), _faces(ref, "%d/%d/%d")]
    else:
        text.append(_faces(ref, "%d//%d"))
    # written piece by piece: the file's text is never whole in memory
    with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8", newline="") as out:
        for pieces in text:
            out.writelines(pieces)


def _faces(ref, corner):
    """``f`` lines of 1-based triangles (F, 3), one index per vertex reused for v, vt and vn, in
    pieces of :data:`LINES_PER_PIECE` lines."""
    line = "f " + " ".join([corner] * 3) + "\n"
    for start in range(0, len(ref), LINES_PER_PIECE):
        values = np.repeat(ref[start:start + LINES_PER_PIECE], corner.count("%d"), axis=1)
        yield (line * len(values)) % tuple(values.ravel().tolist())


def write_depth_mesh(path, depth, K=None, normals=None, albedo=None, **options):
    """Mesh of a depth map over its finite pixels (:func:`build_mesh`), written as PLY.

    Returns
    -------
    (vertex count, face count)
    """
    mesh = build_mesh(depth, K, normals, albedo, **options)
    write_ply(path, mesh.vertices, mesh.normals, mesh.faces, mesh.colours, [f"unit {mesh.unit}"])
    return len(mesh.vertices), len(mesh.faces)


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
