"""Settings shown are the settings used (issue 34, item 6): a sphere mask stored at import, the
transfer --gamma auto chose, the comparison page's labels, and a calibrate that kept imported
lights."""

from pipeline import runner
from pipeline.cli import main
from pipeline.report.details import settings_used
from pipeline.report.sections import stages_table
from pipeline.core.session import Session
from tests.pipeline.tiny_session import lambert_stage, make_session


def test_a_stored_sphere_mask_and_a_decided_transfer_are_shown_as_used():
    record = {"params": {"circle": None, "sphere_mask": None, "sphere_mask_sha256": None, "K": None},
              "inputs": {"calibration/sphere_mask.png": "ab12", "linear/sphere_000.exr": "cd34"}}
    shown = settings_used("calibrate", record)
    assert shown["sphere_mask"] == "calibration/sphere_mask.png (stored at import)" and "sphere_mask_sha256" not in shown
    assert settings_used("calibrate", {"params": {"sphere_mask": None}, "inputs": {}})["sphere_mask"] is None
    decode = {"params": {"gamma": "auto"}, "transfer_decision": {"transfer": "linear", "guess": False}}
    assert settings_used("decode", decode)["gamma"] == "auto (linear, from the data)"


def test_sessions_that_differ_by_gamma_do_not_look_alike(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(runner.RUNNERS, "normals", lambert_stage)
    first, second = make_session(tmp_path, "a"), make_session(tmp_path, "b")
    runner.run_session(first.root, stop="integrate")
    runner.run_session(second.root, stop="integrate", options={"decode": {"gamma": "srgb"}})
    out = tmp_path / "cmp"
    assert main(["report", str(first.root), str(second.root), "--out", str(out)]) == 0
    text = (out / "index.html").read_text()
    assert "a (lambert; decode gamma=auto)" in text and "b (lambert; decode gamma=srgb)" in text


def test_a_calibrate_that_kept_imported_lights_is_not_not_run(tmp_path, monkeypatch):
    monkeypatch.setitem(runner.RUNNERS, "normals", lambert_stage)
    session = make_session(tmp_path)
    runner.run_session(session.root, stop="normals")
    table = stages_table(Session.open(session.root))
    row = table[table.index("<td>calibrate</td>"):].split("</tr>")[0]
    assert "up to date (kept)" in row and "not run" not in row
