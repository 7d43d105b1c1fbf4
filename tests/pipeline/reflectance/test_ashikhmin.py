import numpy as np

from pipeline.reflectance import get_model
from pipeline.reflectance import ashikhmin  # noqa: F401


def test_recovers_r(scattered):
    _, _, geometry = scattered
    model = get_model("ashikhmin")
    shading = np.clip(geometry.nl, 0, None)
    values = model.evaluate(np.array([0.35]), geometry) * shading
    params = model.fit(geometry, values, shading=shading)
    np.testing.assert_allclose(params, 0.35, rtol=1e-6)


def test_eq6_values():
    from pipeline.reflectance import Geometry

    g = Geometry(nl=np.array([1.0, 0.5]), nv=np.array([1.0, 1.0]), nh=np.ones(2), lh=np.ones(2),
                 lv=np.ones(2))
    rho = get_model("ashikhmin").evaluate(np.array([2.0]), g)
    expected = 2.0 * (1 - 0.5 ** 5) * np.array([1 - 0.5 ** 5, 1 - 0.75 ** 5])
    np.testing.assert_allclose(rho, expected)
