"""Issue 17's guarantees: a high-breakdown selection, no normal facing away, statuses that say
what happened, and few lights handled by evidence rather than a fixed count."""

import numpy as np
import pytest

from pipeline.photometric import STATUS, estimate_normals, normals_warnings
from pipeline.photometric.selection import consensus_triplets, select_robust, shadow_weights

from tests import SHARED_DATA
from tests.pipeline.photometric.ps_synthetic import angular_error_deg, cook_torrance_images, hemisphere_lights, sphere_normals

CAT = SHARED_DATA / "diligent" / "catPNG"

NARROW = hemisphere_lights(48, seed=5, min_elevation_deg=48)


def lambertian_pixels(count, lights, seed):
    rng = np.random.default_rng(seed)
    n = rng.normal(size=(count, 3))
    n[:, 2] = np.abs(n[:, 2]) + 2.0
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    return n, 0.5 * np.clip(n @ lights.T, 0, None)


def test_the_start_withstands_outliers_that_break_least_squares():
    # 40 % of each pixel's observations are wrong (interreflection-bright or shadow-dark): a
    # least-squares start breaks down there; the least-median start and its rejection do not
    normals, obs = lambertian_pixels(300, NARROW, seed=1)
    rng = np.random.default_rng(2)
    wrong = rng.random(obs.shape) < 0.4
    obs = np.where(wrong, obs * rng.choice([0.35, 2.2], size=obs.shape), obs)
    base = shadow_weights(obs)
    robust, b = select_robust(obs, NARROW, base)
    plain, b_plain = select_robust(obs, NARROW, base, consensus=0)

    def error(bb):
        u = bb / np.linalg.norm(bb, axis=1, keepdims=True)
        return np.degrees(np.arccos(np.clip(np.sum(u * normals, axis=1), -1, 1)))
    # measured: 16 % of pixels more than 1 degree off (45 % from a least-squares start); of
    # the wrong observations 16 % are kept (38 %)
    assert np.mean(error(b) > 1) < 0.5 * np.mean(error(b_plain) > 1)
    assert np.mean(robust[wrong] > 0) < 0.5 * np.mean(plain[wrong] > 0)


@pytest.mark.parametrize("count", [4, 5, 6, 8])
def test_with_few_lights_noise_is_not_taken_for_outliers(count):
    # the start's median is over the residuals its triplet does not fit: with the triplet's own
    # three (zero) counted, the median of 4-8 residuals was at or next to those zeros, and noise
    # was rejected (measured on this data: 76-88 % of the observations kept, now 97-100 %)
    lights = hemisphere_lights(count, seed=3, min_elevation_deg=50)
    _, obs = lambertian_pixels(300, lights, seed=4)
    obs = obs + np.random.default_rng(4).normal(0, 0.01, obs.shape)
    base = shadow_weights(obs)
    weights, _ = select_robust(obs, lights, base)
    full = base.sum(axis=1) == count
    assert full.mean() > 0.9
    assert np.mean(weights[full] > 0) > 0.96


def test_with_eight_lights_a_frame_far_off_is_still_rejected():
    lights = hemisphere_lights(8, seed=3, min_elevation_deg=50)
    _, obs = lambertian_pixels(300, lights, seed=4)
    obs = obs + np.random.default_rng(4).normal(0, 0.004, obs.shape)
    obs[:, 2] *= 2.5   # one frame far too bright at every pixel
    base = shadow_weights(obs)
    weights, _ = select_robust(obs, lights, base)
    full = base.sum(axis=1) == 8
    assert full.mean() > 0.9 and np.mean(weights[full, 2] == 0) > 0.95
    assert np.mean(np.delete(weights[full], 2, axis=1) > 0) > 0.95


def test_with_few_lights_the_default_beats_lambert_on_noisy_spheres():
    # random 4- to 8-light sets under a narrow cone with noise (measured: the default is better
    # on 7 of these 8, 3.90 against 4.03 degrees on average; on DiLiGenT subsets see
    # docs/photometric-stereo.md, "Few lights")
    normals, mask = sphere_normals(48)
    default_errors, lambert_errors = [], []
    for count, seed in ((4, 11), (4, 12), (5, 12), (5, 13), (5, 14), (6, 15), (6, 16), (8, 17)):
        lights = hemisphere_lights(count, seed=seed, min_elevation_deg=50)
        images = cook_torrance_images(normals, mask, lights, roughness=0.4, noise=0.004)
        default = estimate_normals(images, lights, mask)
        plain = estimate_normals(images, lights, mask, method="lambert")
        both = mask & (np.linalg.norm(default.normals, axis=2) > 0) & (np.linalg.norm(plain.normals, axis=2) > 0)
        assert both.sum() > 0.9 * mask.sum()
        default_errors.append(angular_error_deg(default.normals, normals, both).mean())
        lambert_errors.append(angular_error_deg(plain.normals, normals, both).mean())
    assert np.mean(default_errors) < np.mean(lambert_errors)
    assert np.sum(np.array(default_errors) > np.array(lambert_errors)) <= 1


@pytest.mark.skipif(not CAT.is_dir(), reason="shared DiLiGenT data missing")
def test_real_five_and_six_light_subsets_beat_lambert():
    # DiLiGenT cat, random 5- and 6-light subsets (seeds of docs/photometric-stereo.md's
    # 30-subset table): with 5 lights the default used to be worse than plain Lambert (measured
    # here: 9.81 and 11.77 against 9.34 and 9.60 degrees; now 8.88 and 8.89; with 6 lights 8.43
    # and 7.99 against 9.62 and 9.85)
    from pipeline.importers import read_diligent

    obj = read_diligent(CAT)
    images = obj.load_images()[0]
    for count, seed in ((5, 5100), (5, 5101), (6, 6100), (6, 6101)):
        chosen = np.sort(np.random.default_rng(seed).choice(len(images), count, replace=False))
        default = estimate_normals(images[chosen], obj.directions[chosen], obj.mask)
        plain = estimate_normals(images[chosen], obj.directions[chosen], obj.mask, method="lambert")
        both = obj.mask & np.logical_and(np.linalg.norm(default.normals, axis=2) > 0,
                                         np.linalg.norm(plain.normals, axis=2) > 0)
        assert both.sum() > 0.95 * obj.mask.sum()
        assert angular_error_deg(default.normals, obj.normals_gt, both).mean() < \
            angular_error_deg(plain.normals, obj.normals_gt, both).mean(), (count, seed)


def test_triplets_are_fixed_and_cover_small_light_sets():
    assert np.array_equal(consensus_triplets(96), consensus_triplets(96))
    assert len(consensus_triplets(96)) == 48 and len(consensus_triplets(6)) == 20   # all of C(6, 3)
    assert len({tuple(t) for t in consensus_triplets(96)}) == 48


def test_no_normal_faces_away_and_such_pixels_say_so():
    normals, mask = sphere_normals(32)
    images = cook_torrance_images(normals, mask, NARROW, roughness=0.3, noise=0.001)
    # a block of pixels lit from behind only: what they show fits no normal facing the camera
    block = (slice(12, 18), slice(12, 18))
    images[:, block[0], block[1]] = 0.0
    images[:3, block[0], block[1]] = 0.2
    for method in ("biquadratic", "lambert-low", "lambert"):
        result = estimate_normals(images, NARROW, mask, method=method)
        solved = result.mask & ~np.isin(result.status, [STATUS["shadowed"], STATUS["too_few"], STATUS["ill_posed"]])
        assert np.all(result.normals[solved][:, 2] > 0), method
        assert not np.isnan(result.normals).any()
        no_normal = np.isin(result.status, [STATUS["shadowed"], STATUS["too_few"], STATUS["ill_posed"]])
        assert np.all(result.normals[no_normal] == 0)


def test_coplanar_lights_at_a_pixel_are_ill_posed():
    normals, obs = lambertian_pixels(50, NARROW, seed=3)
    flat = NARROW.copy()
    flat[:, 1] = 0.0                       # every light in the x-z plane
    flat /= np.linalg.norm(flat, axis=1, keepdims=True)
    images = (0.5 * np.clip(normals @ flat.T, 0, None)).T.reshape(len(flat), 5, 10)
    with pytest.raises(Exception, match="rank < 3"):
        estimate_normals(images, flat, np.ones((5, 10), bool))
    # nearly coplanar: accepted for the image, ill-posed at the pixels whose lights are so
    tilted = flat.copy()
    tilted[0, 1] = 0.2
    tilted /= np.linalg.norm(tilted, axis=1, keepdims=True)
    result = estimate_normals(images, tilted, np.ones((5, 10), bool), method="lambert-low")
    assert np.all(result.status == STATUS["ill_posed"]) and not result.normals.any()


def test_a_degenerate_selection_widens_rather_than_leaving_no_normal():
    # 8 lights over a wide dome, 8-bit frames: the darkest few of a pixel's observations often
    # sit on one side and determined no normal at 6-16 % of the pixels, where plain Lambert
    # was within 5 degrees; they now take all their non-shadowed observations
    normals, mask = sphere_normals(64)
    lights = hemisphere_lights(8, seed=0, min_elevation_deg=20)
    images = cook_torrance_images(normals, mask, lights, roughness=0.3)
    images = np.round(np.clip(images / np.percentile(images[:, mask], 99.5) * 0.9, 0, 1) * 255) / 255
    default = estimate_normals(images, lights, mask)
    lambert = estimate_normals(images, lights, mask, method="lambert")
    no_normal = np.isin(default.status, [STATUS["shadowed"], STATUS["too_few"], STATUS["ill_posed"]])
    assert np.mean(no_normal[mask]) < 0.02
    solved = mask & ~no_normal
    assert (angular_error_deg(default.normals, normals, solved).mean()
            < angular_error_deg(lambert.normals, normals, solved).mean())
    # the lit observations are the ones the selection chose from: never fewer than it used
    assert np.all(default.lit >= default.used) and np.any(default.lit[mask] > default.used[mask])
    assert np.array_equal(lambert.lit, lambert.used)


def test_few_lights_fit_the_shared_shape_rather_than_fall_back():
    normals, mask = sphere_normals(48)
    lights = hemisphere_lights(10, seed=7, min_elevation_deg=48)
    images = cook_torrance_images(normals, mask, lights, roughness=0.3, noise=0.002)
    default = estimate_normals(images, lights, mask, specular_anchor=False)
    low = estimate_normals(images, lights, mask, method="lambert-low")
    shares = {name: np.mean(default.status[mask] == code) for name, code in STATUS.items()}
    assert shares["shared_shape"] + shares["ok"] > 0.5, shares        # not a fallback to Lambert
    assert angular_error_deg(default.normals, normals, mask).mean() < angular_error_deg(low.normals, normals, mask).mean()


def test_warnings_name_the_shares_that_matter():
    counts = {"ok": 100, "lambert_fallback": 300, "not_converged": 2, "ill_posed": 3, "shared_shape": 0}
    warnings = normals_warnings(counts, 12, {})
    assert any("74.1% of pixels fell back to Lambert" in w and "12 lights" in w for w in warnings)
    # the share reads as the status line's: not "100%" while some pixels took another model
    nearly = normals_warnings({"lambert_fallback": 996, "shared_shape": 1, "too_few": 3}, 6, {})
    assert nearly[0].startswith("99.6% of pixels fell back to Lambert"), nearly
    assert any("3 pixel(s) have no normal" in w for w in warnings)
    assert not any("did not converge" in w for w in warnings)      # 0.5 %: under the 5 % bar
    failed = normals_warnings({"ok": 10}, 96, {"shape_check": {"ratio": 20.0, "expected": 1.1,
                                                              "fallback": "lambertian prior"}})
    assert any("several materials" in w for w in failed)


def test_a_reused_selection_is_refitted_under_the_new_lights():
    from pipeline.photometric.lambert import lambert_weighted
    from pipeline.photometric.selection import reuse_selection, select_observations

    normals, mask = sphere_normals(24)
    lights = hemisphere_lights(40, seed=2, min_elevation_deg=48)
    obs = cook_torrance_images(normals, mask, lights, roughness=0.3)[:, mask].T.astype(float)
    base, weights, _ = select_observations(obs, None, lights)
    other = lights + np.array([0.02, -0.01, 0.0])
    other /= np.linalg.norm(other, axis=1, keepdims=True)
    base2, weights2, b2 = reuse_selection(obs, None, other, weights > 0)
    np.testing.assert_array_equal(base2, base)
    np.testing.assert_array_equal(weights2, weights)
    np.testing.assert_allclose(b2, lambert_weighted(obs, other, weights), rtol=1e-12, atol=1e-12)
