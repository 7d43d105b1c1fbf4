"""Lights left out by hand survive ``psrig run`` on a sphere-calibrated session: in
``calibration/exclude.yaml`` (never written by a stage), and as flags added to lights.yaml."""

import pytest

from pipeline.cli import main
from pipeline.core.errors import InputError
from pipeline.core.lightsio import read_exclude, read_lights_yaml
from pipeline.core.session import Session
from pipeline.core.yamlio import dump_yaml, load_yaml
from rig.sim.scene import Scene

from tests.calibration.sim_session import SHAPE, make_sphere_session, sphere_scene

COUNT = 8


@pytest.fixture
def session(tmp_path):
    """A simulated session with chrome-sphere frames and object frames under the same 8 lights,
    run once through normals."""
    spheres = sphere_scene(count=COUNT)
    session = make_sphere_session(tmp_path / "s", spheres, decoded=True)
    scene = Scene.default_object(SHAPE, directions=spheres.directions, intensities=spheres.intensities)
    for k in range(COUNT):
        session.add_frame("object", scene.render_dng(k), light=k, save=False)
    session.save()
    assert main(["run", str(session.root), "--to", "normals", "-q"]) == 0
    return Session.open(session.root)


def test_exclude_yaml_leaves_a_light_out_across_reruns_and_says_so(session, capsys):
    session.path("calibration/exclude.yaml").write_text("lights:\n  3: misfired\n")
    capsys.readouterr()
    assert main(["run", str(session.root), "--to", "normals"]) == 0
    out = capsys.readouterr().out
    assert "1 light(s) left out by hand (calibration/exclude.yaml): 3 (misfired)" in out
    record = Session.open(session.root).stage("normals")
    assert 3 in record["lights_left_out"] and record["lights_left_out_by_hand"] == {"3": "misfired"}
    assert record["lights_used"] == COUNT - 1
    # a forced recalibration rewrites lights.yaml; exclude.yaml is untouched and still read
    assert main(["run", str(session.root), "--to", "normals", "--force", "--from", "calibrate"]) == 0
    out = capsys.readouterr().out
    assert "left out by hand (calibration/exclude.yaml): 3 (misfired)" in out
    assert session.path("calibration/exclude.yaml").read_text() == "lights:\n  3: misfired\n"
    assert Session.open(session.root).stage("normals")["lights_left_out_by_hand"] == {"3": "misfired"}


def test_a_flag_added_to_lights_yaml_survives_the_recalibration_it_causes(session, capsys):
    path = session.path("calibration/lights.yaml")
    data = load_yaml(path.read_text())
    data.setdefault("flags", {})[5] = "a shadow of the arm, by hand"
    path.write_text(dump_yaml(data))
    capsys.readouterr()
    assert main(["run", str(session.root), "--to", "normals"]) == 0
    out = capsys.readouterr().out
    assert "calibrate: ran" in out   # the edited output reruns calibrate, which rewrites the file
    assert "kept 1 flag(s) added by hand (light 5: a shadow of the arm, by hand)" in out
    assert "calibration/exclude.yaml" in out
    assert read_lights_yaml(path).flags[5] == "a shadow of the arm, by hand"
    record = Session.open(session.root).stage("normals")
    assert 5 in record["lights_left_out"] and record["lights_used"] == COUNT - 1


def test_exclude_yaml_errors_name_the_file_and_key(session):
    session.path("calibration/exclude.yaml").write_text("lights:\n  12: gone\n")
    with pytest.raises(InputError, match=r"exclude.yaml: lights: 12 is not a light of this session \(0 .. 7\)"):
        read_exclude(session, COUNT)
    session.path("calibration/exclude.yaml").write_text("light: [1]\n")
    with pytest.raises(InputError, match="exclude.yaml: expected one key 'lights'"):
        read_exclude(session)
    session.path("calibration/exclude.yaml").write_text("lights: [1, 2]\n")
    assert read_exclude(session) == {1: "no reason given", 2: "no reason given"}
