import numpy as np
import pytest

from pipeline.reflectance import Geometry, get_model
from pipeline.reflectance import cook_torrance, ward  # noqa: F401


@pytest.mark.parametrize("name", ["cook-torrance", "ward"])
@pytest.mark.parametrize("truth", [(0.8, 0.5, 0.3), (0.3, 1.0, 0.12), (0.5, 0.2, 0.7)])
def test_recovers_own_parameters_batched(scattered, name, truth):
    _, _, geometry = scattered
    model = get_model(name)
    shading = np.clip(geometry.nl, 0, None)
    values = model.evaluate(np.array(truth), geometry) * shading
    params = model.fit(geometry, values, shading=shading, weights=(shading > 0).astype(float))
    assert params.shape == (300, 3)
    # Pixels that see the highlight identify all three parameters.
    seen = np.max(model.lobe(geometry, truth[2]) * (shading > 0), axis=1) > 0.05
    assert seen.sum() > 30
    np.testing.assert_allclose(params[seen], np.broadcast_to(truth, params[seen].shape), rtol=5e-3)
    fitted = model.evaluate(params, geometry) * shading
    assert np.max(np.abs(fitted - values)) < 1e-3 * np.max(values)


@pytest.mark.parametrize("name", ["cook-torrance", "ward"])
def test_bounded_and_finite_on_garbage(scattered, name):
    _, _, geometry = scattered
    rng = np.random.default_rng(3)
    values = rng.normal(size=geometry.nl.shape)
    values[:5] = 0.0
    params = get_model(name).fit(geometry, values, weights=(rng.uniform(size=values.shape) > 0.7) * 1.0)
    assert np.all(np.isfinite(params))
    assert np.all(params[:, :2] >= 0)
    assert np.all((params[:, 2] >= 0.01) & (params[:, 2] <= 1.0))
    assert np.all(np.isfinite(get_model(name).evaluate(params, geometry)))


def test_cook_torrance_matches_eq3_eq4_at_a_point():
    model = get_model("cook-torrance")
    n = np.array([0.0, 0.0, 1.0])
    light = np.array([np.sin(0.5), 0.0, np.cos(0.5)])
    g = Geometry.from_vectors(n, light[None])
    m, nh, lh, nl = 0.3, float(g.nh[0]), float(g.lh[0]), float(g.nl[0])
    d = np.exp((1 - 1 / nh ** 2) / m ** 2) / (4 * m ** 2 * nh ** 4)
    f = (0.04 + 0.96 * (1 - lh) ** 5) / 0.04
    gterm = min(1.0, 2 * nh * min(1.0, nl) / lh)
    expected = 0.2 / np.pi + 0.7 * d * f * gterm / (np.pi * nl * 1.0)
    np.testing.assert_allclose(model.evaluate(np.array([0.2, 0.7, m]), g), [expected], rtol=1e-9)


def test_ward_matches_formula_at_a_point():
    model = get_model("ward")
    light = np.array([np.sin(0.4), 0.0, np.cos(0.4)])
    g = Geometry.from_vectors(np.array([0.1, 0.0, 1.0]) / np.hypot(0.1, 1.0), light[None])
    m, nh, nl, nv = 0.2, float(g.nh[0]), float(g.nl[0]), float(g.nv[0])
    tan2 = (1 - nh ** 2) / nh ** 2
    expected = 0.5 / np.pi + 0.3 * np.exp(-tan2 / m ** 2) / (4 * np.pi * m ** 2 * np.sqrt(nl * nv))
    np.testing.assert_allclose(model.evaluate(np.array([0.5, 0.3, m]), g), [expected], rtol=1e-9)
