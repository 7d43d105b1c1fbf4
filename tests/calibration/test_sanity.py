"""Sphere outlines given by hand that cannot be a sphere's are refused with their figures."""

import numpy as np
import pytest

from calibration.circle import Circle, circle_from_mask
from calibration.sanity import check_given_circle, check_highlights_inside, check_mask_disc
from calibration.sphere import calibrate_sphere
from pipeline.core.errors import InputError

from .render import render_chrome
from .test_sphere import _lights

CIRCLE = (118.3, 97.6, 70.2)


def _disc(shape, cx, cy, r, stretch=1.0):
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]]
    return ((xx - cx) / (r * stretch)) ** 2 + ((yy - cy) / r) ** 2 <= 1


@pytest.mark.parametrize("r", [8, 20, 100, 300])
def test_rasterised_discs_pass(r):
    mask = _disc((2 * r + 21, 2 * r + 23), r + 10.3, r + 9.6, r)
    check_mask_disc(mask, circle_from_mask(mask))


@pytest.mark.parametrize("stretch, shape", [(1.2, "ellipse"), (1.0, "square")])
def test_masks_that_are_not_discs_are_refused_with_the_figures(stretch, shape):
    mask = _disc((200, 240), 120, 100, 60, stretch) if shape == "ellipse" else np.zeros((200, 240), bool)
    if shape == "square":
        mask[40:160, 60:180] = True
    with pytest.raises(InputError, match=r"sphere mask: blob 0 at .* is not a disc: its outline is [\d.]+ px rms "
                                         r"from the best circle of radius [\d.]+ px \([\d.]+ %.*covers \d+ %"):
        check_mask_disc(mask, circle_from_mask(mask))


def test_the_stage_refuses_an_object_mask_given_as_the_spheres():
    frames = render_chrome(_lights(5))
    blob = np.zeros(frames.shape[1:], bool)
    blob[40:150, 60:180] = True   # a box around the sphere, as an object's mask would be
    with pytest.raises(InputError, match="is not a disc"):
        calibrate_sphere(frames, mask=blob)
    disc = _disc(frames.shape[1:], *CIRCLE)
    assert calibrate_sphere(frames, mask=disc).directions.shape == (5, 3)


def test_a_circle_the_frames_contradict_is_refused():
    frames = render_chrome(_lights(5))
    check_given_circle(frames, Circle(*CIRCLE))
    with pytest.raises(InputError, match=r"circle \(138\.3, 97\.6\) r 70\.2: the frames show the sphere's outline at "
                                         r"\(11[78]\.\d, 9[78]\.\d\)"):
        calibrate_sphere(frames, circle=(CIRCLE[0] + 20, CIRCLE[1], CIRCLE[2]))


def test_a_highlight_outside_the_given_outline_is_refused():
    lights = _lights(5)
    frames = render_chrome(lights)
    background = np.median(frames, axis=0)
    check_highlights_inside(frames, background, Circle(*CIRCLE))
    # a circle 60 px to the right of the sphere (on a dark limb nothing contradicts it): the
    # highlights of the lights from the left lie outside it
    shifted = Circle(CIRCLE[0] + 60, CIRCLE[1], CIRCLE[2])
    with pytest.raises(InputError, match=r"2 highlight\(s\) outside the sphere \(178\.3, 97\.6\) r 70\.2 \(given\): "
                                         r"frame 0 at \(103\.\d, 89\.\d\), 7\d\.\d px from the centre; frame 3 at"):
        check_highlights_inside(frames, background, shifted)
