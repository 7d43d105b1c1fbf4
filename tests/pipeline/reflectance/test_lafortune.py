import numpy as np

from pipeline.reflectance import get_model
from pipeline.reflectance import lafortune  # noqa: F401  (registers the model)


def test_recovers_own_parameters_through_shading(scattered):
    _, _, geometry = scattered
    model = get_model("lafortune")
    truth = np.array([0.7, 1.3])
    shading = np.clip(geometry.nl, 0, None)
    values = model.evaluate(truth, geometry) * shading
    params = model.fit(geometry, values, shading=shading, weights=(shading > 0.05).astype(float))
    np.testing.assert_allclose(params, np.broadcast_to(truth, params.shape), rtol=1e-6)


def test_log_fit_is_linear_least_squares_on_logs(scattered):
    """With multiplicative noise the fit equals the closed-form LS line through the logs."""
    _, _, geometry = scattered
    model = get_model("lafortune")
    rng = np.random.default_rng(1)
    t = np.log(np.clip(geometry.nl[0], 1e-4, 1)) + np.log(np.clip(geometry.nv[0], 1e-4, 1))
    noisy = 0.5 * np.exp(0.8 * t) * np.exp(rng.normal(0, 0.05, t.shape))
    ok = geometry.nl[0] > 0
    slope, intercept = np.polyfit(t[ok], np.log(noisy[ok]), 1)
    params = model.fit(type(geometry)(*(np.broadcast_to(getattr(geometry, k), geometry.nl.shape)[0]
                                        for k in ("nl", "nv", "nh", "lh", "lv"))),
                       noisy, weights=ok.astype(float))
    np.testing.assert_allclose(params, [np.exp(intercept), slope], rtol=1e-5)


def test_non_positive_values_are_ignored(scattered):
    _, _, geometry = scattered
    model = get_model("lafortune")
    values = model.evaluate(np.array([0.4, 0.5]), geometry)
    values[:, ::5] = -1.0
    params = model.fit(geometry, values)
    assert np.all(np.isfinite(params))
    np.testing.assert_allclose(params[:, 1], 0.5, rtol=1e-6)
