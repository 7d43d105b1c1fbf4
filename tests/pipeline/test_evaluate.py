"""Evaluation against ground truth: angular errors, light angles, depth fits, eval.yaml, CLI."""

import json

import numpy as np
import pytest
import yaml

from pipeline.cli import main
from pipeline.evaluate import angular_error, depth_error, error_stats, evaluate_session, light_errors
from pipeline.core.imageio import read_image, write_image, write_mask
from pipeline.core.lightsio import LightSet, write_lights_yaml
from pipeline.core.session import Session


def rotate_x(vectors, degrees):
    a = np.radians(degrees)
    rot = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    return vectors @ rot.T


def random_normals(shape, seed=0):
    rng = np.random.default_rng(seed)
    n = rng.normal(size=shape + (3,))
    n[..., 2] = np.abs(n[..., 2]) + 0.5
    return n / np.linalg.norm(n, axis=-1, keepdims=True)


def test_angular_error_of_known_rotation():
    n = random_normals((20, 30))
    err = angular_error(n, rotate_x(n, 7.0) * 3.0)  # length must not matter
    # a rotation by 7 deg about x moves no normal by more than 7 deg, those in the y-z plane by 7
    assert np.nanmax(err) <= 7.0 + 1e-6 and np.nanmin(err) >= 0
    assert np.nanmax(err[np.abs(n[..., 0]) < 0.05]) > 6.99
    axis_free = np.zeros((1, 2, 3))
    axis_free[0, :, :] = [[0, 0, 1], [0, 0.6, 0.8]]
    np.testing.assert_allclose(angular_error(axis_free, rotate_x(axis_free, 7.0)), 7.0, atol=1e-9)
    mask = np.zeros((20, 30), bool)
    mask[:5] = True
    assert np.isnan(angular_error(n, n, mask)[~mask]).all()
    assert np.nanmax(angular_error(n, n, mask)) < 1e-6


def test_error_stats_fractions_and_percentiles():
    errors = np.array([1.0, 2.0, 6.0, 12.0, 30.0, np.nan])
    stats = error_stats(errors)
    assert stats["pixels"] == 5
    assert stats["mean_deg"] == pytest.approx(10.2)
    assert stats["median_deg"] == pytest.approx(6.0)
    assert stats["under_5_deg"] == pytest.approx(0.4)
    assert stats["under_10_deg"] == pytest.approx(0.6)
    assert stats["under_20_deg"] == pytest.approx(0.8)
    assert stats["p90_deg"] == pytest.approx(np.percentile([1, 2, 6, 12, 30], 90))


def test_light_and_depth_errors():
    dirs = random_normals((6,), seed=3)
    result = light_errors(rotate_x(dirs, 2.0), dirs)
    assert 0 < result["mean_deg"] <= 2.0 + 1e-9 and result["max_deg"] <= 2.0 + 1e-9
    assert len(result["per_light_deg"]) == 6
    truth = np.linspace(1, 5, 100).reshape(10, 10)
    truth[0, 0] = np.nan
    ortho = depth_error(truth - 7.5 + 0.1 * (np.arange(100).reshape(10, 10) % 2), truth)
    assert ortho["fit"] == "offset" and ortho["mean_abs"] == pytest.approx(0.05, abs=1e-3)
    persp = depth_error(truth / 4.0, truth, "perspective")
    assert persp["scale"] == pytest.approx(4.0) and persp["mean_abs"] < 1e-9


def make_scored_session(root):
    """Estimated normals = truth rotated by 3 deg (left half) and 12 deg (right half)."""
    session = Session.create(root)
    truth = random_normals((16, 20), seed=1)
    truth = truth * np.array([0, 1, 1.0])
    truth /= np.linalg.norm(truth, axis=-1, keepdims=True)
    estimate = np.concatenate([rotate_x(truth[:, :10], 3.0), rotate_x(truth[:, 10:], 12.0)], axis=1)
    write_image(session.path("truth/normals.exr"), truth.astype(np.float32))
    mask = np.ones((16, 20), bool)
    mask[0] = False
    write_mask(session.path("truth/mask.png"), mask)
    write_image(session.path("normals/normals.exr"), estimate.astype(np.float32))
    write_mask(session.path("normals/mask.png"), np.ones((16, 20), bool))
    dirs = random_normals((5,), seed=2)
    write_lights_yaml(session.path("truth/lights.yaml"), LightSet(dirs))
    write_lights_yaml(session.path("calibration/lights.yaml"), LightSet(rotate_x(dirs, 1.0)))
    for key, rel in (("normals", "truth/normals.exr"), ("mask", "truth/mask.png"),
                     ("lights", "truth/lights.yaml")):
        session.set_truth(key, rel)
    return session


def test_evaluate_session_scores_and_files(tmp_path):
    session = make_scored_session(tmp_path / "s")
    result = evaluate_session(session)
    normals = result["normals"]
    assert normals["pixels"] == 15 * 20
    assert normals["mean_deg"] == pytest.approx(7.5, abs=0.05)
    assert normals["under_5_deg"] == pytest.approx(0.5) and normals["under_20_deg"] == 1.0
    assert 0 < result["lights"]["mean_deg"] <= 1.0 + 1e-6
    assert "depth" not in result
    saved = yaml.safe_load(session.path("normals/eval.yaml").read_text())
    assert saved["normals"]["median_deg"] == pytest.approx(normals["median_deg"])
    error_map = read_image(session.path("normals/error.png"))
    assert error_map.shape == (16, 20, 3)
    assert not error_map[0].any() and error_map[1:].any()
    assert not np.allclose(error_map[5, 2], error_map[5, 15])


def test_eval_cli_json(tmp_path, capsys):
    session = make_scored_session(tmp_path / "s")
    assert main(["eval", str(session.root), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert set(data) == {"normals", "lights"}
    assert data["normals"]["mean_deg"] == pytest.approx(7.5, abs=0.05)
    empty = Session.create(tmp_path / "empty")
    assert main(["eval", str(empty.root), "--json"]) == 1   # nothing evaluated is not a pass
    assert json.loads(capsys.readouterr().out) == {}
    assert main(["eval", str(tmp_path / "nope")]) == 1
    assert "no such session folder" in capsys.readouterr().err


def test_light_scores_leave_flagged_lights_out_and_score_intensities_and_positions():
    from pipeline.evaluate import intensity_errors, position_errors

    true = np.array([[1.0, 2.0, 3.0], [2.0, 2.0, 2.0]])
    assert intensity_errors(true * 3.0, true)["max_pct"] < 1e-9
    off = true * 3.0
    off[1, 0] *= 1.05
    scores = intensity_errors(off, true)
    assert scores["worst_light"] == 1 and 4.0 < scores["max_pct"] < 6.0
    positions = np.array([[0.0, 0.0, 100.0], [50.0, 0.0, 100.0]])
    moved = positions + np.array([[0.0, 0.0, 2.0], [0.0, 0.0, 0.0]])
    result = position_errors(moved, positions)
    assert abs(result["max_pct"] - 2.0) < 1e-9 and abs(result["distance_max_pct"] - 2.0) < 1e-9


def test_imported_lights_are_not_scored_against_themselves(tmp_path, capsys):
    session = make_scored_session(tmp_path / "s")
    session.manifest["lights"]["source"] = "imported"  # as the importers record it
    session.save()
    assert main(["eval", str(session.root)]) == 0
    out = capsys.readouterr().out
    assert "lights: imported, not evaluated" in out and "mean 0.000" not in out
    result = evaluate_session(Session.open(session.root))
    assert result["lights"]["evaluated"] is False and "mean_deg" not in result["lights"]


def test_error_map_has_a_fixed_scale_of_30_degrees_unless_told(tmp_path):
    session = make_scored_session(tmp_path / "s")  # errors of 3 and 12 degrees
    result = evaluate_session(session)
    assert result["normals"]["error_map_max_deg"] == 30.0
    low = evaluate_session(session, max_deg=12.0)
    assert low["normals"]["error_map_max_deg"] == 12.0
