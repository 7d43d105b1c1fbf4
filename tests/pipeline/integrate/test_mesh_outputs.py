"""Meshes that open well: albedo colours, OBJ with a texture, units, no faces across jumps."""

import numpy as np
import pytest
import yaml

from pipeline.cli import main
from pipeline.core.errors import InputError
from pipeline.core.imageio import read_image
from pipeline.integrate import integrate_session
from pipeline.integrate.mesh import build_mesh, depth_to_points, grid_faces, split_faces, write_obj
from pipeline.integrate.stage import mesh_units
from pipeline.photometric import normals_session
from tests.pipeline.photometric.test_outputs import colour_session
from tests.pipeline.tiny_session import sphere

K = np.array([[200.0, 0.0, 20.0], [0.0, 200.0, 20.0], [0.0, 0.0, 1.0]])


def read_ply(path):
    """(header lines, vertex records) of a binary PLY, parsing the properties the header names."""
    data = path.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode("ascii").splitlines()
    props = [line.split()[1:] for line in header if line.startswith("property ") and "list" not in line]
    dtype = np.dtype([(name, "<f4" if kind == "float" else "u1") for kind, name in props])
    count = int(next(line.split()[2] for line in header if line.startswith("element vertex")))
    return header, np.frombuffer(data, dtype, count, end)


def read_obj(path):
    """{keyword: rows of numbers} of an OBJ ('f' rows keep their slash-separated corners)."""
    rows = {}
    for line in path.read_text().splitlines():
        if line and not line.startswith("#"):
            key, *rest = line.split()
            rows.setdefault(key, []).append(rest)
    return rows


def hemisphere(size=40):
    """Height (px, NaN outside) and unit normals of a hemisphere of radius 0.45 * size * sqrt(0.9)."""
    normals, mask = sphere(size)
    radius = 0.45 * size
    depth = np.where(mask, normals[..., 2] * radius, np.nan)
    return depth, normals, mask


def test_a_depth_step_splits_the_mesh_and_a_silhouette_does_not():
    depth = np.zeros((10, 12))
    depth[:, 6:] = 100.0  # a step of 100 px between columns 5 and 6, flat on both sides
    normals = np.broadcast_to([0.0, 0.0, 1.0], depth.shape + (3,))
    mesh = build_mesh(depth, None, normals)
    left = mesh.pixels[:, 1] < 6
    crossing = left[mesh.faces].any(axis=1) & ~left[mesh.faces].all(axis=1)
    assert mesh.dropped == 2 * 9 and not crossing.any()
    assert len(mesh.faces) == 2 * 9 * 11 - 2 * 9

    depth, normals, mask = hemisphere()
    whole = build_mesh(depth, None, normals)
    assert whole.dropped == 0 and len(whole.faces) == len(grid_faces(mask))


def test_spikes_of_a_badly_integrated_background_are_cut_off():
    depth, normals, mask = hemisphere()
    spiky = depth.copy()
    spiky[5, 20] = -4343.0  # one pixel far below its neighbours: the normals say it is flat-ish
    mesh = build_mesh(spiky, None, normals)
    spike = np.flatnonzero((mesh.pixels == (5, 20)).all(axis=1))
    if spike.size:  # the spike pixel is in the mask: none of its faces survive
        assert not np.isin(mesh.faces, spike).any()
    assert mesh.vertices[mesh.faces][..., 2].min() > -50


@pytest.mark.parametrize("K_", [None, K])
def test_split_faces_keeps_every_face_of_a_smooth_surface(K_):
    rows, cols = np.indices((15, 20), dtype=float)
    depth = 10.0 + 0.05 * cols if K_ is not None else 0.3 * cols - 0.1 * rows
    points = depth_to_points(depth, K_).reshape(-1, 3)
    faces = grid_faces(np.ones(depth.shape, bool))
    assert split_faces(points, faces, perspective=K_ is not None).all()


def test_mesh_units_are_refused_when_they_do_not_fit_the_projection():
    assert mesh_units() == (None, "px") and mesh_units(K) == (None, "up to scale")
    assert mesh_units(None, pixel_size=0.1) == (0.1, "mm")
    assert mesh_units(K, distance=450, unit="cm") == (450.0, "cm")
    for kwargs, match in (({"K": K, "pixel_size": 0.1}, "orthographic"), ({"distance": 3}, "needs --K"),
                          ({"pixel_size": -1}, "positive"), ({"unit": "mm"}, "needs --pixel-size")):
        with pytest.raises(InputError, match=match):
            mesh_units(**kwargs)


def test_session_meshes_carry_albedo_colours_units_and_a_texture(tmp_path):
    session, mask, colour = colour_session(tmp_path)
    normals_session(session, method="lambert", show_progress=False)
    integrate_session(session, pixel_size=0.25, unit="mm")
    header, vertices = read_ply(session.path("depth/mesh.ply"))
    assert {"red", "green", "blue"} <= set(vertices.dtype.names) and "comment unit mm" in header
    # orange on the left, blue on the right: the colours tell the halves apart
    left = vertices["x"] < 0.25 * (mask.shape[1] / 2 - 2)
    right = vertices["x"] > 0.25 * (mask.shape[1] / 2 + 1)
    assert vertices["red"][left].mean() > vertices["blue"][left].mean() + 40
    assert vertices["blue"][right].mean() > vertices["red"][right].mean() + 40
    cols = np.nonzero(mask)[1]
    np.testing.assert_allclose(np.sort(vertices["x"]), np.sort(cols * 0.25), atol=1e-5)

    obj = read_obj(session.path("depth/mesh.obj"))
    assert len(obj["v"]) == len(vertices) and len(obj["v"][0]) == 6 and len(obj["vt"]) == len(vertices)
    assert obj["mtllib"] == [["mesh.mtl"]] and len(obj["vn"]) == len(vertices)
    corners = np.array([[int(c.split("/")[0]) for c in face] for face in obj["f"]])
    assert corners.min() == 1 and corners.max() <= len(obj["v"])
    assert "map_Kd albedo.png" in session.path("depth/mesh.mtl").read_text()
    assert read_image(session.path("depth/albedo.png")).shape[:2] == mask.shape
    info = yaml.safe_load(session.path("depth/integration.yaml").read_text())
    assert info["mesh"]["unit"] == "mm" and info["mesh"]["scale"] == 0.25
    record = session.stage("integrate")
    assert record["params"]["options"]["pixel_size"] == 0.25 and record["mesh"]["faces"] == len(obj["f"])
    assert integrate_session(session, pixel_size=0.25, unit="mm") is None  # the units are recorded


def test_obj_without_texture_uses_vertex_normal_corners(tmp_path):
    depth, normals, _ = hemisphere(12)
    mesh = build_mesh(depth, None, normals)
    write_obj(tmp_path / "m.obj", mesh)
    obj = read_obj(tmp_path / "m.obj")
    assert "vt" not in obj and "mtllib" not in obj and all("//" in c for c in obj["f"][0])
    assert len(obj["f"]) == len(mesh.faces) and len(obj["v"][0]) == 3


def test_integrate_command_refuses_bad_units_before_writing(tmp_path, capsys):
    session, _, _ = colour_session(tmp_path)
    normals_session(session, method="lambert", show_progress=False)
    assert main(["integrate", str(session.root), "--distance", "300"]) == 1
    assert "--distance needs --K" in capsys.readouterr().err
    assert not session.path("depth/mesh.ply").exists()
    assert main(["integrate", str(session.root), "--pixel-size", "0.1"]) == 0
    out = capsys.readouterr().out
    assert "unit mm" in out and "colour from the albedo" in out


def test_the_command_lists_the_integration_methods_it_checks():
    from pipeline.cli.integrate import METHOD_NAMES
    from pipeline.integrate import METHODS

    assert sorted(METHOD_NAMES) == sorted(METHODS)


def test_depth_exr_is_in_the_unit_given_like_the_meshes(tmp_path):
    session, mask, _ = colour_session(tmp_path)
    normals_session(session, method="lambert", show_progress=False)
    integrate_session(session)
    pixels = read_image(session.path("depth/depth.exr"))[:, :, 0]
    assert yaml.safe_load(session.path("depth/integration.yaml").read_text())["depth_unit"] == "px"
    integrate_session(session, pixel_size=0.25, unit="mm")
    scaled = read_image(session.path("depth/depth.exr"))[:, :, 0]
    finite = np.isfinite(pixels)
    np.testing.assert_allclose(scaled[finite], 0.25 * pixels[finite], rtol=1e-5, atol=1e-6)
    info = yaml.safe_load(session.path("depth/integration.yaml").read_text())
    assert info["depth_unit"] == "mm" and "in mm" in info["depth"]


def whole_obj_text(mesh, texture=None):
    """The OBJ as write_obj formatted it whole, before it wrote in pieces (the reference)."""
    def lines(prefix, array, fmt):
        line = f"{prefix} " + " ".join([fmt] * array.shape[1]) + "\n"
        return (line * len(array)) % tuple(np.asarray(array).ravel().tolist())

    def faces(ref, corner):
        values = np.repeat(ref, corner.count("%d"), axis=1)
        return ("f " + " ".join([corner] * 3) + "\n") * len(values) % tuple(values.ravel().tolist())

    vertex = np.hstack([mesh.vertices, mesh.colours / 255.0]) if mesh.colours is not None else mesh.vertices
    text = ["# psrig normal integration\n"] + (["mtllib m.mtl\nusemtl albedo\n"] if texture else [])
    text += [lines("v", vertex, "%.6g"), lines("vn", mesh.normals, "%.5f")]
    if texture:
        h, w = mesh.shape
        uv = np.stack([(mesh.pixels[:, 1] + 0.5) / w, 1 - (mesh.pixels[:, 0] + 0.5) / h], axis=1)
        text += [lines("vt", uv, "%.6f"), faces(mesh.faces + 1, "%d/%d/%d")]
    else:
        text.append(faces(mesh.faces + 1, "%d//%d"))
    return "".join(text)


@pytest.mark.parametrize("texture", [None, "albedo.png"])
def test_obj_written_in_pieces_is_the_whole_text(tmp_path, monkeypatch, texture):
    from pipeline.integrate import mesh as mesh_module

    depth, normals, _ = hemisphere(12)
    mesh = build_mesh(depth, None, normals)
    monkeypatch.setattr(mesh_module, "LINES_PER_PIECE", 7)   # pieces end mid-array, and a short last one
    assert len(mesh.vertices) % 7 and len(mesh.faces) > 7
    write_obj(tmp_path / "m.obj", mesh, texture)
    assert (tmp_path / "m.obj").read_text(encoding="utf-8") == whole_obj_text(mesh, texture)
