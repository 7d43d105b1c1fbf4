import numpy as np
import pytest

from pipeline.reflectance import Geometry


@pytest.fixture
def scattered():
    """300 random visible normals x 40 upper-hemisphere lights (fixed seed): (normals, lights, Geometry)."""
    rng = np.random.default_rng(7)
    normals = rng.normal(size=(300, 3))
    normals[:, 2] = np.abs(normals[:, 2]) + 0.4
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    lights = rng.normal(size=(40, 3))
    lights[:, 2] = np.abs(lights[:, 2]) + 0.2
    lights /= np.linalg.norm(lights, axis=1, keepdims=True)
    return normals, lights, Geometry.from_vectors(normals, lights)
