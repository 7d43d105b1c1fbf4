"""psrig demo: folder rules (fast) and the whole chain on the simulated rig (slow)."""

import importlib.util
import time
from html.parser import HTMLParser
from pathlib import Path

import pytest

from pipeline.cli import main
from pipeline.demo import DEMO_MARK, prepare_folder
from pipeline.core.errors import SessionError
from pipeline.core.imageio import read_image
from pipeline.core.session import Session


def test_prepare_folder_accepts_new_or_empty(tmp_path):
    assert prepare_folder(tmp_path / "new") == tmp_path / "new"
    (tmp_path / "empty").mkdir()
    assert prepare_folder(tmp_path / "empty") == tmp_path / "empty"


def test_prepare_folder_never_deletes_user_data(tmp_path, capsys):
    busy = tmp_path / "busy"
    busy.mkdir()
    (busy / "thesis.tex").write_text("precious")
    with pytest.raises(SessionError, match="not a session"):
        prepare_folder(busy, force=True)
    other = Session.create(tmp_path / "lab")
    with pytest.raises(SessionError, match="did not make"):
        prepare_folder(other.root, force=True)
    assert main(["demo", str(busy), "--force"]) == 1
    assert "not a session" in capsys.readouterr().err
    assert (busy / "thesis.tex").read_text() == "precious" and other.path("session.yaml").is_file()


def test_prepare_folder_replaces_old_demo_only_with_force(tmp_path):
    demo = Session.create(tmp_path / "demo", rig={"name": "sim", DEMO_MARK: True})
    with pytest.raises(SessionError, match="--force"):
        prepare_folder(demo.root)
    assert demo.path("session.yaml").is_file()
    prepare_folder(demo.root, force=True)
    assert not demo.root.exists()


_PARTS = ("rig.capture", "calibration.stage", "pipeline.photometric.stage")


@pytest.mark.slow
@pytest.mark.skipif(any(importlib.util.find_spec(p) is None for p in _PARTS),
                    reason="capture, calibration or normals stage not installed")
def test_demo_end_to_end(tmp_path, capsys):
    start = time.perf_counter()
    assert main(["demo", str(tmp_path / "demo")]) == 0
    seconds = time.perf_counter() - start
    out = capsys.readouterr().out
    assert "report:" in out and "normals: mean" in out
    session = Session.open(tmp_path / "demo")
    assert all(session.stage(n)["status"] == "ok" for n in ("decode", "calibrate", "normals", "integrate", "report"))
    scores = __import__("yaml").safe_load(session.path("normals/eval.yaml").read_text())
    assert scores["normals"]["mean_deg"] < 2.0
    assert scores["lights"]["mean_deg"] < 1.0
    assert seconds < 120
    index = session.path("report/index.html")

    class Links(HTMLParser):
        found = []

        def handle_starttag(self, tag, attrs):
            self.found += [v for k, v in attrs if k in ("src", "href")]

    parser = Links()
    parser.feed(index.read_text())
    assert parser.found
    for link in parser.found:
        if link.endswith(".js"):  # the 3-D view's viewer and mesh data
            assert (index.parent / link).stat().st_size > 0
        else:
            assert read_image(index.parent / link).size > 0
    assert main(["run", str(session.root)]) == 0
    assert "ran in" not in capsys.readouterr().out
