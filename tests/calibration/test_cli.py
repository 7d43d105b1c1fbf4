"""``psrig calibrate`` end to end on small simulated sessions."""

import numpy as np
import pytest
import yaml

from pipeline.cli import main
from pipeline.imageio import read_image
from pipeline.lightsio import read_lp
from pipeline.session import Session
from rig.sim.scene import Scene
from tests.calibration.sim_session import make_sphere_session, sphere_scene


def _yaml(session):
    return yaml.safe_load(session.path("calibration/lights.yaml").read_text())


def test_decoded_session_calibrates(tmp_path, capsys):
    scene = sphere_scene(6)
    make_sphere_session(tmp_path / "s", scene, decoded=True)
    assert main(["calibrate", str(tmp_path / "s")]) == 1   # not decoded yet: says what to run
    assert "run `psrig decode` first" in capsys.readouterr().err
    assert main(["decode", str(tmp_path / "s")]) == 0
    assert main(["calibrate", str(tmp_path / "s")]) == 0
    session = Session.open(tmp_path / "s")
    data = _yaml(session)
    assert data["light_model"] == "directional" and "positions" not in data
    assert [s["kind"] for s in data["spheres"]].count("chrome") == 2
    err = np.degrees(np.arccos(np.clip((np.array(data["directions"]) * scene.directions).sum(1), -1, 1)))
    assert np.median(err) < 0.6
    got, truth = np.array(data["intensities"]), scene.intensities / scene.intensities.mean()
    assert np.abs(got / truth - 1).max() < 0.03          # small 240 x 320 frames with noise
    names, lp = read_lp(session.path("calibration/lights.lp"))[:2]
    assert len(names) == 6 and np.allclose(lp, data["directions"], atol=1e-5)
    for name in ("overlay.png", "overlay_chrome0.png", "overlay_chrome1.png", "overlay_matte0.png"):
        assert read_image(session.path(f"calibration/{name}")).shape[2] == 3
    assert main(["calibrate", str(tmp_path / "s")]) == 0
    assert "up to date" in capsys.readouterr().out


def test_near_lights_give_positions(tmp_path):
    scene = sphere_scene(6, distance=600.0)
    session = make_sphere_session(tmp_path / "s", scene)
    assert main(["calibrate", str(tmp_path / "s")]) == 0
    data = _yaml(session)
    assert data["light_model"] == "near"
    dist = np.linalg.norm(np.array(data["positions"]), axis=1)
    assert np.abs(dist / 600.0 - 1).max() < 0.05         # 57 px spheres: measured within 2.3 %
    assert len(data["ray_miss"]) == 6 and len(data["residual_deg"]) == 6


def test_light_behind_the_spheres_is_flagged_and_named(tmp_path, capsys):
    d = sphere_scene(8).directions
    d[2] = [0.0, 0.0, -1.0]
    scene = Scene.default_spheres((240, 320), directions=d)
    session = make_sphere_session(tmp_path / "s", scene)
    # the back light rims the chrome balls and spoils their found outline (not yet handled)
    text = ";".join(",".join(f"{v:.2f}" for v in c) for c in scene.circles)
    assert main(["calibrate", str(tmp_path / "s"), "--circle", text]) == 0
    out = capsys.readouterr().out
    assert "flagged" in out and "sphere_002" in out
    flags = _yaml(session)["flags"]
    assert list(flags) == [2] and ("no highlight" in flags[2] or "rim" in flags[2])


def test_bad_circle_is_one_clear_error(tmp_path, capsys):
    make_sphere_session(tmp_path / "s", sphere_scene(3))
    assert main(["calibrate", str(tmp_path / "s"), "--circle", "10,20"]) == 1
    assert "--circle" in capsys.readouterr().err


def test_given_circles_are_used(tmp_path):
    scene = sphere_scene(4)
    session = make_sphere_session(tmp_path / "s", scene)
    text = ";".join(",".join(f"{v:.2f}" for v in c) for c in scene.circles)
    assert main(["calibrate", str(tmp_path / "s"), "--circle", text]) == 0
    spheres = _yaml(session)["spheres"]
    assert [s["method"] for s in spheres] == ["given"] * 3


@pytest.mark.parametrize("missing", ["mask.png"])
def test_missing_mask_is_named(tmp_path, capsys, missing):
    make_sphere_session(tmp_path / "s", sphere_scene(3))
    assert main(["calibrate", str(tmp_path / "s"), "--sphere-mask", str(tmp_path / missing)]) == 1
    assert missing in capsys.readouterr().err
