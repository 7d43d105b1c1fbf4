"""Held-out-light prediction (pipeline.photometric.prediction) and its place in the normals stage,
psrig eval and the report."""

import json

import numpy as np
import pytest

from pipeline.cli import main
from pipeline.experiments.synthetic import hemisphere_lights, sphere_normals
from pipeline.photometric import normals_session
from pipeline.photometric.prediction import (MIN_LIGHTS, held_out_prediction, light_folds, prediction_line,
                                             read_prediction, render)
from pipeline.core.session import Session
from tests.pipeline.tiny_session import make_session


def decoded(tmp_path):
    """The tiny session (8 Lambertian lights) decoded, ready for the normals stage."""
    session = make_session(tmp_path)
    assert main(["decode", str(session.root)]) == 0
    return Session.open(session.root)


def glossy_sphere(count=24, size=64, seed=3):
    """A sphere whose rho grows with n . h (a broad lobe Lambert cannot follow), rendered by the
    formula written out here (not the module's :func:`render`)."""
    normals, mask = sphere_normals(size)
    lights = hemisphere_lights(count, seed=seed, min_elevation_deg=30)
    h = lights + np.array([0.0, 0.0, 1.0])
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    n = normals[mask]
    x = n @ h.T
    rho = 0.4 + 0.9 * x ** 2
    images = np.zeros((count,) + mask.shape)
    images[:, mask] = (0.6 * rho * np.maximum(n @ lights.T, 0.0)).T
    return images.astype(np.float32), mask, lights


def test_biquadratic_predicts_held_out_frames_of_a_glossy_sphere_better_than_lambert():
    images, mask, lights = glossy_sphere()
    # every non-shadowed observation (t_low 1): the robust default keeps too few of 24 to fit 9
    # coefficients and falls back to Lambert; both fits take the option alike
    found = held_out_prediction(images, None, lights, mask, folds=4, options={"t_low": 1.0})
    assert found["verdict"] == "checked" and found["folds"] == 4
    overall = found["overall"]
    assert overall["biquadratic_pct"] < 2.0 < overall["lambert_pct"]
    assert len(found["lights"]) == len(lights)
    assert {e["fold"] for e in found["lights"]} == {0, 1, 2, 3}
    worst = found["lights"][found["worst_light"]]
    assert worst["biquadratic_pct"] == max(e["biquadratic_pct"] for e in found["lights"])
    rows, cols = np.nonzero(mask)
    assert found["images"]["captured"].shape == (np.ptp(rows) + 1, np.ptp(cols) + 1)
    line = prediction_line(found)
    assert line.startswith("held-out lights: biquadratic predicts within ") and "Lambert" in line


def test_a_sample_grid_caps_the_pixels():
    images, mask, lights = glossy_sphere(count=12, size=96)
    found = held_out_prediction(images, None, lights, mask, folds=3, sample_pixels=1500)
    assert found["pixels"] <= 1500 and found["stride"] >= 2
    assert found["images"]["captured"].shape[0] < mask.shape[0]


def test_too_few_lights_are_refused_with_the_reason():
    images, mask, lights = glossy_sphere(count=MIN_LIGHTS - 1)
    found = held_out_prediction(images, None, lights, mask)
    assert found["verdict"] == "not checked" and "too few" in found["reason"]
    assert "not checked" in prediction_line(found)


def test_folds_are_interleaved_by_azimuth():
    azimuth = np.radians(np.arange(0, 360, 30))
    lights = np.stack([np.cos(azimuth), np.sin(azimuth), np.ones_like(azimuth)], 1)
    fold = light_folds(lights[::-1], 4)
    assert np.bincount(fold).tolist() == [3, 3, 3, 3]
    # neighbours in azimuth fall into different folds
    order = np.argsort(np.arctan2(lights[::-1, 1], lights[::-1, 0]))
    assert np.all(fold[order][:-1] != fold[order][1:])


def test_render_matches_the_paper_order_of_the_coefficients():
    n = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8]])
    lights = np.array([[0.0, 0.6, 0.8]])
    params = np.zeros((2, 9))
    params[:, 2] = 1.0          # C: x^2
    params[:, 8] = 0.5          # I: 1
    h = (lights[0] + [0, 0, 1]) / np.linalg.norm(lights[0] + [0, 0, 1])
    x = n @ h
    expected = 2.0 * (x ** 2 + 0.5) * np.maximum(n @ lights[0], 0)
    assert np.allclose(render(n, [2.0, 2.0], lights, params)[:, 0], expected)


def test_the_normals_stage_records_it_and_eval_and_the_report_show_it(tmp_path, capsys):
    session = decoded(tmp_path)      # 8 Lambertian lights
    record = normals_session(session, show_progress=False)
    assert record["prediction"]["verdict"] == "checked"
    assert "normals/prediction.yaml" in record["outputs"] and "normals/prediction.exr" in record["outputs"]
    found = read_prediction(Session.open(session.root))
    assert len(found["lights"]) == 8 and found["lights"][0]["frame"]
    # a Lambertian object: both models predict it closely
    assert found["overall"]["lambert_pct"] < 3.0 and found["overall"]["biquadratic_pct"] < 3.0
    capsys.readouterr()
    assert main(["eval", str(session.root), "--json"]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert printed["prediction"]["overall"] == found["overall"]
    assert main(["report", str(session.root)]) == 0
    page = session.path("report/index.html").read_text()
    assert "held-out lights: biquadratic predicts within" in page
    assert session.path("report/prediction/difference.png").is_file()


def test_holdout_folds_zero_skips_it_and_one_is_refused(tmp_path):
    session = decoded(tmp_path)
    normals_session(session, show_progress=False)
    assert read_prediction(Session.open(session.root)) is not None
    record = normals_session(session, show_progress=False, holdout_folds=0)
    assert "prediction" not in record and record["params"]["holdout_folds"] == 0
    # the earlier run's files are gone: they were not of this fit
    assert read_prediction(Session.open(session.root)) is None
    assert not session.path("normals/prediction.exr").exists()
    from pipeline.core.errors import StageError
    with pytest.raises(StageError, match="holdout-folds"):
        normals_session(session, show_progress=False, holdout_folds=1, force=True)


def test_near_lights_are_scored_with_their_per_pixel_directions_and_falloff():
    from pipeline.photometric import PointLights

    normals, mask = sphere_normals(48)
    directions = hemisphere_lights(16, seed=4, min_elevation_deg=35)
    lights = PointLights(directions * 150.0, mask.shape)
    flat = np.flatnonzero(mask)
    towards, falloff = lights.at(flat)                                   # (N, K, 3), (N, K)
    n = normals.reshape(-1, 3)[flat]
    images = np.zeros((16,) + mask.shape, np.float32)
    images.reshape(16, -1)[:, flat] = (0.5 * falloff * np.maximum(np.einsum("nc,nkc->nk", n, towards), 0)).T
    near = held_out_prediction(images, None, lights, mask, folds=4)
    assert near["verdict"] == "checked"
    assert near["overall"]["lambert_pct"] < 2.0 and near["overall"]["biquadratic_pct"] < 2.0
    # the same images read as distant lights miss the falloff and the directions' spread
    far = held_out_prediction(images, None, directions, mask, folds=4)
    assert far["overall"]["lambert_pct"] > 2 * near["overall"]["lambert_pct"]


def test_the_line_shows_two_decimals_only_when_one_would_hide_the_difference():
    def found(bq, lam):
        return {"verdict": "checked", "overall": {"biquadratic_pct": bq, "lambert_pct": lam}}

    assert prediction_line(found(6.12, 11.43)) == ("held-out lights: biquadratic predicts within 6.1 % RMS, "
                                                   "Lambert 11.4 %")
    assert prediction_line(found(12.89, 12.92)).endswith("within 12.89 % RMS, Lambert 12.92 %")


def test_a_damaged_prediction_file_is_named_by_eval_and_the_report(tmp_path, capsys):
    session = decoded(tmp_path)
    normals_session(session, show_progress=False)
    session.path("normals/prediction.yaml").write_text("just text\n")
    capsys.readouterr()
    assert main(["eval", str(session.root)]) == 1
    assert "prediction.yaml: not a held-out prediction record" in capsys.readouterr().err
    assert main(["report", str(session.root)]) == 0
    assert "prediction.yaml: not a held-out prediction record" in session.path("report/index.html").read_text()
