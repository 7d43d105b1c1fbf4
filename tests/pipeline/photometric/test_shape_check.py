"""The shared-shape prior is used for one material and dropped when one shape fails the sample:
every pixel then keeps the robust selection with the Lambertian prior instead.

Measured (benchmarks/materials.py): on the simulated two-material object below the shared shape
costs 3.2 degrees where the Lambertian prior gives 1.9."""

import functools
import time
from concurrent.futures import Future
from pathlib import Path

import numpy as np
import pytest

from pipeline.photometric import METHODS, estimate_normals, resolve_selection

from pipeline.photometric.engine import Context

from tests.pipeline.photometric.ps_synthetic import angular_error_deg, cook_torrance_images, hemisphere_lights, sphere_normals

NARROW = hemisphere_lights(64, seed=3, min_elevation_deg=48)   # DiLiGenT-like cone: prior path


@functools.lru_cache(maxsize=1)
def two_materials():
    """The simulated rig's object (dome with dents and a groove, cast shadows, a spatially
    varying mix of its Cook-Torrance and Ward lobes) under the narrow cone (cached: do not
    modify the arrays)."""
    from rig.sim.scene import Scene

    scene = Scene.default_object((120, 160), directions=NARROW, intensities=np.ones((len(NARROW), 3)),
                                 ambient=0.0)
    images = np.stack([scene.render_linear(k, ambient=False).mean(axis=2) for k in range(len(NARROW))])
    images += np.random.default_rng(0).normal(0, 0.002, images.shape)
    truth = scene.truth()
    return images, truth["normals"], truth["mask"]


def one_material():
    normals, mask = sphere_normals(64)
    return cook_torrance_images(normals, mask, NARROW, roughness=0.4, noise=0.002), normals, mask


def test_one_material_keeps_the_prior_and_the_robust_selection():
    images, _, mask = one_material()
    result = estimate_normals(images, NARROW, mask, specular_anchor=False)
    check = result.options["shape_check"]
    assert check["one_material"] and check["ratio"] < 4 * check["expected"]
    assert "fallback" not in check and result.options["selection"] == "robust"
    assert result.shared_shape is not None
    # the same as asking for robust selection (no fallback possible) explicitly
    robust = estimate_normals(images, NARROW, mask, specular_anchor=False, selection="robust")
    np.testing.assert_array_equal(result.normals, robust.normals)


def test_two_materials_drop_the_prior_and_do_better_without_it():
    images, normals, mask = two_materials()
    result = estimate_normals(images, NARROW, mask, specular_anchor=False)
    check = result.options["shape_check"]
    assert not check["one_material"] and check["ratio"] > 4 * check["expected"]
    assert result.shared_shape is None
    forced = estimate_normals(images, NARROW, mask, specular_anchor=False, shape_prior=0.01,
                              shape_check=False)
    assert forced.shared_shape is not None
    err = angular_error_deg(result.normals, normals, mask).mean()
    err_forced = angular_error_deg(forced.normals, normals, mask).mean()
    assert err < err_forced, (err, err_forced)


def test_two_materials_keep_the_robust_selection_with_the_lambertian_prior():
    images, normals, mask = two_materials()
    result = estimate_normals(images, NARROW, mask, specular_anchor=False)
    assert result.options["shape_check"]["fallback"] == "lambertian prior"
    assert result.options["selection"] == "robust" and result.options["shared_shape"] is False
    # exactly the Lambertian prior asked for explicitly
    explicit = estimate_normals(images, NARROW, mask, specular_anchor=False, shared_shape=False)
    np.testing.assert_array_equal(result.normals, explicit.normals)


def test_the_anchor_reports_but_does_not_correct_after_the_fallback():
    images, _, mask = two_materials()
    anchored = estimate_normals(images, NARROW, mask)
    assert anchored.options["anchor"] in ("not corrected: several materials", "no highlights", "consistent")
    assert anchored.options["cone_scale"] == 1.0
    plain = estimate_normals(images, NARROW, mask, specular_anchor=False)
    np.testing.assert_array_equal(anchored.normals, plain.normals)


class _Late(Future):
    """A finished future that claims not to be done: a chunk that selected before the context."""

    def done(self):
        return False


def test_chunks_solved_with_a_shared_context_match_whatever_its_timing():
    # The tiled stage (pipeline.photometric.tiles) prepares the context once and hands the dict to
    # every tile; estimate_normals' chunks may select before it is ready.
    images, _, mask = one_material()
    # the chunks alone, as the solver makes them: no neighbours' vote (pipeline.photometric.consensus)
    result = estimate_normals(images, NARROW, mask, specular_anchor=False, neighbour_consensus=False)
    options = resolve_selection(NARROW, {})
    solver = METHODS["biquadratic"]
    flat = images.reshape(len(images), -1)
    pixels = np.flatnonzero(mask)
    context = solver.prepare(lambda idx: (flat[:, idx].T.astype(np.float64), None, NARROW), pixels, **options)
    assert context["shape"] is not None
    late = _Late()
    late.set_result(context)
    obs = flat[:, pixels].T.astype(np.float64)
    for shared in (context, Context(late)):
        b = solver(obs, None, NARROW, context=shared, **options)["b"]
        normals = b / np.linalg.norm(b, axis=1, keepdims=True)
        np.testing.assert_allclose(normals, result.normals[mask], atol=1e-6)


@pytest.mark.parametrize("material", [one_material, two_materials])
def test_chunks_selected_ahead_of_a_slow_context_give_the_serial_result(material, monkeypatch):
    images, _, mask = material()
    serial = estimate_normals(images, NARROW, mask, specular_anchor=False, workers=1, chunk_size=256)
    solver = type(METHODS["biquadratic"])
    prepare, select = solver.prepare, solver.select
    early = []

    def slow_prepare(self, *args, **kwargs):
        time.sleep(0.3)   # the other worker selects chunks meanwhile
        return prepare(self, *args, **kwargs)

    def spied_select(self, *args, context=None, **kwargs):
        early.append(not context.ready())
        return select(self, *args, context=context, **kwargs)

    monkeypatch.setattr(solver, "prepare", slow_prepare)
    monkeypatch.setattr(solver, "select", spied_select)
    ahead = estimate_normals(images, NARROW, mask, specular_anchor=False, workers=2, chunk_size=256)
    assert sum(early) >= 3, early   # several chunks were selected before the context was ready
    np.testing.assert_array_equal(ahead.normals, serial.normals)
    np.testing.assert_array_equal(ahead.status, serial.status)
    assert ahead.options.get("selection") == serial.options.get("selection")


def two_material_session(folder, name):
    """The object of :func:`two_materials` imported as 16-bit PNGs with its light file and mask."""
    from tests.pipeline.photometric.ps_synthetic import import_stack

    images, _, mask = two_materials()
    images = np.clip(images / (1.05 * images.max()), 0, 1) * mask
    return import_stack(folder, name, images, mask, NARROW)


def test_tiled_stage_falls_back_as_the_serial_stage(tmp_path):
    from pipeline import runner
    from pipeline.photometric import tiles as cluster_tiles
    from pipeline.core.imageio import read_image
    from pipeline.photometric import normals_session
    from pipeline.core.session import Session

    reference, tiled = (two_material_session(tmp_path, name) for name in ("a", "b"))
    for root in (reference, tiled):
        runner.run_session(root, stop="calibrate")
    normals_session(Session.open(reference), show_progress=False, specular_anchor=False)
    plan = cluster_tiles.plan_normals(Session.open(tiled), {"specular_anchor": False}, tile_pixels=1)
    assert len(plan.tiles) > 1 and "shape" not in plan.context
    cluster_tiles.assemble_normals(plan, [cluster_tiles.run_tile(plan, tile) for tile in plan.tiles])
    want, got = Session.open(reference).stage("normals"), Session.open(tiled).stage("normals")
    assert want["shared_shape_check"]["fallback"] == "lambertian prior"
    assert got["shared_shape_check"] == want["shared_shape_check"] and "shared_shape" not in got
    for name in ("normals/normals.exr", "normals/status.png", "normals/brdf.exr"):
        np.testing.assert_array_equal(read_image(Path(tiled) / name), read_image(Path(reference) / name))


def test_per_pixel_lights_reach_the_same_verdict_as_shared_ones():
    # near lights give per-pixel directions; the check must not depend on how lights are given
    images, normals, mask = two_materials()
    per_pixel = np.broadcast_to(NARROW[:, None, None, :], NARROW.shape[:1] + mask.shape + (3,))
    result = estimate_normals(images, per_pixel, mask)
    shared = estimate_normals(images, NARROW, mask, specular_anchor=False)
    assert result.options["shape_check"] == shared.options["shape_check"]
    assert result.options["shape_check"]["fallback"] == "lambertian prior"
    np.testing.assert_allclose(result.normals, shared.normals, atol=1e-5)
