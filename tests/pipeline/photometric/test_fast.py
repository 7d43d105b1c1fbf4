"""The per-pixel fit: shared and per-pixel lights agree, it converges, and the fast shared-light
blocks and helpers give the general code's results."""

import numpy as np
import pytest

from pipeline.photometric.model import powers
from pipeline.photometric.pixel_fit import fit_pixels
from pipeline.photometric.shared_shape import _schur_blocks, _shared_state
from pipeline.photometric.lambert import solve3
from pipeline.photometric.selection import _mad, select_darkest, shadow_weights

from tests.pipeline.photometric.ps_synthetic import row_angles_deg, selected_problem


@pytest.fixture(scope="module")
def narrow():
    """A glossy sphere under a DiLiGenT-like cone of lights, selected as the method does."""
    return selected_problem(40, 48, seed=4, min_elevation_deg=48, roughness=0.4, noise=0.002)


@pytest.mark.parametrize("shape_prior", [0.01, 0.0])
def test_per_pixel_lights_give_the_shared_lights_result(narrow, shape_prior):
    obs, weights, b, lights, h, y = narrow
    prior = np.array([[1.0, 0.1, 0.0], [0.2, 0.0, 0.05], [0.0, 0.0, 0.01]]) if shape_prior else None
    shared = fit_pixels(obs, weights, b, lights, h, y, prior=prior, shape_prior=shape_prior)
    tile = (len(b),) + lights.shape
    pixel = fit_pixels(obs, weights, b, np.broadcast_to(lights, tile), np.broadcast_to(h, tile),
                       np.broadcast_to(y, tile[:2]), prior=prior, shape_prior=shape_prior)
    assert row_angles_deg(shared[0], pixel[0]).max() < 1e-4   # einsum and matmul round apart
    np.testing.assert_allclose(pixel[2], shared[2], rtol=1e-6, atol=1e-14)
    np.testing.assert_array_equal(pixel[3], shared[3])
    assert not np.shares_memory(shared[0], b)


def test_the_joint_fit_converges_where_alternating_creeps(narrow):
    """Stopped when its Gauss-Newton step would turn the normal by less than ``tol_deg``, the
    joint fit ends within that angle of where many more steps end."""
    obs, weights, b, lights, h, y = narrow
    prior = np.array([[1.0, 0.1, 0.0], [0.2, 0.0, 0.05], [0.0, 0.0, 0.01]])
    long = fit_pixels(obs, weights, b, lights, h, y, prior=prior, shape_prior=0.01, max_iter=400, tol_deg=1e-5)
    for tol in (0.1, 0.02):
        short = fit_pixels(obs, weights, b, lights, h, y, prior=prior, shape_prior=0.01, tol_deg=tol)
        stopped = ~short[3]
        assert stopped.mean() > 0.99
        off = row_angles_deg(short[0][stopped], long[0][stopped])
        assert np.percentile(off, 99) < tol and off.mean() < tol / 3, (tol, np.percentile(off, 99), off.mean())
    # the prior leaves the albedo free: shapes have mean 1 over the used observations
    assert np.all(np.isfinite(short[1]))


def test_fit_stops_after_max_iter(narrow):
    obs, weights, b, lights, h, y = narrow
    _, coeffs, rss, moving, dof = fit_pixels(obs, weights, b, lights, h, y, max_iter=0)
    assert moving.all() and np.isfinite(rss).all()   # the linear start, never stepped
    _, _, _, moving, _ = fit_pixels(obs, weights, b, lights, h, y, max_iter=2)
    assert 0 < moving.sum() < len(b)


def test_effective_parameters_fall_with_the_prior(narrow):
    obs, weights, b, lights, h, y = narrow
    prior = np.array([[1.0, 0.1, 0.0], [0.2, 0.0, 0.05], [0.0, 0.0, 0.01]])
    free = fit_pixels(obs, weights, b, lights, h, y)[4]
    pulled = fit_pixels(obs, weights, b, lights, h, y, prior=prior, shape_prior=0.01)[4]
    held = fit_pixels(obs, weights, b, lights, h, y, prior=prior, shape_prior=1e6)[4]
    assert np.all(held < pulled) and np.all(pulled < free)
    np.testing.assert_allclose(held, 3.0, atol=1e-3)   # the normal and one scale of the prior


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
