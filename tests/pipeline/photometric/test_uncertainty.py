"""The normals' uncertainty map: its linearisation, the map and the 'uncertain' status, what the
stage writes and says, eval's agreement, the PLY's per-vertex quality."""

import numpy as np
import pytest

from pipeline.core.imageio import read_image
from pipeline.core.paths import UNCERTAINTY
from pipeline.photometric import STATUS, estimate_normals, normals_session
from pipeline.photometric.engine import normal_leverage
from pipeline.photometric.summary import normals_summary
from pipeline.photometric.uncertainty import agreement, roc_auc
from tests.pipeline.tiny_session import lights, make_session, sphere


def test_leverage_is_the_linearised_angular_deviation_of_a_lambertian_fit():
    rng = np.random.default_rng(1)
    dirs = lights(12)
    n = np.array([0.3, -0.2, 0.93])
    n /= np.linalg.norm(n)
    noise = 1e-3
    normals = []
    for _ in range(4000):
        obs = dirs @ n + rng.normal(0, noise, len(dirs))
        b = np.linalg.lstsq(dirs, obs, rcond=None)[0]
        normals.append(b / np.linalg.norm(b))
    spread = np.sqrt(np.mean(np.sum((np.array(normals) - n) ** 2, axis=1)))   # radians, small angles
    lev = normal_leverage(n[None, :], np.ones((1, len(dirs))), dirs)[0]
    assert lev * noise == pytest.approx(spread, rel=0.05)
    # fewer lights, or lights closing in on a plane, turn the normal more; coplanar: none
    assert normal_leverage(n[None, :], (np.arange(12) < 6)[None, :].astype(float), dirs)[0] > lev
    flat = np.array([[1.0, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0]])
    assert np.isnan(normal_leverage(n[None, :], np.ones((1, 4)), flat)[0])
    per_pixel = normal_leverage(np.tile(n, (3, 1)), np.ones((3, 12)), np.broadcast_to(dirs, (3, 12, 3)))
    np.testing.assert_allclose(per_pixel, lev, rtol=1e-5)


def test_map_is_nan_off_the_normals_and_flags_uncertain_pixels_without_dropping_them():
    normals, mask = sphere()
    dirs = lights(12)
    rng = np.random.default_rng(0)
    images = np.stack([np.clip(normals @ l, 0, None) * 0.8 * mask for l in dirs])
    images += rng.normal(0, 0.002, images.shape) * mask
    result = estimate_normals(images, dirs, mask)
    unc = result.uncertainty
    assert unc.shape == mask.shape and unc.dtype == np.float32
    has = np.linalg.norm(result.normals, axis=2) > 0
    assert np.isfinite(unc[has]).all() and np.isnan(unc[~has]).all() and (unc[has] > 0).all()
    assert STATUS["uncertain"] not in result.status   # a clean sphere: nothing near 20 degrees
    summary = result.options["uncertainty"]
    assert summary["threshold_deg"] == 20.0 and summary["pixels"] == has.sum()
    # a threshold under the typical expected error marks those pixels, keeping their normals
    low = float(np.median(unc[has]))
    marked = estimate_normals(images, dirs, mask, uncertain_deg=low)
    flagged = marked.status == STATUS["uncertain"]
    assert 0.2 < flagged[mask].mean() < 0.8
    np.testing.assert_array_equal(marked.normals, result.normals)
    assert (flagged <= (result.status == STATUS["ok"])).all()   # only 'ok' pixels become uncertain
    with pytest.raises(Exception, match="uncertain_deg"):
        estimate_normals(images, dirs, mask, uncertain_deg=-1)


def test_three_lights_give_no_map_and_say_why():
    normals, mask = sphere()
    dirs = lights(3)
    images = np.stack([np.clip(normals @ l, 0, None) * 0.8 * mask for l in dirs])
    result = estimate_normals(images, dirs, mask, method="lambert")
    assert result.uncertainty is None
    assert "not estimated: 3 light(s)" in result.options["uncertainty"]


def test_stage_writes_the_map_and_the_summary_line_says_it(tmp_path):
    session = make_session(tmp_path)
    from pipeline.decode import decode_session

    decode_session(session)
    record = normals_session(session, show_progress=False)
    unc = read_image(session.path(UNCERTAINTY))
    import OpenImageIO as oiio

    assert tuple(oiio.ImageInput.open(str(session.path(UNCERTAINTY))).spec().channelnames) == ("uncertainty",)
    _, mask = sphere()
    assert np.isfinite(unc[:, :, 0][mask]).mean() > 0.95 and np.isnan(unc[:, :, 0][~mask]).all()
    assert UNCERTAINTY in record["outputs"]
    found = record["uncertainty"]
    assert found["threshold_deg"] == 20.0 and 0 <= found["within_5"] <= 1
    line = normals_summary(record)
    assert "of pixels expected within 5 degrees" in line and "uncertain (over 20 degrees)" in line
    from pipeline.cli.eval import format_summary
    from pipeline.evaluate import evaluate_session

    scores = evaluate_session(session)
    assert len(scores["normals"]["uncertainty"]["bins"]) == 5
    assert "\nuncertainty: AUC not judged: pixels over 20 deg (0.0%), under 1 %; expected/actual" in format_summary(scores)
    # a rerun with a threshold records it, and a session too small for a map removes a stale one
    record = normals_session(session, show_progress=False, force=True, uncertain_deg=1.0)
    assert record["params"]["uncertain_deg"] == 1.0 and record["uncertainty"]["threshold_deg"] == 1.0
    assert record["status_counts"]["uncertain"] > 0


def test_summary_says_when_there_is_no_map():
    line = normals_summary({"pixels": 10, "status_counts": {"ok": 10},
                            "uncertainty": {"not_estimated": "not estimated: 3 light(s), at least 4 are needed"}})
    assert line.endswith("; uncertainty not estimated: 3 light(s), at least 4 are needed")
    line = normals_summary({"pixels": 100, "status_counts": {"ok": 94, "uncertain": 6},
                            "uncertainty": {"pixels": 100, "within_5": 0.82, "over_threshold": 0.06,
                                            "threshold_deg": 20.0}})
    assert line.endswith("; 82.0% of pixels expected within 5 degrees, 6.0% uncertain (over 20 degrees)")
    assert "uncertain 6.0%" in line


def test_agreement_ranks_and_bins():
    rng = np.random.default_rng(3)
    actual = rng.gamma(2.0, 4.0, 5000)
    exact = agreement(actual, actual)
    assert exact["auc"] == pytest.approx(1.0) and exact["calibrated_bins"] == 5
    assert all(b["ratio"] == pytest.approx(1.0) for b in exact["bins"])
    off = agreement(actual / 3, actual)   # three times too confident: ranks as well, not calibrated
    assert off["auc"] == pytest.approx(1.0) and off["calibrated_bins"] == 0
    assert roc_auc(rng.random(1000), rng.random(1000) > 0.5) == pytest.approx(0.5, abs=0.06)
    assert agreement(actual, np.full(5000, 1.0))["auc"] is None   # nothing over 20 degrees: not judged


def test_ply_carries_per_vertex_quality(tmp_path):
    from pipeline.integrate.mesh import build_mesh, write_ply

    depth = np.full((4, 5), np.nan)
    depth[1:3, 1:4] = 0.0
    unc = np.full((4, 5), np.nan, np.float32)
    unc[1:3, 1:4] = np.arange(6).reshape(2, 3)
    unc[2, 3] = np.nan
    mesh = build_mesh(depth, uncertainty=unc)
    np.testing.assert_array_equal(mesh.quality, [0, 1, 2, 3, 4, -1])
    path = tmp_path / "m.ply"
    write_ply(path, mesh.vertices, mesh.normals, mesh.faces, quality=mesh.quality)
    data = path.read_bytes()
    header, body = data.split(b"end_header\n", 1)
    assert b"property float quality\n" in header
    vert = np.frombuffer(body[:len(mesh.vertices) * 28], dtype=[(k, "<f4") for k in
                                                                  ("x", "y", "z", "nx", "ny", "nz", "quality")])
    np.testing.assert_array_equal(vert["quality"], mesh.quality)


def test_many_uncertain_pixels_are_warned_of():
    from pipeline.photometric.summary import normals_warnings

    warnings = normals_warnings({"ok": 85, "uncertain": 15}, 10, {})
    assert len(warnings) == 1 and warnings[0].startswith("15.0% of pixels are uncertain")
    assert normals_warnings({"ok": 95, "uncertain": 5}, 10, {}) == []


def test_the_map_made_in_bands_is_the_whole_image_map(monkeypatch):
    from pipeline.photometric import uncertainty as module

    rng = np.random.default_rng(4)
    yy, xx = np.mgrid[:90, :120]
    # a disc and a strip along the top edge: bands cut both, the strip's outline is the border's
    mask = ((yy - 45) ** 2 + (xx - 50) ** 2 < 38 ** 2) | ((yy < 5) & (xx > 100))
    normals = rng.normal(size=(90, 120, 3))
    normals[..., 2] = np.abs(normals[..., 2]) + 1
    normals = np.where(mask[..., None], normals / np.linalg.norm(normals, axis=-1, keepdims=True), 0.0)
    residual, leverage = rng.random((90, 120)) * 0.1, rng.random((90, 120)) + 0.5
    used, status = rng.integers(5, 96, (90, 120)), np.ones((90, 120), np.uint8)
    has, features = module.uncertainty_features(normals, status, residual, leverage, mask, used)
    whole = module.predict_uncertainty(features, has)
    for rows in (7, 16, 1000):
        monkeypatch.setattr(module, "BAND_ROWS", rows)
        banded, _ = module.uncertainty_map(normals, status, residual, leverage, mask, 96, used)
        np.testing.assert_allclose(banded, whole, rtol=1e-6)
        assert np.array_equal(np.isnan(banded), np.isnan(whole))
