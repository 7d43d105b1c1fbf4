"""The normals at the outline checked against it (pipeline.photometric.outline)."""

import numpy as np

from pipeline.photometric import estimate_normals, normals_warnings
from pipeline.photometric.outline import mirrored_axes, outline_check, transposed_axes

from tests.pipeline.photometric.ps_synthetic import cook_torrance_images, hemisphere_lights, sphere_normals

LIGHTS = hemisphere_lights(24, seed=2, min_elevation_deg=50)


def test_a_sphere_seen_whole_agrees_with_its_outline_on_both_axes():
    normals, mask = sphere_normals(64)
    found = outline_check(normals, mask)
    assert found["x"] == 1.0 and found["y"] == 1.0 and found["pixels"] > 100
    assert mirrored_axes(found) == []


def test_mirrored_lights_give_normals_that_point_into_the_mask_and_a_warning():
    normals, mask = sphere_normals(64)
    images = cook_torrance_images(normals, mask, LIGHTS, roughness=0.3, noise=0.002)
    right = estimate_normals(images, LIGHTS, mask).options["outline_check"]
    flipped = estimate_normals(images, LIGHTS * [1, -1, 1], mask).options["outline_check"]
    assert right["x"] > 0.9 and right["y"] > 0.9
    assert flipped["x"] > 0.9 and flipped["y"] < 0.1 and mirrored_axes(flipped) == ["y"]
    (warning,) = normals_warnings({"ok": 1}, len(LIGHTS), {"outline_check": flipped})
    assert "point into the mask along y" in warning and "negate y in the light file" in warning
    assert normals_warnings({"ok": 1}, len(LIGHTS), {"outline_check": right}) == []


def test_a_light_file_with_x_and_y_exchanged_is_named_and_so_is_a_turn_by_90_degrees():
    normals, mask = sphere_normals(64)
    images = cook_torrance_images(normals, mask, LIGHTS, roughness=0.3, noise=0.002)
    right = estimate_normals(images, LIGHTS, mask).options["outline_check"]
    assert transposed_axes(right) is None
    exchanged = estimate_normals(images, LIGHTS[:, [1, 0, 2]], mask).options["outline_check"]
    assert transposed_axes(exchanged) == [] and mirrored_axes(exchanged) == []
    (warning,) = normals_warnings({"ok": 1}, len(LIGHTS), {"outline_check": exchanged})
    assert "x and y are probably swapped (" in warning and "exchange the light file's x and y columns and" in warning
    turned = estimate_normals(images, LIGHTS[:, [1, 0, 2]] * [-1, 1, 1], mask).options["outline_check"]
    assert transposed_axes(turned) == ["y"]
    (warning,) = normals_warnings({"ok": 1}, len(LIGHTS), {"outline_check": turned})
    assert "and y then the other way" in warning and "negate y after" in warning


def test_no_verdict_without_a_silhouette():
    normals, mask = sphere_normals(64)
    # a crop of the surface that fills the image: its edge is the image's, not an outline
    full = np.ones_like(mask)
    assert outline_check(normals, full) == {"pixels": 0, "x": None, "y": None}
    # a relief facing the camera: no normal leans out at its outline
    flat = np.zeros_like(normals)
    flat[..., 2] = 1.0
    assert outline_check(flat, mask)["x"] is None and outline_check(flat, mask)["y"] is None
    # half a sphere: its cut faces the camera, so only one side leans out along x
    half = mask.copy()
    half[:, : mask.shape[1] // 2] = False
    assert outline_check(normals, half)["x"] is None


def test_the_stage_records_the_outline_and_warns_of_a_light_file_with_y_down(tmp_path):
    from pipeline.decode import decode_session
    from pipeline.photometric import normals_session
    from pipeline.core.session import Session
    from tests.pipeline.photometric.ps_synthetic import import_stack

    normals, mask = sphere_normals(48)
    images = cook_torrance_images(normals, mask, LIGHTS, roughness=0.3, noise=0.002)
    root = import_stack(tmp_path, "s", images / images.max() * 0.9, mask, LIGHTS * [1, -1, 1])
    decode_session(Session.open(root), progress=False)
    record = normals_session(Session.open(root), show_progress=False)
    assert record["outline_check"]["y"] < 0.1 and record["outline_check"]["x"] > 0.9
    assert any("point into the mask along y" in w for w in record["warnings"])


def test_an_image_too_small_for_an_outline_gives_no_verdict():
    assert outline_check(np.zeros((1, 1, 3)), np.ones((1, 1), bool)) == {"pixels": 0, "x": None, "y": None}
