"""``psrig calibrate`` end to end on small simulated sessions."""

import numpy as np
import pytest
import yaml

from pipeline.cli import main
from pipeline.core.imageio import read_image
from pipeline.core.lightsio import read_lp
from pipeline.core.session import Session
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


def _calibrated_and_objects(tmp_path, objects):
    """A calibrated sphere session 'cal' of 6 lights, and a session 'obj' of ``objects`` frames."""
    scene = sphere_scene(6)
    make_sphere_session(tmp_path / "cal", scene)
    assert main(["calibrate", str(tmp_path / "cal")]) == 0
    session = Session.create(tmp_path / "obj")
    for k in range(objects):
        session.add_frame("object", scene.render_dng(k), light=k, save=False)
    session.save()


def test_calibrate_from_another_session_reuses_its_lights_with_its_hash(tmp_path, capsys):
    _calibrated_and_objects(tmp_path, 6)
    assert main(["calibrate", str(tmp_path / "obj"), "--from", str(tmp_path / "cal")]) == 0
    session = Session.open(tmp_path / "obj")
    record = session.stage("calibrate")
    source = (tmp_path / "cal" / "calibration" / "lights.yaml")
    from pipeline.core.session import file_sha256

    assert record["params"]["from_session_sha256"] == file_sha256(source)
    assert _yaml(session)["directions"] == _yaml(Session.open(tmp_path / "cal"))["directions"]
    assert "calibration of session" in _yaml(session)["source"]
    # psrig run keeps the choice: up to date, then redone when the source is recalibrated
    from pipeline.runner import run_stage

    assert not run_stage(session, "calibrate", {}, False, 1).ran
    assert main(["calibrate", str(tmp_path / "cal"), "--circle", "1,1,1", "--force"]) == 1   # no light on it
    assert "none of the 6 lights could be calibrated" in capsys.readouterr().err
    assert main(["calibrate", str(tmp_path / "cal"), "--no-outline", "--force"]) == 0
    data = yaml.safe_load(source.read_text())
    data["source"] += " (edited)"
    source.write_text(yaml.safe_dump(data, sort_keys=False))
    assert run_stage(session, "calibrate", {}, False, 1).ran
    capsys.readouterr()
    assert main(["calibrate", str(tmp_path / "obj"), "--from", str(tmp_path / "nowhere")]) == 1
    assert "nowhere" in capsys.readouterr().err


def test_calibrate_from_a_session_with_other_lights_is_refused(tmp_path, capsys):
    _calibrated_and_objects(tmp_path, 4)
    assert main(["calibrate", str(tmp_path / "obj"), "--from", str(tmp_path / "cal")]) == 1
    assert "6 lights for 4 object frames" in capsys.readouterr().err
    assert Session.open(tmp_path / "obj").stage("calibrate") is None


def test_calibrate_from_itself_or_a_loop_is_refused(tmp_path, capsys):
    """A session taking its lights from itself (or from one that takes them from it) would
    rerun calibrate on every psrig run and nest its source deeper each time."""
    _calibrated_and_objects(tmp_path, 6)
    obj, cal = str(tmp_path / "obj"), str(tmp_path / "cal")
    assert main(["calibrate", obj, "--from", obj]) == 1
    assert "that is this session" in capsys.readouterr().err
    assert main(["calibrate", obj, "--from", cal]) == 0
    capsys.readouterr()
    assert main(["calibrate", cal, "--from", obj, "--force"]) == 1
    assert "takes its lights from this session" in capsys.readouterr().err
    assert Session.open(tmp_path / "cal").stage("calibrate")["params"].get("from_session") is None


def _sphere_mask(path, scene):
    yy, xx = np.mgrid[0:240, 0:320]
    mask = np.zeros((240, 320), bool)
    for cx, cy, r in scene.circles:
        mask |= np.hypot(xx - cx, yy - cy) <= r
    from pipeline.core.imageio import write_mask

    write_mask(path, mask)
    return mask


def test_psrig_run_takes_the_calibration_options_and_keeps_them(tmp_path, capsys):
    scene = sphere_scene(6)
    make_sphere_session(tmp_path / "s", scene)
    _sphere_mask(tmp_path / "spheres.png", scene)
    code = main(["run", str(tmp_path / "s"), "--to", "calibrate", "--sphere-mask", str(tmp_path / "spheres.png")])
    assert code == 0, capsys.readouterr().err
    record = Session.open(tmp_path / "s").stage("calibrate")
    assert record["params"]["sphere_mask"] == str((tmp_path / "spheres.png").absolute())
    assert {s["method"] for s in _yaml(Session.open(tmp_path / "s"))["spheres"]} == {"mask"}
    assert main(["run", str(tmp_path / "s"), "--to", "calibrate"]) == 0
    assert "calibrate: up to date" in capsys.readouterr().out
    assert main(["run", str(tmp_path / "s"), "--circle", "1,2,3", "--sphere-mask", "m.png"]) == 1
    assert "one way only" in capsys.readouterr().err


def test_a_sphere_mask_given_at_import_is_used_by_calibrate(tmp_path):
    from pipeline.importers import import_images

    scene = sphere_scene(6)
    source = make_sphere_session(tmp_path / "src", scene)
    files = sorted(source.path(f["file"]) for f in source.frames("sphere"))
    _sphere_mask(tmp_path / "spheres.png", scene)
    session = import_images(tmp_path / "s", str(files[0].parent / "*.dng"), sphere_glob=str(files[0].parent / "*.dng"),
                            sphere_mask=tmp_path / "spheres.png")
    assert main(["run", str(session.root), "--to", "calibrate"]) == 0
    session = Session.open(session.root)
    assert "calibration/sphere_mask.png" in session.stage("calibrate")["inputs"]
    assert {s["method"] for s in _yaml(session)["spheres"]} == {"mask"}
