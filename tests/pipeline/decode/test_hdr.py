"""pipeline.decode.hdr.merge_exposures: longest unsaturated exposure, scaled to a reference shutter."""

import numpy as np
import pytest

from pipeline.core.errors import InputError
from pipeline.decode.hdr import merge_exposures


def bracket(radiance, shutters, white=1.0):
    """Exposures of ``radiance`` (per second): clipped at white, with their saturation masks."""
    images = np.stack([np.minimum(radiance * t, white) for t in shutters]).astype(np.float32)
    return images, images >= white


def test_each_value_from_the_longest_unsaturated_exposure():
    rng = np.random.default_rng(0)
    radiance = rng.uniform(0, 200, (20, 30, 3))  # up to 200 x white per second
    shutters = [1 / 15, 1 / 60, 1 / 250]          # any order
    images, saturated = bracket(radiance, shutters)
    result = merge_exposures(images, shutters, saturated)
    ref = 1 / 250
    ok = ~result.saturated
    np.testing.assert_allclose(result.image[ok], (radiance * ref)[ok], rtol=1e-5)
    # which exposure: the longest one whose value is below white
    expected = np.where(radiance * (1 / 15) < 1, 0, np.where(radiance * (1 / 60) < 1, 1, 2))
    np.testing.assert_array_equal(result.source, expected)
    assert result.record["reference_shutter"] == pytest.approx(ref)
    assert sum(result.record["values_from"].values()) == radiance.size


def test_saturated_in_every_exposure_is_flagged_not_used():
    radiance = np.array([[10.0, 1e6]])  # the second pixel clips even at 1/1000 s
    shutters = [1 / 1000, 1 / 30]
    images, saturated = bracket(radiance, shutters)
    result = merge_exposures(images, shutters, saturated)
    assert result.saturated.tolist() == [[False, True]]
    assert result.image[0, 0] == pytest.approx(10.0 / 1000)
    assert result.image[0, 1] == pytest.approx(1.0)  # the shortest exposure's clipped value
    assert result.record["saturated_in_all"] == 1


def test_reference_shutter_scales_the_result():
    radiance = np.full((4, 4), 3.0)
    images, saturated = bracket(radiance, [0.1, 0.2])
    result = merge_exposures(images, [0.1, 0.2], saturated, reference=0.2)
    np.testing.assert_allclose(result.image, 0.6, rtol=1e-6)
    assert (result.source == 1).all()


@pytest.mark.parametrize("kwargs, message", [
    ({"shutters": [0.1, 0.1]}, "distinct positive"),
    ({"shutters": [0.1]}, "distinct positive"),
    ({"saturated": np.zeros((2, 3, 3), bool)}, "saturated: shape"),
])
def test_bad_input_is_refused(kwargs, message):
    args = {"images": np.zeros((2, 4, 4)), "shutters": [0.1, 0.2],
            "saturated": np.zeros((2, 4, 4), bool), **kwargs}
    with pytest.raises(InputError, match=message):
        merge_exposures(**args)


def test_flags_per_pixel_take_all_of_a_pixels_channels_from_one_exposure():
    rng = np.random.default_rng(1)
    radiance = rng.uniform(0, 20, (30, 40, 3))
    shutters = [1 / 60, 1 / 15]
    images, per_value = bracket(radiance, shutters)
    per_pixel = per_value.any(axis=3)   # as decode's masks: a pixel is saturated in any channel
    result = merge_exposures(list(images), shutters, list(per_pixel))
    assert result.saturated.shape == (30, 40) and result.source.shape == (30, 40)
    expected_source = np.where(per_pixel[1], 0, 1)
    np.testing.assert_array_equal(result.source, expected_source)
    ok = ~result.saturated
    np.testing.assert_allclose(result.image[ok], (radiance / 60)[ok], rtol=1e-5)
    assert result.record["ratios"][0]["measured"] == pytest.approx(4.0, rel=1e-4)


def test_exposures_that_do_not_scale_with_their_shutters_are_refused():
    rng = np.random.default_rng(2)
    radiance = rng.uniform(0, 20, (40, 40))
    images, saturated = bracket(radiance, [1 / 30, 1 / 30])   # the camera kept one shutter time
    with pytest.raises(InputError, match=r"1/15 s is 1.00 x the one at 1/60 s .* its shutter time says 4.00 x"):
        merge_exposures(images, [1 / 60, 1 / 15], saturated, tolerance=0.2)
    result = merge_exposures(images, [1 / 60, 1 / 15], saturated)   # no tolerance: measured, said
    assert result.record["ratios"][0]["measured"] == pytest.approx(1.0, rel=1e-4)


def test_a_dark_bracket_has_no_measured_ratio():
    images = np.zeros((2, 20, 20), np.float32)
    result = merge_exposures(images, [0.1, 0.4], np.zeros((2, 20, 20), bool), tolerance=0.2)
    assert result.record["ratios"] == [{"shutters": [0.1, 0.4], "expected": 4.0, "measured": None, "pixels": 0}]
