"""The report's rough edges (issue 34, item 8): clipped curves marked, the grey bars' scale, 96
lights' labels, one intensity, units, and the dark frame's thumbnail."""

import numpy as np

from pipeline.core.imageio import write_image
from pipeline.core.lightsio import LightSet
from pipeline.report.charts import error_by_observations
from pipeline.report.lights import hemisphere_svg, light_rows
from pipeline.report.sections import scores_section
from pipeline.report.stage import _thumbnails
from pipeline.core.session import Session


def test_clipped_curves_are_marked_and_the_bars_have_a_scale():
    counts = np.repeat(np.arange(3, 9), 50).reshape(10, 30)
    errors = np.where(counts < 5, 45.0, 5.0)   # few observations: above the 30-degree axis
    svg = error_by_observations([("errors", errors, counts)], 30.0)
    assert svg.count("(above the axis)") == 4   # mean and median at counts 3 and 4
    assert "above 30 deg: drawn at the top" in svg
    assert "the tallest is 16.7 % of the pixels" in svg
    plain = error_by_observations([("errors", np.full((10, 30), 5.0), counts)], 30.0)
    assert "above the axis" not in plain and "drawn at the top" not in plain


def test_ninety_six_lights_do_not_write_every_label_and_one_intensity_is_one_value():
    rng = np.random.default_rng(0)
    dirs = rng.normal(size=(96, 3)) * [1, 1, 0] + [0, 0, 1.2]
    svg = hemisphere_svg(LightSet(dirs))
    written = svg.count('font-size="8">') - 3   # the three ring labels
    assert 10 < written < 96 and f"{96 - written} crowded labels left out" in svg
    assert "every light's intensity is 1 (mean of channels)" in svg and "linearGradient" not in svg
    assert "crowded" not in hemisphere_svg(LightSet(dirs[:6], intensities=np.arange(1, 7)))


def test_units_of_light_positions_and_depth_errors_are_named():
    lights = LightSet(np.tile([0.0, 0.0, 1.0], (3, 1)), extra={"distance": [1.0, 2.0, 3.0], "ray_miss": [0.1] * 3,
                                                             "residual_deg": [0.2] * 3, "position_unit": "px"})
    header, _ = light_rows(lights, {})
    assert "distance (px)" in header and "ray_miss (px)" in header and "residual_deg (deg)" in header
    html = scores_section({"depth": {"mean_abs": 1.5, "median_abs": 1.0, "rms": 2.0, "fit": "scale", "scale": 3.0}})
    assert "mean_abs (ground truth&#x27;s unit)" in html or "mean_abs (ground truth's unit)" in html


def test_a_dark_frames_thumbnail_is_grey_and_dark(tmp_path):
    session = Session.create(tmp_path / "s")
    src = tmp_path / "f.png"
    write_image(src, np.zeros((8, 8, 3), np.float32))
    dark = session.add_frame("dark", source=src, save=False)
    lit = session.add_frame("object", source=src, light=0, frame_id="object_000", save=False)
    session.save()
    noise = np.random.default_rng(1).normal(0.002, 0.001, (40, 40, 3)).astype(np.float32)
    write_image(session.linear_path(dark), noise)
    write_image(session.linear_path(lit), np.full((40, 40, 3), 0.6, np.float32))
    written = {}

    def write(rel, rgb):
        written[rel] = rgb
        return rel
    groups = dict(_thumbnails(session, write))
    shown = written[f"report/frames/{dark['id']}.png"]
    assert (shown[:, :, 0] == shown[:, :, 1]).all() and shown.mean() < 40
    assert "on the object frames' scale" in groups["dark"][0].caption
