"""What `psrig run` prints: one line per stage, -q, -v, --json; progress on a TTY or as lines."""

import io
import json

import pytest

from pipeline.core import progress as progress_module
from pipeline import runner
from pipeline.cli import main
from pipeline.core.progress import LineProgress, progress, progress_mode
from tests.calibration.sim_session import make_sphere_session, sphere_scene
from tests.pipeline.tiny_session import lambert_stage, make_session


@pytest.fixture
def tiny(tmp_path, monkeypatch):
    monkeypatch.setitem(runner.RUNNERS, "normals", lambert_stage)
    return make_session(tmp_path)


def stage_lines(out, root):
    return [line for line in out.splitlines() if line.startswith(f"{root}: ")]


def test_one_line_per_stage_even_for_an_up_to_date_calibration(tmp_path, capsys):
    session = make_sphere_session(tmp_path / "cal", sphere_scene(count=4))
    assert main(["run", str(session.root), "--to", "calibrate"]) == 0
    capsys.readouterr()
    assert main(["run", str(session.root), "--to", "calibrate"]) == 0
    out = capsys.readouterr().out
    assert "is up to date" not in out
    assert stage_lines(out, session.root) == [f"{session.root}: decode: up to date",
                                              f"{session.root}: calibrate: up to date"]


def test_quiet_prints_nothing_but_warnings(tiny, capsys):
    assert main(["run", str(tiny.root), "-q", "--to", "integrate"]) == 0
    captured = capsys.readouterr()
    assert captured.out == ""
    assert all(": warning: " in line for line in captured.err.splitlines())


def test_json_is_one_object_per_session_with_stages_shares_warnings_and_paths(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(runner.RUNNERS, "normals", lambert_stage)
    first, second = make_session(tmp_path, "a"), make_session(tmp_path, "b")
    assert main(["run", str(first.root), str(second.root), "--json", "--to", "integrate"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 2
    summaries = [json.loads(line) for line in lines]
    assert [s["session"] for s in summaries] == [str(first.root), str(second.root)]
    for summary in summaries:
        assert summary["ok"] and summary["error"] is None
        assert [s["name"] for s in summary["stages"]] == ["decode", "calibrate", "normals", "integrate"]
        assert all(s["ran"] for s in summary["stages"] if s["name"] != "calibrate")
        assert summary["outputs"]["mesh_obj"].endswith("depth/mesh.obj")
        assert isinstance(summary["warnings"], list)
        integrate = summary["stages"][-1]
        assert integrate["status"] == "ok" and "depth/mesh.ply" in integrate["outputs"]


def test_json_reports_a_failed_session_without_stopping_the_others(tiny, tmp_path, capsys):
    assert main(["run", str(tiny.root), str(tmp_path / "nope"), "--json", "--to", "decode"]) == 1
    captured = capsys.readouterr()
    summaries = [json.loads(line) for line in captured.out.splitlines()]
    assert [s["ok"] for s in summaries] == [True, False]
    assert "no such session folder" in summaries[1]["error"]


def test_verbose_adds_settings_outputs_and_status_shares(tiny, capsys):
    from pipeline.core.session import Session

    assert main(["run", str(tiny.root), "--to", "integrate"]) == 0
    session = Session.open(tiny.root)
    record = session.stage("normals")
    record["status_counts"], record["pixels"] = {"ok": 3, "shadowed": 1}, 4
    session.save()
    capsys.readouterr()
    assert main(["run", str(tiny.root), "-v", "--to", "integrate"]) == 0
    out = capsys.readouterr().out
    assert f"{tiny.root}: integrate: settings: method=smooth" in out
    assert f"{tiny.root}: normals: status: ok 75.0%, shadowed 25.0%" in out
    assert "depth/mesh.ply" in out


def test_progress_draws_a_bar_only_on_a_terminal(monkeypatch):
    class Terminal(io.StringIO):
        def isatty(self):
            return True

    monkeypatch.delenv("PSRIG_PROGRESS", raising=False)
    assert progress_mode(Terminal()) == "bar" and progress_mode(io.StringIO()) == "lines"
    monkeypatch.setenv("PSRIG_PROGRESS", "off")
    assert progress_mode(Terminal()) == "off"
    monkeypatch.setenv("PSRIG_PROGRESS", "bar")
    assert type(progress(total=3)).__name__ == "tqdm"


def test_progress_lines_are_periodic_and_plain(monkeypatch):
    clock = iter(range(0, 1000, 4))  # each reading of the clock is 4 s later
    monkeypatch.setattr(progress_module.time, "monotonic", lambda: next(clock))
    stream = io.StringIO()
    with LineProgress(total=10, desc="normals", unit="px", stream=stream) as bar:
        for _ in range(10):
            bar.update(1)
    lines = stream.getvalue().splitlines()
    assert "\r" not in stream.getvalue() and 2 <= len(lines) <= 5
    assert lines[0].startswith("normals: ") and " px (" in lines[0]
    assert lines[-1] == "normals: 10/10 px (100 %), 44 s, done"  # 11 clock readings after the start


def test_short_work_writes_no_progress_line_and_quiet_none_at_all():
    stream = io.StringIO()
    with LineProgress(total=3, desc="decode", stream=stream) as bar:
        bar.update(3)
    assert stream.getvalue() == ""
    silent = LineProgress(range(3), silent=True, stream=stream)
    assert list(silent) == [0, 1, 2] and stream.getvalue() == ""
