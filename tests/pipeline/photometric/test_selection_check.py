"""The wide layout's darkest-fraction rule, checked on the images: kept where the darkest lights
determine the normals (a dome), replaced by the robust selection where they do not (a narrow cone
with two stray lights, whose spread passes for wide)."""

import numpy as np

from pipeline.experiments.synthetic import hemisphere_lights
from pipeline.photometric import estimate_normals
from pipeline.photometric.selection import DARKEST_LEVERAGE_MAX, light_spread_deg
from tests.pipeline.tiny_session import sphere


def _ring(count, polar_deg, phase=0.0):
    azimuth = np.linspace(0, 2 * np.pi, count, endpoint=False) + phase
    polar = np.radians(polar_deg)
    return np.stack([np.sin(polar) * np.cos(azimuth), np.sin(polar) * np.sin(azimuth),
                     np.full(count, np.cos(polar))], axis=1)


def _images(lights, seed=0):
    normals, mask = sphere(48)
    noise = np.random.default_rng(seed).normal(0, 0.003, (len(lights),) + mask.shape)
    return normals, mask, np.stack([np.clip(normals @ l, 0, None) * 0.8 * mask for l in lights]) + noise * mask


def _error(result, normals, mask):
    return np.degrees(np.arccos(np.clip(np.sum(result.normals[mask] * normals[mask], axis=1), -1, 1))).mean()


def test_a_narrow_cone_with_two_stray_lights_gets_the_robust_selection():
    lights = np.vstack([_ring(4, 12), _ring(4, 22, 0.4), _ring(2, 58, 0.3)])
    assert light_spread_deg(lights) > 45   # the layout alone calls it wide
    normals, mask, images = _images(lights)
    result = estimate_normals(images, lights, mask)
    check = result.options["selection_check"]
    assert result.options["selection"] == "robust" and check["verdict"].startswith("robust")
    assert check["darkest_leverage"] > DARKEST_LEVERAGE_MAX
    darkest = estimate_normals(images, lights, mask, selection="darkest", t_low=0.35, t_shadow=0.02,
                               shared_shape=False)
    assert _error(result, normals, mask) < 0.7 * _error(darkest, normals, mask)
    # an explicit choice is not second-guessed
    assert "selection_check" not in darkest.options


def test_a_dome_keeps_the_darkest_fraction_rule():
    lights = hemisphere_lights(16, seed=0, min_elevation_deg=20)
    _, mask, images = _images(lights, seed=1)
    result = estimate_normals(images, lights, mask)
    assert result.options["selection"] == "darkest"
    assert result.options["selection_check"]["verdict"] == "darkest"
