"""Circle refinement on a stack of frames: the sharpest step per ray, not the maximum's."""

import numpy as np
from scipy import ndimage

from calibration.circle import refine_circle, sphere_image
from tests.calibration.test_outline import _discs

TRUE = (100.3, 96.8, 60.4)
SHAPE = (200, 210)


def _frames():
    """(2, H, W): a dim frame with a sharp limb all round, and a bright one whose lower limb
    mirrors a lamp, its glow spreading 4 px past the outline, as a chrome limb's can."""
    sharp = ndimage.gaussian_filter(_discs(SHAPE, [TRUE], 0.4, 0.02), 0.7)
    cx, cy, r = TRUE
    glow = ndimage.gaussian_filter(_discs(SHAPE, [(cx, cy, r + 4)], 1.0, 0.02), 3.0)
    glow[: int(cy)] = 0.02   # the lamp lights the lower half only
    return np.stack([sharp, glow]).astype(np.float32)


def test_the_sharpest_step_per_ray_is_not_pulled_out_by_a_bright_soft_limb():
    frames = _frames()
    start = np.add(TRUE, (3.0, -2.5, 2.0))
    on_max = refine_circle(sphere_image(frames), start)
    on_frames = refine_circle(frames, start)
    # the maximum keeps the glow's outer edge on the lower half: the centre sinks, the radius grows
    assert on_max.cy - TRUE[1] > 1.0 and on_max.r - TRUE[2] > 1.0, on_max
    assert np.allclose(on_frames.params, TRUE, atol=0.1), on_frames
    assert on_frames.inliers > 0.95 and on_frames.method == "fit"


def test_one_frame_is_refined_as_an_image():
    frames = _frames()
    start = np.add(TRUE, (2.0, 2.0, -1.5))
    a, b = refine_circle(frames[0], start), refine_circle(frames[:1], start)
    assert np.allclose(a.params, TRUE, atol=0.1)
    assert np.array_equal(a.params, b.params) and a.inliers == b.inliers


def test_a_seed_pixels_off_is_pulled_in_on_the_frames():
    # 9 px off is outside the per-frame search band; the maximum's pass brings it in first
    frames = _frames()
    found = refine_circle(frames, np.add(TRUE, (9.0, 0.0, 0.0)))
    assert np.allclose(found.params, TRUE, atol=0.1), found
