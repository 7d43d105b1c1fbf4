import numpy as np
import pytest

from pipeline.core.errors import InputError
from pipeline.photometric import STATUS, estimate_normals, light_spread_deg, resolve_selection

from tests.pipeline.photometric.ps_synthetic import angular_error_deg, cook_torrance_images, hemisphere_lights, sphere_normals


@pytest.fixture(scope="module")
def glossy():
    normals, mask = sphere_normals(64)
    lights = hemisphere_lights(80, seed=1)
    images = cook_torrance_images(normals, mask, lights, roughness=0.4, noise=0.002)
    return images, lights, normals, mask


def test_lambertian_exact():
    normals, mask = sphere_normals(40)
    lights = hemisphere_lights(20, seed=2, min_elevation_deg=40)
    images = np.einsum("khw->khw", np.clip(np.einsum("hwc,kc->khw", normals, lights), 0, None)).astype(np.float32)
    for method in ("lambert", "biquadratic"):
        result = estimate_normals(images, lights, mask, method=method)
        inner = mask & (normals[..., 2] > 0.8)  # no attached shadows there for any light
        assert angular_error_deg(result.normals, normals, inner).max() < 0.05, method


def test_biquadratic_beats_lambert_on_cook_torrance(glossy):
    images, lights, normals, mask = glossy
    errors = {m: angular_error_deg(estimate_normals(images, lights, mask, method=m).normals, normals, mask).mean()
              for m in ("lambert", "biquadratic")}
    assert errors["biquadratic"] < 2.0
    assert errors["biquadratic"] < 0.4 * errors["lambert"], errors


def test_result_layout(glossy):
    images, lights, normals, mask = glossy
    result = estimate_normals(images, lights, mask, chunk_size=500)
    assert result.normals.shape == normals.shape and result.normals.dtype == np.float32
    assert result.params.shape == mask.shape + (9,)
    assert np.isfinite(result.normals).all() and np.isfinite(result.params).all()
    np.testing.assert_allclose(np.linalg.norm(result.normals[mask], axis=1), 1, atol=1e-5)
    assert (result.normals[~mask] == 0).all() and (result.status[~mask] == 0).all()
    assert set(np.unique(result.status[mask])) <= {STATUS["ok"], STATUS["not_converged"]}


def test_chunking_does_not_change_results(glossy):
    images, lights, _, mask = glossy
    a = estimate_normals(images, lights, mask, chunk_size=100000, workers=1)
    b = estimate_normals(images, lights, mask, chunk_size=333, workers=2)
    np.testing.assert_allclose(a.normals, b.normals, atol=1e-6)


def test_shadowed_and_too_few_pixels_are_marked_not_nan(glossy):
    images, lights, _, mask = glossy
    images = images.copy()
    ys, xs = np.nonzero(mask)
    images[:, ys[0], xs[0]] = 0.0            # never lit
    images[3:, ys[1], xs[1]] = 0.0           # only 3 lit observations... of 80
    images[2:, ys[2], xs[2]] = 0.0           # 2 lit observations
    result = estimate_normals(images, lights, mask)
    assert result.status[ys[0], xs[0]] == STATUS["shadowed"]
    assert result.status[ys[2], xs[2]] == STATUS["too_few"]
    for y, x in zip(ys[:3:2], xs[:3:2]):
        assert (result.normals[y, x] == 0).all()
    assert np.isfinite(result.normals).all() and np.isfinite(result.albedo).all()


def test_saturated_observations_are_not_used(glossy):
    images, lights, normals, mask = glossy
    spoiled = images.copy()
    spoiled[::7] *= 1.8                      # these frames are "saturated" garbage
    valid = np.ones(images.shape, bool)
    valid[::7] = False
    good = estimate_normals(spoiled, lights, mask, valid=valid, method="lambert")
    bad = estimate_normals(spoiled, lights, mask, method="lambert")
    ref = estimate_normals(images[np.arange(len(images)) % 7 != 0], lights[np.arange(len(images)) % 7 != 0],
                           mask, method="lambert")
    np.testing.assert_allclose(good.normals, ref.normals, atol=1e-5)
    assert not np.allclose(bad.normals, ref.normals, atol=1e-3)


@pytest.mark.parametrize("method", ["lambert-low", "bicubic", "biquadratic"])
def test_paper_rule_t_low(glossy, method):
    images, lights, normals, mask = glossy
    result = estimate_normals(images, lights, mask, method=method, t_low=0.4)
    assert angular_error_deg(result.normals, normals, mask).mean() < 3.0


def test_auto_selection_follows_light_geometry():
    narrow = hemisphere_lights(40, min_elevation_deg=50)
    wide = hemisphere_lights(40, min_elevation_deg=10)
    assert light_spread_deg(narrow) < 45 < light_spread_deg(wide)
    assert resolve_selection(narrow, {})["selection"] == "robust"
    assert resolve_selection(wide, {})["t_low"] == 0.35
    assert resolve_selection(wide, {})["t_shadow"] == 0.02
    assert resolve_selection(wide, {"t_low": 0.3})["t_low"] == 0.3


def test_per_pixel_lights_match_shared(glossy):
    images, lights, _, mask = glossy
    per_pixel = np.broadcast_to(lights[:, None, None, :], lights.shape[:1] + mask.shape + (3,))
    a = estimate_normals(images, lights, mask, method="lambert-low")
    b = estimate_normals(images, per_pixel, mask, method="lambert-low")
    np.testing.assert_allclose(a.normals, b.normals, atol=1e-5)


@pytest.mark.parametrize("case, match", [
    ("sizes", "lights must be"),
    ("count", "light directions for"),
    ("zero", "zero direction"),
    ("nonfinite_light", "non-finite direction"),
    ("nonfinite_pixel", "non-finite pixel"),
    ("empty", "no pixels"),
    ("rank", "rank < 3"),
    ("method", "unknown photometric stereo method"),
])
def test_bad_input(glossy, case, match):
    images, lights, _, mask = glossy
    images, lights, mask = images.copy(), lights.copy(), mask.copy()
    kwargs = {}
    if case == "sizes":
        lights = np.zeros((len(lights), 2))
    elif case == "count":
        lights = lights[:-1]
    elif case == "zero":
        lights[4] = 0
    elif case == "nonfinite_light":
        lights[5, 0] = np.nan
    elif case == "nonfinite_pixel":
        images[6][mask] = np.inf
    elif case == "empty":
        mask[:] = False
    elif case == "rank":
        lights[:, 0] = 0.0
    elif case == "method":
        kwargs["method"] = "no-such-model"
    with pytest.raises(InputError, match=match):
        estimate_normals(images, lights, mask, **kwargs)


def test_images_of_wrong_shape():
    with pytest.raises(InputError, match=r"\(K, H, W\)"):
        estimate_normals(np.zeros((4, 5)), np.eye(3)[[0, 1, 2, 2]])
