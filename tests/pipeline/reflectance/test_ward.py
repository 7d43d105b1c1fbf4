import numpy as np

from pipeline.reflectance import get_model
from pipeline.reflectance import ward  # noqa: F401


def test_no_highlight_gives_no_specular(scattered):
    """A Lambertian surface: k_s must come out 0 (not an unbounded k_s times a vanishing lobe)."""
    _, _, geometry = scattered
    shading = np.clip(geometry.nl, 0, None)
    values = 0.6 / np.pi * shading
    params = get_model("ward").fit(geometry, values, shading=shading)
    np.testing.assert_allclose(params[:, 0], 0.6, rtol=1e-6)
    assert np.all(params[:, 1] < 1e-6)


def test_fits_a_channel_batch(scattered):
    _, _, geometry = scattered
    model = get_model("ward")
    truth = np.array([[0.5, 0.4, 0.25], [0.2, 0.8, 0.25], [0.9, 0.1, 0.25]])
    values = np.stack([model.evaluate(t, geometry) for t in truth])  # (3, N, K)
    params = model.fit(geometry, values)
    assert params.shape == (3, 300, 3)
    np.testing.assert_allclose(np.median(params, axis=1), truth, rtol=1e-3)
