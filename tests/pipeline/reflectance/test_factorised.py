import numpy as np

from pipeline.reflectance import get_model
from pipeline.reflectance.factorised import fit_factorised
from pipeline.reflectance.polynomial import Biquadratic


def test_recovers_product_form_within_ten_iterations(scattered):
    _, _, geometry = scattered
    model = get_model("biquadratic-factorised")
    truth = np.array([0.2, 0.3, 0.5, -0.4, 0.2, 1.0])
    shading = np.clip(geometry.nl, 0, None)
    values = model.evaluate(truth, geometry) * shading
    params, iterations = fit_factorised(geometry, values, shading, (shading > 0) * 1.0)
    assert iterations <= 10
    fitted = model.evaluate(params, geometry) * shading
    assert np.max(np.abs(fitted - values)) < 1e-6
    # Same function: the outer products of the two quadratics agree (scale is not identifiable).
    outer = np.einsum("...i,...j->...ij", params[..., :3], params[..., 3:])
    np.testing.assert_allclose(outer, np.broadcast_to(np.outer(truth[:3], truth[3:]), outer.shape),
                               atol=1e-4)


def test_ten_iterations_reach_the_converged_residual_for_most_items(scattered):
    _, _, geometry = scattered
    relaxed = np.array([0.1, -0.3, 0.4, 0.2, 0.5, -0.2, 0.3, 0.1, 0.6])
    values = Biquadratic().evaluate(relaxed, geometry)
    model = get_model("biquadratic-factorised")
    res = lambda p: np.sum((model.evaluate(p, geometry) - values) ** 2, -1)  # noqa: E731
    ten = res(fit_factorised(geometry, values, max_iter=10, tol=0.0)[0])
    converged = res(fit_factorised(geometry, values, max_iter=200, tol=0.0)[0])
    assert np.all(converged <= ten * (1 + 1e-9))
    assert np.median(ten / converged) < 1.01


def test_iterated_is_never_much_worse_than_its_start(scattered):
    """Alternation only lowers the residual from the rank-one split of the relaxed fit."""
    _, _, geometry = scattered
    rng = np.random.default_rng(5)
    values = np.abs(rng.normal(0.3, 0.1, geometry.nl.shape))
    model = get_model("biquadratic-factorised")
    one, _ = fit_factorised(geometry, values, max_iter=1, tol=0.0)
    ten, _ = fit_factorised(geometry, values, max_iter=10, tol=0.0)
    res = lambda p: np.sum((model.evaluate(p, geometry) - values) ** 2, -1)  # noqa: E731
    assert np.all(res(ten) <= res(one) * (1 + 1e-9))
