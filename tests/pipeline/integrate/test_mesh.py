"""Meshes: faces and winding, PLY layout, back-projection, shaded render."""

import numpy as np
import pytest

from pipeline.core.errors import InputError
from pipeline.core.imageio import read_image
from pipeline.integrate.mesh import (depth_to_points, grid_faces, mesh_normals, shade, write_depth_mesh, write_ply,
                                    write_shaded)

K = np.array([[200.0, 0.0, 9.5], [0.0, 210.0, 7.0], [0.0, 0.0, 1.0]])


def read_ply(path):
    """Parse the binary PLY that write_ply writes: (header lines, vertices (V, 6), faces (F, 3))."""
    data = path.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode("ascii").splitlines()
    count = {line.split()[1]: int(line.split()[2]) for line in header if line.startswith("element")}
    vertices = np.frombuffer(data, "<f4", count["vertex"] * 6, end).reshape(-1, 6)
    face_dtype = np.dtype([("n", "u1"), ("v", "<i4", (3,))])
    faces = np.frombuffer(data, face_dtype, count["face"], end + vertices.nbytes)
    assert (faces["n"] == 3).all()
    assert len(data) == end + vertices.nbytes + faces.nbytes
    return header, vertices, faces["v"]


def face_normals(points, faces):
    a, b, c = points[faces[:, 0]], points[faces[:, 1]], points[faces[:, 2]]
    return np.cross(b - a, c - a)


def test_two_triangles_per_full_block_only():
    mask = np.zeros((4, 5), bool)
    mask[:3, :3] = True  # 4 full 2x2 blocks
    mask[3, 4] = True  # isolated: no face
    faces = grid_faces(mask)
    assert faces.shape == (8, 3)
    assert faces.max() < mask.sum()
    assert len({tuple(sorted(f)) for f in faces}) == 8


@pytest.mark.parametrize("K_", [None, K])
def test_faces_face_the_camera(K_):
    rows, cols = np.indices((15, 20), dtype=float)
    depth = 10.0 + 0.05 * cols + 0.02 * rows if K_ is not None else 0.3 * cols - 0.1 * rows
    mask = np.ones(depth.shape, bool)
    points = depth_to_points(depth, K_)[mask]
    normals = face_normals(points, grid_faces(mask))
    if K_ is None:
        assert (normals[:, 2] > 0).all()
    else:  # toward the camera: against the ray from the camera to the face
        centres = points[grid_faces(mask)].mean(axis=1)
        assert (np.einsum("ij,ij->i", normals, centres) < 0).all()


def test_perspective_points_project_back_to_their_pixels():
    rows, cols = np.indices((15, 20), dtype=float)
    depth = 5.0 + 0.1 * rows
    points = depth_to_points(depth, K)
    assert (points[..., 2] < 0).all()  # in front of the camera: negative z (z toward camera)
    cv = points * np.array([1.0, -1.0, -1.0])
    np.testing.assert_allclose(cv[..., 2], depth)
    pixels = cv @ K.T
    np.testing.assert_allclose(pixels[..., 0] / pixels[..., 2], cols, atol=1e-9)
    np.testing.assert_allclose(pixels[..., 1] / pixels[..., 2], rows, atol=1e-9)


def test_mesh_normals_of_a_tilted_plane():
    rows, cols = np.indices((10, 10), dtype=float)
    normals = mesh_normals(depth_to_points(0.5 * cols, None))
    expected = np.array([-0.5, 0.0, 1.0]) / np.sqrt(1.25)
    np.testing.assert_allclose(normals[3:7, 3:7], np.broadcast_to(expected, (4, 4, 3)), atol=1e-12)


def test_ply_round_trip_without_nan(tmp_path):
    depth = np.full((6, 7), np.nan)
    depth[1:5, 1:6] = np.arange(20, dtype=float).reshape(4, 5) * 0.1
    given = np.zeros((6, 7, 3))
    given[..., 2] = 1.0
    given[2, 2] = np.nan  # falls back to the mesh's own normal
    vertices, faces = write_depth_mesh(tmp_path / "m.ply", depth, None, given)
    header, verts, tris = read_ply(tmp_path / "m.ply")
    assert header[1] == "format binary_little_endian 1.0"
    assert (vertices, faces) == (20, 24) and verts.shape == (20, 6) and tris.shape == (24, 3)
    assert np.isfinite(verts).all()
    mask = np.isfinite(depth)
    np.testing.assert_allclose(verts[:, 2], depth[mask].astype(np.float32))
    np.testing.assert_allclose(verts[:, 0], np.nonzero(mask)[1])
    np.testing.assert_allclose(verts[:, 1], -np.nonzero(mask)[0])
    np.testing.assert_allclose(np.linalg.norm(verts[:, 3:], axis=1), 1.0, atol=1e-6)


def test_ply_refuses_nan(tmp_path):
    with pytest.raises(InputError, match="non-finite"):
        write_ply(tmp_path / "x.ply", [[0, 0, np.nan]], [[0, 0, 1]], np.zeros((0, 3), int))
    assert not (tmp_path / "x.ply").exists()


def test_shade_flat_surface_and_background(tmp_path):
    depth = np.full((8, 9), np.nan)
    depth[2:7, 2:8] = 3.0
    light = (0.0, 0.6, 0.8)
    image = shade(depth, None, light)
    assert (image[np.isnan(depth)] == 0).all()
    np.testing.assert_allclose(image[3:6, 3:7], 0.1 + 0.9 * 0.8, atol=1e-6)
    write_shaded(tmp_path / "s.png", depth, None, light)
    stored = read_image(tmp_path / "s.png")[:, :, 0]
    np.testing.assert_allclose(stored, image, atol=1 / 255)
