"""Doubtful lights are flagged with a reason, never returned as silently wrong directions."""

import numpy as np
import pytest

from calibration.sphere import calibrate_sphere
from tests.calibration.render import render_chrome

CIRCLE = (118.3, 97.6, 70.2)


def _direction(polar_deg, azimuth_deg=30.0):
    t, p = np.radians(polar_deg), np.radians(azimuth_deg)
    return [np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)]


GOOD = [_direction(20, 10), _direction(35, 140), _direction(30, 250)]


def test_overexposed_blob_is_flagged():
    frames = render_chrome(GOOD)
    frames[1] = render_chrome([GOOD[1]], gain=3000.0, sigma_deg=4.0)[0]
    result = calibrate_sphere(frames, circle=CIRCLE)
    assert set(result.flags) == {1} and "overexposed" in result.flags[1]


@pytest.mark.parametrize("polar", [160.0, 170.0])
def test_highlight_on_the_rim_is_flagged(polar):
    frames = render_chrome(GOOD + [_direction(polar)])
    result = calibrate_sphere(frames, circle=CIRCLE)
    assert 3 in result.flags and ("rim" in result.flags[3] or "no highlight" in result.flags[3])
    assert set(result.flags) == {3}


def test_one_sphere_doubting_a_light_keeps_the_other_spheres_direction():
    truth = np.array(GOOD)
    frames = render_chrome(truth)
    frames2 = frames.copy()
    frames2[0] = np.maximum(frames2[0], render_chrome([_direction(40, 200)])[0])   # two highlights
    both = np.concatenate([frames, frames2], axis=2)                             # spheres side by side
    circles = [CIRCLE, (CIRCLE[0] + frames.shape[2], CIRCLE[1], CIRCLE[2])]
    result = calibrate_sphere(both, circle=circles)
    assert not result.flags and "two highlights" in result.sphere_flags[1][0]
    err = np.degrees(np.arccos(np.clip((result.directions * truth).sum(1), -1, 1)))
    assert err.max() < 1.0
