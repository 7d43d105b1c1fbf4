"""Stage runner: skip / rerun logic, --from, --to, errors naming stage and file, parallel runs."""

import pytest

from pipeline import runner
from pipeline.cli import main
from pipeline.core.errors import StageError
from pipeline.core.session import STAGES, Session
from tests.pipeline.tiny_session import lambert_stage, make_session


@pytest.fixture
def stubbed(monkeypatch):
    monkeypatch.setitem(runner.RUNNERS, "normals", lambert_stage)


def ran(outcomes):
    return [o.name for o in outcomes if o.ran]


def test_first_run_runs_all_then_everything_is_up_to_date(tmp_path, stubbed):
    session = make_session(tmp_path)
    lines = []
    first = runner.run_session(session.root, echo=lines.append)
    assert ran(first) == ["decode", "normals", "integrate", "report"]
    assert first[1].note == "no sphere frames: the imported calibration/lights.yaml is kept"
    assert any(line.startswith("normals: ran in") for line in lines)
    second = runner.run_session(session.root)
    assert ran(second) == []
    assert [o.describe().split(":")[1].strip() for o in second][0] == "up to date"
    for rel in ("depth/depth.exr", "report/index.html", "normals/eval.yaml"):
        assert session.path(rel).is_file()


def test_changed_option_reruns_that_stage_and_what_follows_only(tmp_path, stubbed):
    session = make_session(tmp_path)
    runner.run_session(session.root)
    decode_record = Session.open(session.root).stage("decode")
    options = runner.stage_options(method="tilted")
    outcomes = runner.run_session(session.root, options=options)
    assert ran(outcomes) == ["normals", "integrate", "report"]
    assert Session.open(session.root).stage("decode") == decode_record
    assert ran(runner.run_session(session.root, options=options)) == []


def test_from_and_to_and_force(tmp_path, stubbed):
    session = make_session(tmp_path)
    assert ran(runner.run_session(session.root, stop="decode")) == ["decode"]
    assert Session.open(session.root).stage("normals") is None
    runner.run_session(session.root)
    assert ran(runner.run_session(session.root, start="integrate")) == ["integrate", "report"]
    assert ran(runner.run_session(session.root, force=True)) == ["decode", "normals", "integrate", "report"]
    with pytest.raises(StageError, match="--from 'bogus'"):
        runner.run_session(session.root, start="bogus")


def test_changed_raw_file_is_an_error_naming_stage_and_file(tmp_path, stubbed, capsys):
    session = make_session(tmp_path)
    runner.run_session(session.root)
    raw = session.path(session.frames("object")[2]["file"])
    raw.write_bytes(raw.read_bytes() + b"x")
    report_before = session.path("report/index.html").read_bytes()
    with pytest.raises(StageError, match=r"stage decode: .*object_002\.png"):
        runner.run_session(session.root)
    assert main(["run", str(session.root)]) == 1
    err = capsys.readouterr().err
    assert "stage decode" in err and "object_002.png" in err and "Traceback" not in err
    assert session.path("report/index.html").read_bytes() == report_before


def test_missing_inputs_and_bad_folders(tmp_path, stubbed, capsys):
    session = make_session(tmp_path)
    session.path("calibration/lights.yaml").unlink()
    with pytest.raises(StageError, match=r"stage calibrate: .*lights\.yaml"):
        runner.run_session(session.root)
    (tmp_path / "plain").mkdir()
    assert main(["run", str(tmp_path / "plain"), str(tmp_path / "absent")]) == 1
    err = capsys.readouterr().err
    assert "not a session folder" in err and "no such session folder" in err


def test_interrupted_run_keeps_finished_stages_valid(tmp_path, monkeypatch):
    session = make_session(tmp_path)

    def interrupted(*args):
        raise KeyboardInterrupt

    monkeypatch.setitem(runner.RUNNERS, "normals", interrupted)
    with pytest.raises(KeyboardInterrupt):
        runner.run_session(session.root)
    monkeypatch.setitem(runner.RUNNERS, "normals", lambert_stage)
    assert ran(runner.run_session(session.root)) == ["normals", "integrate", "report"]


def test_sessions_in_parallel_processes(tmp_path, capsys):
    roots = [make_session(tmp_path, f"s{i}").root for i in range(2)]
    assert main(["run", *map(str, roots), "--jobs", "2", "--to", "calibrate"]) == 0
    out = capsys.readouterr().out
    for root in roots:
        assert f"{root}: decode: ran in" in out
        assert Session.open(root).stage("decode")["status"] == "ok"
    outcomes = runner.run_sessions(roots, stop="calibrate", jobs=2)
    assert all(ran(o.stages) == [] and not o.error for o in outcomes)
    assert len(STAGES) == 5


def test_run_keeps_the_settings_a_stage_was_run_with_by_hand(tmp_path):
    from pipeline.photometric import normals_session

    root = make_session(tmp_path).root
    runner.run_session(root, stop="calibrate")
    normals_session(Session.open(root), method="lambert-low", t_low=0.3, show_progress=False)
    by_hand = Session.open(root).stage("normals")
    assert ran(runner.run_session(root)) == ["integrate", "report"]
    assert Session.open(root).stage("normals") == by_hand
    # an option given to the run replaces the recorded one; the rest is kept
    assert ran(runner.run_session(root, options={"normals": {"method": "lambert"}}))[0] == "normals"
    params = Session.open(root).stage("normals")["params"]
    assert params["method"] == "lambert" and params["t_low"] == 0.3


def test_no_sphere_frames_and_no_lights_is_one_message_for_run_and_calibrate(tmp_path, stubbed):
    from calibration import calibrate_session

    session = make_session(tmp_path)
    session.path("calibration/lights.yaml").unlink()
    with pytest.raises(StageError) as run_error:
        runner.run_session(session.root, stop="calibrate")
    with pytest.raises(StageError) as calibrate_error:
        calibrate_session(session)
    expected = f"{session.root}: no sphere frames and no calibration/lights.yaml; capture a chrome sphere"
    assert expected in str(run_error.value) and "--from CAL" in str(run_error.value)
    assert str(calibrate_error.value).startswith(expected)


def test_the_sweep_note_names_the_session_once(tmp_path, stubbed, capsys):
    root = make_session(tmp_path).root
    assert main(["run", str(root), "--to", "decode"]) == 0
    (root / "linear" / ".object_001.a1b2c3.tmp.exr").write_bytes(b"x")
    capsys.readouterr()
    assert main(["run", str(root), "--to", "decode"]) == 0
    out = capsys.readouterr().out
    assert f"{root}: removed 1 temporary file (0.0 MB) left by an interrupted run (linear/ 1)\n" in out, out
    assert f"{root}: {root}" not in out


def test_an_empty_mask_in_a_session_is_named(tmp_path, capsys):
    from pipeline.core.imageio import read_mask, write_mask

    root = make_session(tmp_path).root
    session = Session.open(root)
    mask = session.path(session.manifest["lights"]["object_mask"])
    write_mask(mask, read_mask(mask) & False)   # all black, edited after the import
    assert main(["run", str(root), "--to", "normals"]) == 1
    err = capsys.readouterr().err
    assert f"{mask}: the object mask is empty (no white pixel)" in err, err
    assert "Traceback" not in err
