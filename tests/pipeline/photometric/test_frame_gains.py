"""Each frame's brightness checked against its light's intensity (pipeline.photometric.frame_gains)."""

import numpy as np
import pytest

from pipeline.core.errors import InputError
from pipeline.photometric import PointLights, estimate_normals
from pipeline.photometric.engine import gatherer
from pipeline.photometric.frame_gains import GAIN_TOL, check_frames
from pipeline.photometric.selection import resolve_selection

from tests.pipeline.photometric.ps_synthetic import angular_error_deg, cook_torrance_images, hemisphere_lights, sphere_normals

NARROW = hemisphere_lights(48, seed=3, min_elevation_deg=48)   # a DiLiGenT-like cone: robust selection
DOME = hemisphere_lights(12, seed=1, min_elevation_deg=20)     # wide: the paper's darkest rule


def scene(lights, size=80, roughness=0.3):
    normals, mask = sphere_normals(size)
    images = cook_torrance_images(normals, mask, lights, roughness=roughness, noise=0.002)
    return images, normals, mask


def check(images, lights, mask, **kwargs):
    k = images.shape[0]
    return check_frames(gatherer(images.reshape(k, -1), None, lights), np.flatnonzero(mask),
                        resolve_selection(lights, {}), **kwargs)


def error(result, normals, mask):
    return float(angular_error_deg(result.normals, normals, mask).mean())


@pytest.mark.parametrize("lights", [NARROW, DOME], ids=["narrow", "dome"])
def test_right_intensities_are_left_alone_and_the_solve_is_unchanged(lights):
    images, _, mask = scene(lights)
    found = check(images, lights, mask)
    assert found.verdict == "consistent" and found.applied() is None
    assert np.nanmax(np.abs(found.deviation)) < GAIN_TOL / 3
    checked = estimate_normals(images, lights, mask)
    unchecked = estimate_normals(images, lights, mask, frame_gains=False)
    assert checked.options["frame_check"]["verdict"] == "consistent"
    assert unchecked.options["frame_check"]["verdict"] == "not checked"
    np.testing.assert_array_equal(checked.normals, unchecked.normals)


def test_a_dim_frame_under_a_dome_is_found_rescaled_and_its_damage_undone():
    images, normals, mask = scene(DOME)
    clean = error(estimate_normals(images, DOME, mask), normals, mask)
    dim = images.copy()
    dim[2] *= 0.6
    checked = estimate_normals(dim, DOME, mask)
    unchecked = estimate_normals(dim, DOME, mask, frame_gains=False)
    record = checked.options["frame_check"]
    assert record["verdict"] == "rescaled" and set(record["rescaled"]) == {2}
    assert abs(record["rescaled"][2] - 0.6) < 0.02 and not record["uncalibrated"]
    # the darkest-fraction rule has no rejection: one dim frame of 12 costs degrees
    assert error(unchecked, normals, mask) > clean + 1.0
    assert error(checked, normals, mask) < clean + 0.1


def test_several_frames_off_under_a_narrow_cone_are_each_measured():
    images, normals, mask = scene(NARROW)
    truth = {3: 0.7, 10: 1.3, 20: 1.5}
    off = images.copy()
    for k, gain in truth.items():
        off[k] *= gain
    found = check(off, NARROW, mask)
    assert found.verdict == "rescaled" and set(found.rescaled) == set(truth)
    for k, gain in truth.items():
        assert abs(found.gains[k] / gain - 1) < 0.03, (k, found.gains[k])
    assert np.all(found.gains[np.setdiff1d(np.arange(len(NARROW)), list(truth))] == 1.0)


def test_estimating_every_frame_recovers_gains_up_to_their_median():
    images, _, mask = scene(NARROW)
    truth = np.random.default_rng(4).uniform(0.8, 1.25, len(NARROW))
    found = check(images * truth[:, None, None], NARROW, mask, mode=True)
    assert found.verdict == "estimated" and found.rescaled.size == len(NARROW)
    assert abs(np.median(np.log(found.gains))) < 1e-9
    relative = truth / np.exp(np.median(np.log(truth)))
    # what the images cannot tell is a ramp across the lights; within a narrow cone it is small
    assert np.median(np.abs(np.log(found.gains / relative))) < 0.03


def test_a_frame_whose_ratios_spread_widely_is_not_rescaled_for_a_small_shift():
    # a frame under which the object departs from Lambert shifts and spreads its ratios: the
    # shift alone (above GAIN_TOL) is no evidence of a wrong intensity
    images, _, mask = scene(NARROW)
    rng = np.random.default_rng(0)
    noisy = images.copy()
    noisy[5] *= np.exp(rng.normal(0.2, 0.6, images.shape[1:]))
    assert check(noisy, NARROW, mask).applied() is None
    assert 5 in check(noisy, NARROW, mask, significance=0.0).rescaled


def test_most_frames_off_reads_as_uncalibrated_intensities():
    images, _, mask = scene(NARROW)
    truth = np.random.default_rng(2).uniform(0.4, 2.5, len(NARROW))
    record = estimate_normals(images * truth[:, None, None], NARROW, mask).options["frame_check"]
    assert record["verdict"] == "rescaled" and record["uncalibrated"]


def test_a_frame_lighting_too_few_pixels_is_not_judged():
    images, _, mask = scene(NARROW)
    images = images.copy()
    images[7] = 0.0
    found = check(images, NARROW, mask)
    assert np.isnan(found.deviation[7]) and 7 not in found.rescaled and found.gains[7] == 1.0


def test_near_lights_are_not_checked_unless_asked_and_a_bad_mode_is_refused():
    images, _, mask = scene(NARROW, size=48)
    near = PointLights(NARROW * 50.0, mask.shape)
    assert estimate_normals(images, near, mask, method="lambert").options["frame_check"]["verdict"] == "not checked"
    with pytest.raises(InputError, match="frame_gains"):
        estimate_normals(images, NARROW, mask, frame_gains="yes")


def test_the_stage_names_the_rescaled_frame_and_can_be_told_to_trust_the_intensities(tmp_path, capsys):
    from pipeline.cli import main
    from pipeline.decode import decode_session
    from pipeline.core.session import Session
    from tests.pipeline.photometric.ps_synthetic import import_stack

    images, _, mask = scene(DOME, size=64)
    images = images / images.max() * 0.9
    images[4] *= 0.6
    root = import_stack(tmp_path, "s", images, mask, DOME)
    decode_session(Session.open(root), progress=False)
    assert main(["normals", str(root)]) == 0
    printed = capsys.readouterr().out
    record = Session.open(root).stage("normals")
    frame = Session.open(root).stage_frames("object")[4]["id"]
    assert list(record["frame_gains"]["rescaled"]) == [frame]
    assert abs(record["frame_gains"]["rescaled"][frame] - 0.6) < 0.03
    assert "1 frame(s) rescaled to the others' brightness" in printed
    assert f"warning: frame(s) {frame} (0.6" in printed and "lights.yaml" in printed
    assert main(["normals", str(root), "--frame-gains", "off"]) == 0
    record = Session.open(root).stage("normals")
    assert record["params"]["frame_gains"] is False and record["frame_gains"]["verdict"] == "not checked"
    assert not any("rescaled" in w for w in record["warnings"])


@pytest.mark.parametrize("lights", [NARROW, DOME], ids=["narrow", "dome"])
def test_two_swapped_lights_are_found_and_right_ones_are_not(lights):
    images, _, mask = scene(lights)
    right = check(images, lights, mask).directions
    assert right["off"] == {} and right["swapped"] == [] and right["max_angle"] < 2.0
    swapped = lights.copy()
    swapped[[1, 6]] = swapped[[6, 1]]
    found = check(images, swapped, mask).directions
    assert set(found["off"]) == {1, 6} and found["swapped"] == [[1, 6]]
    # each estimate is the frame's true light
    for k, true in ((1, lights[1]), (6, lights[6])):
        assert np.degrees(np.arccos(min(np.dot(found["off"][k]["estimated"], true), 1.0))) < 1.0


def test_a_moved_light_a_repeated_frame_and_a_dark_one_are_each_named():
    from pipeline.photometric.summary import normals_warnings

    images, _, mask = scene(NARROW)
    moved = NARROW.copy()
    moved[9] = NARROW[9] + np.array([0.25, 0.0, 0.0])
    moved[9] /= np.linalg.norm(moved[9])
    wrong = images.copy()
    wrong[20] = wrong[19]        # the camera gave the last frame again
    wrong[30] *= 0.01            # a light that did not fire
    directions = estimate_normals(wrong, moved, mask).options["frame_check"]["directions"]
    assert set(directions["off"]) == {9, 20} and directions["swapped"] == [] and directions["dark"] == [30]
    assert "like" not in directions["off"][9] and directions["off"][20]["like"] == 19
    named = {"off": {"f09": directions["off"][9], "f20": dict(directions["off"][20], like="f19")},
             "swapped": [], "dark": ["f30"]}
    warnings = normals_warnings({"ok": 1}, len(NARROW), {}, {"directions": named})
    assert warnings[0].startswith("frame(s) f30: dark at almost every pixel") and "did the light fire" in warnings[0]
    assert warnings[1].startswith("frame f09: by the images its light is ") and "degrees from where" in warnings[1]
    assert warnings[2].startswith("frame f20: by the images its light is frame f19's")
    pair = {"directions": {"off": {"a": directions["off"][9], "b": directions["off"][9]}, "swapped": [["a", "b"]]}}
    (warning,) = normals_warnings({"ok": 1}, len(NARROW), {}, pair)
    assert warning.startswith("frames a and b look swapped")
