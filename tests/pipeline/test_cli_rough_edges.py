"""Small things a new user hit on the command line (issue 34, item 7)."""

import pytest

from pipeline import runner
from pipeline.cli import main
from pipeline.core.session import Session

from tests.pipeline.tiny_session import lambert_stage, make_session


def test_run_prints_the_reports_path(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(runner.RUNNERS, "normals", lambert_stage)
    session = make_session(tmp_path)
    assert main(["run", str(session.root)]) == 0
    out = capsys.readouterr().out
    assert f"{session.root}: report: {session.path('report/index.html').resolve()}" in out.splitlines()
    assert main(["run", str(session.root), "--to", "normals"]) == 0   # no report stage: no path
    assert "report:" not in capsys.readouterr().out


def test_eval_with_nothing_to_evaluate_fails_and_says_why(tmp_path, capsys):
    session = make_session(tmp_path)   # ground truth normals, but no normals yet
    assert main(["eval", str(session.root)]) == 1
    err = capsys.readouterr().err
    assert "nothing to evaluate" in err and "ground truth for normals" in err and "psrig run" in err
    bare = Session.create(tmp_path / "bare")
    assert main(["eval", str(bare.root), "--json"]) == 1
    captured = capsys.readouterr()
    assert captured.out.strip() == "{}" and "has no ground truth" in captured.err


def test_an_option_of_another_command_gets_this_commands_usage(tmp_path, capsys):
    with pytest.raises(SystemExit) as stop:
        main(["decode", str(tmp_path), "--t-low", "0.3"])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("usage: psrig decode") and "psrig decode: error: unrecognized arguments: --t-low 0.3" in err
    assert "--t-low is an option of psrig normals, psrig run" in err
    with pytest.raises(SystemExit):
        main(["import", "images", str(tmp_path / "s"), "--object", "a*", "--gamma", "linear"])
    err = capsys.readouterr().err
    assert err.startswith("usage: psrig import images") and "--gamma is an option of psrig decode, psrig run" in err
