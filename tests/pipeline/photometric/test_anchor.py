"""Specular anchoring of the light cone (pipeline.photometric.anchor) through estimate_normals."""

import numpy as np
import pytest

from pipeline.core.errors import InputError
from pipeline.photometric import estimate_normals
from pipeline.photometric.anchor import highlight_mismatch, scale_cone

from tests.pipeline.photometric.ps_synthetic import angular_error_deg, cook_torrance_images, hemisphere_lights, sphere_normals

NARROW = hemisphere_lights(96, seed=1, min_elevation_deg=48)   # DiLiGenT-like cone


def render(true_scale, roughness, ks=0.5, size=96):
    """A Cook-Torrance sphere lit by NARROW with its polar angles scaled by ``true_scale``."""
    normals, mask = sphere_normals(size)
    images = cook_torrance_images(normals, mask, scale_cone(NARROW, true_scale), roughness=roughness, ks=ks,
                                  noise=0.002)
    return images, normals, mask


def test_scale_cone_scales_polar_angles_only():
    scaled = scale_cone(NARROW, 1.1)
    np.testing.assert_allclose(np.linalg.norm(scaled, axis=1), 1.0)
    np.testing.assert_allclose(np.arccos(scaled[:, 2]), 1.1 * np.arccos(NARROW[:, 2]), atol=1e-12)
    np.testing.assert_allclose(np.arctan2(scaled[:, 1], scaled[:, 0]), np.arctan2(NARROW[:, 1], NARROW[:, 0]),
                               atol=1e-12)
    assert scale_cone(NARROW, 1.0) is not None and np.array_equal(scale_cone(NARROW, 1.0), NARROW)


@pytest.mark.parametrize("true_scale", [0.96, 1.05])
def test_anchor_recovers_a_miscalibrated_cone(true_scale):
    images, normals, mask = render(true_scale, roughness=0.05)
    anchored = estimate_normals(images, NARROW, mask)
    plain = estimate_normals(images, NARROW, mask, specular_anchor=False)
    assert anchored.options["anchor"] == "corrected"
    assert abs(anchored.options["cone_scale"] - true_scale) < 0.01, anchored.options
    low, high = anchored.options["cone_scale_range"]
    assert low <= anchored.options["cone_scale"] <= high and high - low < 0.01, anchored.options
    e_anchored = angular_error_deg(anchored.normals, normals, mask).mean()
    e_plain = angular_error_deg(plain.normals, normals, mask).mean()
    assert e_anchored < 0.4 < 1.0 < e_plain, (e_anchored, e_plain)


def test_anchor_keeps_correct_lights():
    images, normals, mask = render(1.0, roughness=0.05)
    anchored = estimate_normals(images, NARROW, mask)
    assert anchored.options["anchor"] == "consistent" and anchored.options["cone_scale"] == 1.0
    assert abs(anchored.options["mismatch_deg"]) < 0.05
    plain = estimate_normals(images, NARROW, mask, specular_anchor=False)
    np.testing.assert_array_equal(anchored.normals, plain.normals)


def test_mismatch_is_unbiased_at_the_true_normals():
    images, normals, mask = render(1.0, roughness=0.05)
    obs = images[:, mask].T.astype(float)
    albedo = 0.7 / np.pi            # the Lambertian part of cook_torrance_images
    found = highlight_mismatch(obs, normals[mask] * albedo, NARROW)
    assert found.size > 50
    assert abs(np.median(found)) < 0.1
    # A normal field 1 degree too slanted (tilted away from the view) reads clearly positive
    # (the discrete lights attenuate the reading; the secant in anchor_scale uses the measured
    # response, so only its sign and size matter).
    tilted = normals[mask].copy()
    slant = np.arccos(np.clip(tilted[:, 2], -1, 1)) + np.radians(1.0)
    azimuth = np.arctan2(tilted[:, 1], tilted[:, 0])
    tilted = np.stack([np.sin(slant) * np.cos(azimuth), np.sin(slant) * np.sin(azimuth), np.cos(slant)], axis=1)
    assert 0.4 < np.median(highlight_mismatch(obs, tilted * albedo, NARROW)) < 1.2


def test_no_highlights_no_change():
    images, _, mask = render(1.05, roughness=0.4)
    anchored = estimate_normals(images, NARROW, mask)
    assert anchored.options["anchor"] == "no highlights" and anchored.options["cone_scale"] == 1.0
    plain = estimate_normals(images, NARROW, mask, specular_anchor=False)
    np.testing.assert_array_equal(anchored.normals, plain.normals)


@pytest.mark.parametrize("ks", [1.0, 2.0])
def test_peaks_of_broader_lobes_are_not_taken_for_a_global_error(ks):
    # Exact lights and lobes of roughness 0.1: their peaks sit off the half vector, and the
    # normals' mismatch with them responds to the cone's scale as a global error would (it
    # 'corrected' by 1.03-1.04, error 0.28 -> 0.9-1.2 degrees): such lobes are not counted.
    images, normals, mask = render(1.0, roughness=0.1, ks=ks)
    anchored = estimate_normals(images, NARROW, mask)
    assert anchored.options["anchor"] == "no highlights" and anchored.options["cone_scale"] == 1.0
    plain = estimate_normals(images, NARROW, mask, specular_anchor=False)
    np.testing.assert_array_equal(anchored.normals, plain.normals)


def test_anchor_option_checked_and_skipped_for_per_pixel_lights():
    images, _, mask = render(1.0, roughness=0.05, size=32)
    with pytest.raises(InputError, match="specular_anchor"):
        estimate_normals(images, NARROW, mask, specular_anchor="yes")
    per_pixel = np.broadcast_to(NARROW[:, None, None, :], NARROW.shape[:1] + mask.shape + (3,))
    result = estimate_normals(images, per_pixel, mask)       # robust selection, per-pixel lights
    assert "cone_scale" not in result.options
    shared = estimate_normals(images, NARROW, mask, specular_anchor=False)
    np.testing.assert_allclose(result.normals, shared.normals, atol=1e-4)
    assert "cone_scale" not in estimate_normals(images, NARROW, mask, method="lambert").options


def test_anchor_reduces_the_bias_of_a_sub_lambertian_diffuse():
    # Exact lights, but a diffuse falloff (n . l)^1.2 that the biquadratic cannot tell from a
    # steeper slant under a narrow cone (the DiLiGenT-ball pattern): the sharp highlights pull
    # the normals back.
    normals, mask = sphere_normals(96)
    images = cook_torrance_images(normals, mask, NARROW, roughness=0.05, kd=0.0, ks=0.5)
    shading = np.clip(normals[mask] @ NARROW.T, 0, None) ** 1.2
    images[:, mask] += (0.7 / np.pi * shading.T).astype(np.float32)
    anchored = estimate_normals(images, NARROW, mask)
    plain = estimate_normals(images, NARROW, mask, specular_anchor=False)
    e_anchored = angular_error_deg(anchored.normals, normals, mask).mean()
    e_plain = angular_error_deg(plain.normals, normals, mask).mean()
    assert anchored.options["anchor"] == "corrected" and anchored.options["cone_scale"] > 1.0
    assert e_anchored < 0.7 * e_plain, (e_anchored, e_plain)


def test_a_correction_keeps_the_first_runs_selection(monkeypatch):
    # the corrected run fits the observations the first run selected: beyond the first run
    # (every pixel and the shared shape's sample) only the probe selects (its sample and the
    # pixels that peaked), never every pixel again
    from pipeline.photometric import biquadratic, selection

    calls = []
    robust = selection.select_robust
    monkeypatch.setattr(selection, "select_robust", lambda obs, *a, **k: calls.append(len(obs)) or robust(obs, *a, **k))
    images, normals, mask = render(1.05, roughness=0.05)
    anchored = estimate_normals(images, NARROW, mask, workers=1)
    assert anchored.options["anchor"] == "corrected"
    pixels = int(mask.sum())
    sample = min(biquadratic.SAMPLE_PIXELS, pixels)
    probe = sum(calls) - pixels - 2 * sample
    assert 0 < probe < pixels / 2, (calls, pixels)
    # the corrected run reports the single-material verdict of the first
    assert anchored.options["shape_check"]["one_material"]


def test_later_runs_start_their_shared_shape_from_the_last_one(monkeypatch):
    # the probe starts from the first run's shape, the corrected run from the probe's, for
    # WARM_ITERATIONS steps; the first run fits from the constant shape for SHAPE_ITERATIONS
    from pipeline.photometric import biquadratic

    starts = []
    fit = biquadratic.fit_shared_shape
    def recording(*args, start=None, iterations=None, **kwargs):
        shape, b = fit(*args, start=start, iterations=iterations, **kwargs)
        starts.append((None if start is None else np.array(start), iterations, shape))
        return shape, b

    monkeypatch.setattr(biquadratic, "fit_shared_shape", recording)
    images, normals, mask = render(1.05, roughness=0.05)
    anchored = estimate_normals(images, NARROW, mask)
    assert anchored.options["anchor"] == "corrected"
    assert [iterations for _, iterations, _ in starts] == [biquadratic.SHAPE_ITERATIONS] + \
        [biquadratic.WARM_ITERATIONS] * 2
    assert starts[0][0] is None
    for (_, _, before), (start, _, _) in zip(starts, starts[1:]):
        np.testing.assert_array_equal(start, before)
    e_anchored = angular_error_deg(anchored.normals, normals, mask).mean()
    assert e_anchored < 0.4 and abs(anchored.options["cone_scale"] - 1.05) < 0.01, anchored.options


def test_kept_selection_round_trips_packed_rows():
    from pipeline.photometric.engine import KeptSelection

    rng = np.random.default_rng(0)
    pixels = np.sort(rng.choice(10_000, 300, replace=False))
    weights = rng.random((300, 13)) > 0.5
    kept = KeptSelection(pixels, 13)
    kept.put(pixels[:200], weights[:200].astype(float))
    assert not kept.complete()
    kept.put(pixels[200:], weights[200:].astype(float))
    assert kept.complete()
    some = rng.choice(300, 40, replace=False)
    np.testing.assert_array_equal(kept.get(pixels[some]), weights[some])


def test_root_range_follows_the_spread_of_the_highlights():
    from pipeline.photometric.anchor import root_range

    rng = np.random.default_rng(0)
    # mismatch +0.5 at the nominal lights, 0 at 1.05: the root is 1.05, however wide the spread
    tight = root_range(0.5 + 0.1 * rng.normal(size=200), 0.1 * rng.normal(size=200), 1.05)
    wide = root_range(0.5 + 1.5 * rng.normal(size=200), 1.5 * rng.normal(size=200), 1.05)
    assert abs(np.mean(tight) - 1.05) < 0.005 and tight[1] - tight[0] < 0.01, tight
    assert wide[0] < 1.05 < wide[1] and wide[1] - wide[0] > 3 * (tight[1] - tight[0]), (tight, wide)
    # a mismatch that does not fall as the scale rises has no root: the range's far end
    assert root_range(np.full(100, 0.5), np.full(100, 0.6), 1.05) == [1.1, 1.1]
