"""A sphere calibration without a matte target says, on the command line, that the
intensities are all 1."""

from pipeline.cli import main

from tests.calibration.sim_session import make_sphere_session, sphere_scene


def test_run_says_no_matte_target_means_intensities_all_one(tmp_path, capsys):
    scene = sphere_scene(count=4)
    scene.albedo[scene.geometry.label == 2] = 0.0   # no matte sphere: the chrome ones only
    session = make_sphere_session(tmp_path / "cal", scene)
    assert main(["run", str(session.root), "--to", "calibrate"]) == 0
    out = capsys.readouterr().out
    calibrate = next(line for line in out.splitlines() if line.startswith(f"{session.root}: calibrate:"))
    assert "calibrate: ran" in calibrate and "no matte target in the sphere frames: intensities all 1" in calibrate


def test_a_matte_target_says_nothing_of_the_kind(tmp_path, capsys):
    session = make_sphere_session(tmp_path / "cal", sphere_scene(count=4))
    assert main(["run", str(session.root), "--to", "calibrate"]) == 0
    assert "no matte target" not in capsys.readouterr().out
