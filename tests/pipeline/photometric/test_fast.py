"""The fast shared-light kernels give the results of the reference (per-pixel-light) code."""

import numpy as np
import pytest

from pipeline.photometric.alternation import alternate_per_pixel, alternate_shared, powers
from pipeline.photometric.shared_shape import _schur_blocks, _shared_state
from pipeline.photometric.lambert import solve3
from pipeline.photometric.selection import _mad, select_darkest, shadow_weights

from tests.pipeline.photometric.ps_synthetic import row_angles_deg, selected_problem


@pytest.fixture(scope="module")
def narrow():
    """A glossy sphere under a DiLiGenT-like cone of lights, selected as the method does."""
    return selected_problem(40, 48, seed=4, min_elevation_deg=48, roughness=0.4, noise=0.002)


@pytest.mark.parametrize("shape_prior", [0.01, 1e-10])
def test_alternation_matches_reference(narrow, shape_prior):
    obs, weights, b, lights, h, y = narrow
    prior = np.array([[1.0, 0.1, 0.0], [0.2, 0.0, 0.05], [0.0, 0.0, 0.01]]) if shape_prior > 1e-3 else None
    ref_b, ref_c = b.copy(), np.zeros((len(b), 3, 3))
    ref_c[:, 0, 0] = 1.0
    ref_rss = np.zeros(len(b))
    moving = alternate_per_pixel(obs, weights, ref_b, ref_c, ref_rss, np.arange(len(b)), lights, h, y,
                                 prior, shape_prior, 10, 1e-6)
    fast_b, fast_c, fast_rss, fast_moving = alternate_shared(obs, weights, b, lights, h, y, prior=prior,
                                                             shape_prior=shape_prior, max_iter=10, tol=1e-6)
    assert row_angles_deg(ref_b, fast_b).max() < 1e-3
    np.testing.assert_allclose(fast_rss, ref_rss, rtol=1e-4, atol=1e-12)
    # Pixels right at the stopping threshold may stop one iteration apart.
    assert np.mean(fast_moving != np.isin(np.arange(len(b)), moving)) < 0.01
    assert not np.shares_memory(fast_b, b)


def test_alternation_stops_after_max_iter(narrow):
    obs, weights, b, lights, h, y = narrow
    # As in the reference loop, pixels never iterated count as not converged.
    _, coeffs, rss, moving = alternate_shared(obs, weights, b, lights, h, y, max_iter=0)
    assert np.isnan(rss).all() and moving.all() and (coeffs[:, 0, 0] == 1).all()
    _, _, rss, moving = alternate_shared(obs, weights, b, lights, h, y, max_iter=1)
    assert np.isfinite(rss).all() and 0 < moving.sum() < len(b)


def test_shared_shape_blocks_match_generic(narrow):
    obs, weights, b, lights, h, y = narrow
    y3 = powers(y, 2)
    coeffs = np.array([[1.0, 0.1, 0.2], [0.3, -0.1, 0.05], [0.1, 0.0, 0.02]])
    state = _shared_state(obs, weights, b, coeffs, lights, h, y3)
    shape = (len(b),) + lights.shape
    fast = _schur_blocks(weights, state, np.broadcast_to(lights, shape), np.broadcast_to(h, shape), y3)
    slow = _schur_blocks(weights, state, np.broadcast_to(lights, shape).copy(),
                         np.broadcast_to(h, shape).copy(), y3)
    for f, s in zip(fast, slow):
        assert f.shape == s.shape
        np.testing.assert_allclose(f, s, rtol=1e-10, atol=1e-12 * np.abs(s).max())


def test_solve3_matches_lapack():
    rng = np.random.default_rng(0)
    a, rhs = rng.normal(size=(200, 3, 3)), rng.normal(size=(200, 3))
    np.testing.assert_allclose(solve3(a, rhs), np.linalg.solve(a, rhs[..., None])[..., 0], rtol=1e-8, atol=1e-10)
    assert not np.isfinite(solve3(np.zeros((1, 3, 3)), np.ones((1, 3)))).all()


def test_select_darkest_matches_double_argsort():
    rng = np.random.default_rng(1)
    obs = rng.random((500, 30))
    obs[:, :6] = obs[:, 6:12]                      # ties: the stable order must decide
    base = shadow_weights(obs, None, 0.3)
    ranked = np.where(base > 0, obs, np.inf)
    rank = np.argsort(np.argsort(ranked, axis=1, kind="stable"), axis=1, kind="stable")
    for t_low in (0.2, 0.5, 1.0):
        expected = base * (rank < np.maximum(np.ceil(t_low * base.sum(axis=1, keepdims=True)), 3))
        np.testing.assert_array_equal(select_darkest(obs, base, t_low), expected)


def test_mad_is_the_median_of_used_residuals():
    rng = np.random.default_rng(2)
    resid, weights = rng.normal(size=(50, 21)), (rng.random((50, 21)) > 0.4).astype(float)
    weights[0] = 0
    mad = _mad(resid, weights)[:, 0]
    for row in range(1, 50):
        used = np.sort(np.abs(resid[row][weights[row] > 0]))
        assert mad[row] == pytest.approx(1.4826 * used[len(used) // 2], rel=1e-6)
    assert mad[0] == 0
