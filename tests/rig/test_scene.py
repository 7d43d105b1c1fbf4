"""Tests of the simulated scene renderer."""
import io

import numpy as np
import pytest
import rawpy

from rig.sim.scene import Scene


@pytest.fixture(scope="module")
def obj():
    return Scene.default_object(shape=(120, 160), count=8)


def test_normals_unit_and_mask(obj):
    t = obj.truth()
    norms = np.linalg.norm(t["normals"][t["mask"]], axis=1)
    assert np.allclose(norms, 1.0)
    assert np.isnan(t["depth"][~t["mask"]]).all()


def test_lambert_part_follows_cosine(obj):
    on, off = obj.render_linear(0), obj.render_linear(None)
    assert (on >= off - 1e-6).all() and on.max() > off.max()


def test_cast_shadows_exist_for_oblique_light(obj):
    shadowed = [obj._shadow(k, None).mean() for k in range(obj.count)]
    assert max(shadowed) > 0.0


def test_mosaic_levels_and_dng_roundtrip(obj):
    m = obj.render_mosaic(1)
    assert m.dtype == np.uint16 and m.max() <= 16383
    assert abs(np.median(obj.render_mosaic(None, ambient=False)) - 512) <= 2
    raw = rawpy.imread(io.BytesIO(obj.dng_from_mosaic(m)))
    assert np.array_equal(raw.raw_image, m)


def test_noise_seeded_per_frame(obj):
    assert np.array_equal(obj.render_mosaic(2, shot=0), obj.render_mosaic(2, shot=0))
    assert not np.array_equal(obj.render_mosaic(2, shot=0), obj.render_mosaic(2, shot=1))
