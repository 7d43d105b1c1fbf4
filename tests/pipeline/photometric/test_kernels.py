"""The compiled kernels (biquadratic fit, robust selection) give their numpy references' results, pixel by pixel."""

import numpy as np
import pytest

from pipeline.photometric import kernels as ps_kernels
from pipeline.photometric.biquadratic import LAMBERT_SHAPE
from pipeline.photometric.pixel_fit import MAX_ITER, TOL_DEG, fit_pixels, fit_pixels_numpy, penalty_matrix
from pipeline.photometric.selection import select_robust, shadow_weights

from tests.pipeline.photometric.ps_synthetic import row_angles_deg, selected_problem

pytest.importorskip("numba")


@pytest.fixture(scope="module")
def glossy():
    return selected_problem(36, 40, seed=7, min_elevation_deg=40, roughness=0.3, noise=0.003)


@pytest.mark.parametrize("prior, prior_weight, tol_deg, worst_deg", [
    (LAMBERT_SHAPE, 0.01, 1e-3, TOL_DEG),
    (np.array([[1.0, 0.2, 0.0], [0.1, 0.0, 0.02], [0.0, 0.0, 0.01]]), 0.05, 1e-3, TOL_DEG),
    # no prior at all: the 9 coefficients are nearly collinear, rounding shows; on an AMD EPYC
    # host 3 of 836 pixels took another path, up to 0.36 degrees apart (0.01-0.1 elsewhere)
    (None, 0.0, 1e-2, 1.0),
])
def test_compiled_matches_numpy(glossy, prior, prior_weight, tol_deg, worst_deg):
    obs, weights, b, lights, h, y = glossy
    penalty = penalty_matrix(prior, prior_weight)
    ref = fit_pixels_numpy(obs, weights, b, lights, h, y, penalty)
    jit = ps_kernels.fit_pixels_jit(obs, weights, b, lights, h, y, penalty, MAX_ITER, TOL_DEG)
    assert jit is not None
    # A pixel right at the stopping threshold may stop one step apart (rounding decides): its
    # normals then differ by at most that tolerance, the others' by rounding.
    off = row_angles_deg(ref[0], jit[0])
    assert np.mean(off >= tol_deg) < 0.01 and off.max() < worst_deg, (np.sort(off)[-3:], tol_deg)
    close = off < tol_deg
    np.testing.assert_allclose(jit[2][close], ref[2][close], rtol=1e-4, atol=1e-12)
    np.testing.assert_allclose(jit[4][close], ref[4][close], rtol=1e-4)
    # Pixels right at the stopping threshold may stop one iteration apart.
    assert np.mean(jit[3] != ref[3]) < 0.01


def test_compiled_result_does_not_depend_on_chunking(glossy):
    obs, weights, b, lights, h, y = glossy
    penalty = penalty_matrix(None, 0.0)
    whole = ps_kernels.fit_pixels_jit(obs, weights, b, lights, h, y, penalty, MAX_ITER, TOL_DEG)
    cut = len(b) // 3
    parts = [ps_kernels.fit_pixels_jit(obs[s], weights[s], b[s], lights, h, y, penalty, MAX_ITER, TOL_DEG)
             for s in (slice(0, cut), slice(cut, None))]
    for i in range(5):
        assert np.array_equal(np.concatenate([p[i] for p in parts]), whole[i], equal_nan=True)


def test_no_jit_environment_selects_numpy(glossy, monkeypatch):
    obs, weights, b, lights, h, y = glossy
    monkeypatch.setenv(ps_kernels.ENV_NO_JIT, "1")
    assert not ps_kernels.jit_enabled()
    ref = fit_pixels_numpy(obs, weights, b, lights, h, y, penalty_matrix(None, 0.0))
    got = fit_pixels(obs, weights, b, lights, h, y)
    for i in range(4):
        assert np.array_equal(got[i], ref[i], equal_nan=True)


def test_compile_failure_warns_once_and_falls_back(glossy, monkeypatch):
    obs, weights, b, lights, h, y = glossy

    def broken():
        raise RuntimeError("no compiler here")

    monkeypatch.setattr(ps_kernels.KERNELS, "build", broken)
    ps_kernels.KERNELS.reset()
    try:
        with pytest.warns(RuntimeWarning, match="no compiler here"):
            assert ps_kernels.kernels() is None
        assert not ps_kernels.jit_enabled()
        got = fit_pixels(obs, weights, b, lights, h, y)
        ref = fit_pixels_numpy(obs, weights, b, lights, h, y, penalty_matrix(None, 0.0))
        assert np.array_equal(got[0], ref[0])
    finally:
        monkeypatch.undo()
        ps_kernels.KERNELS.reset()


@pytest.mark.parametrize("per_pixel", [False, True])
def test_compiled_selection_matches_numpy(per_pixel, monkeypatch):
    # the selection's kernel (start and MAD rounds in one pass) against its numpy reference, on
    # pixels with 30 % wrong observations so that the start and the rejection both matter
    rng = np.random.default_rng(11)
    lights = NARROW_LIGHTS / np.linalg.norm(NARROW_LIGHTS, axis=1, keepdims=True)
    n = rng.normal(size=(400, 3))
    n[:, 2] = np.abs(n[:, 2]) + 2.0
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    obs = 0.5 * np.clip(n @ lights.T, 0, None)
    wrong = rng.random(obs.shape) < 0.3
    obs = np.where(wrong, obs * rng.choice([0.4, 2.0], size=obs.shape), obs) + 0.002 * rng.normal(size=obs.shape)
    lt = np.broadcast_to(lights, (len(obs),) + lights.shape).copy() if per_pixel else lights
    base = shadow_weights(obs)
    jit_w, jit_b = select_robust(obs, lt, base)
    monkeypatch.setenv(ps_kernels.ENV_NO_JIT, "1")
    ref_w, ref_b = select_robust(obs, lt, base)
    # the kernel takes the MAD's median in float32: a residual right at the threshold may go
    # either way, so a few observations (and the pixels holding them) may differ
    assert np.mean(jit_w != ref_w) < 0.002
    same = (jit_w == ref_w).all(axis=1)
    assert same.mean() > 0.95
    np.testing.assert_allclose(jit_b[same], ref_b[same], rtol=1e-9, atol=1e-12)


NARROW_LIGHTS = np.array([[np.cos(a) * np.sin(e), np.sin(a) * np.sin(e), np.cos(e)]
                          for a, e in zip(np.linspace(0, 6 * np.pi, 40), np.radians(np.linspace(10, 45, 40)))])


@pytest.mark.parametrize("per_pixel", [False, True])
def test_compiled_shape_terms_match_numpy(glossy, per_pixel, monkeypatch):
    # the shared shape's LM terms (compiled, summed over pixels) against numpy, then the whole fit
    from pipeline.photometric.model import half_vectors
    from pipeline.photometric.shared_shape import _numpy_terms, _terms_function, fit_shared_shape

    obs, weights, b, lights, h, y = glossy
    if per_pixel:
        lights = np.broadcast_to(lights, (len(obs),) + lights.shape).copy()
        h, y = half_vectors(lights)
    shape = np.array([[1.0, 0.2, 0.05], [0.3, 0.1, 0.0], [0.1, 0.0, 0.02]])
    terms = _terms_function(obs, weights, lights, h, y)
    jit = terms(b, shape, True)
    ref = _numpy_terms(obs, weights, b, shape, lights, h, y, True, jit["weight_sum"])
    for key in ("cost", "u", "cross", "v", "e_b", "e_c", "basis"):
        np.testing.assert_allclose(jit[key], ref[key], rtol=1e-10, atol=1e-12 * np.max(np.abs(ref[key])), err_msg=key)
    # the cost alone (an LM trial's test) is its own pass, without the Jacobian's terms
    assert terms(b, shape, False) == pytest.approx(ref["cost"], rel=1e-12)
    assert terms(2 * b, shape, False) == pytest.approx(_numpy_terms(obs, weights, 2 * b, shape, lights, h, y, False,
                                                                    jit["weight_sum"]), rel=1e-12)
    fast = fit_shared_shape(obs, weights, b, lights, h, y, iterations=8)
    monkeypatch.setenv(ps_kernels.ENV_NO_JIT, "1")
    slow = fit_shared_shape(obs, weights, b, lights, h, y, iterations=8)
    # the 9 coefficients are nearly collinear under a 40-degree cone: rounding shows at 1e-5
    np.testing.assert_allclose(fast[0], slow[0], rtol=1e-4, atol=1e-9)
    assert row_angles_deg(fast[1], slow[1]).max() < 1e-4


def test_compiled_fit_under_per_pixel_lights_matches_shared(glossy):
    # per-pixel lights (near lights) that happen to be the same everywhere give the shared result
    from pipeline.photometric.model import half_vectors

    obs, weights, b, lights, h, y = glossy
    penalty = penalty_matrix(LAMBERT_SHAPE, 0.01)
    shared = ps_kernels.fit_pixels_jit(obs, weights, b, lights, h, y, penalty, MAX_ITER, TOL_DEG)
    per_pixel = np.broadcast_to(lights, (len(obs),) + lights.shape).copy()
    hp, yp = half_vectors(per_pixel)
    each = ps_kernels.fit_pixels_jit(obs, weights, b, per_pixel, hp, yp, penalty, MAX_ITER, TOL_DEG)
    assert row_angles_deg(shared[0], each[0]).max() < 1e-5   # arccos resolves about 1e-6 degrees here
    np.testing.assert_allclose(each[2], shared[2], rtol=1e-9)


def test_kth_by_bits_is_the_kth_smallest():
    # the MAD's median: exact (the bracket stops once one value is left in it), with ties and
    # zeros, over values spread across many orders of magnitude as residuals are
    compiled = ps_kernels.kernels()
    if compiled is None:
        pytest.skip("compiled kernels unavailable")
    kth_by_bits = compiled["_kth_by_bits"]
    rng = np.random.default_rng(3)
    for trial in range(3000):
        n = int(rng.integers(1, 97))
        values = np.abs(rng.standard_normal(96) * 10.0 ** rng.uniform(-6, 2, 96)).astype(np.float32)
        if trial % 3 == 0:
            values = np.round(values, 1)
        kth = int(rng.integers(0, n))
        assert kth_by_bits(values, values.view(np.int32), n, kth) == np.sort(values[:n])[kth], (n, kth)
