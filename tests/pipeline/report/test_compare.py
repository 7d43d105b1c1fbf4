"""psrig report A B --out DIR: sessions side by side on the same scales."""

import numpy as np
import pytest

from pipeline import runner
from pipeline.cli import main
from pipeline.core.imageio import read_image
from pipeline.report.compare import MARK
from pipeline.core.session import Session
from tests.pipeline.tiny_session import lambert_stage, make_session


@pytest.fixture
def two(tmp_path, monkeypatch):
    """The tiny scene twice: straight Lambert normals, and normals bent toward +z ('tilted')."""
    monkeypatch.setitem(runner.RUNNERS, "normals", lambert_stage)
    first, second = make_session(tmp_path, "a"), make_session(tmp_path, "b")
    runner.run_session(first.root, stop="integrate")
    runner.run_session(second.root, stop="integrate", options={"normals": {"method": "tilted"}})
    return Session.open(first.root), Session.open(second.root)


def test_comparison_lays_sessions_side_by_side_on_one_scale(two, tmp_path, capsys):
    out = tmp_path / "cmp"
    assert main(["report", str(two[0].root), str(two[1].root), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert printed.count("report: ") == 3 and f"{out.resolve()}/index.html" in printed
    text = (out / "index.html").read_text()
    assert "a (lambert)" in text and "b (tilted)" in text
    assert text.count('src="bars/bar_error.png"') == 1 and "&ge; 30 deg" in text
    # the same colours mean the same error in both columns: one scale, one bar per row
    first, second = read_image(out / "s0/error.png"), read_image(out / "s1/error.png")
    assert first.shape == second.shape and not np.allclose(first, second)
    assert (two[0].path("report/index.html")).is_file() and (two[1].path("report/index.html")).is_file()
    assert "angular error histogram" in text


def test_comparison_never_overwrites_a_folder_of_the_user(two, tmp_path, capsys):
    busy = tmp_path / "thesis"
    busy.mkdir()
    (busy / "chapter.tex").write_text("precious")
    assert main(["report", str(two[0].root), str(two[1].root), "--out", str(busy)]) == 1
    assert "not an earlier comparison" in capsys.readouterr().err
    assert (busy / "chapter.tex").read_text() == "precious" and not (busy / MARK).exists()
    again = tmp_path / "cmp"
    for _ in range(2):  # an earlier comparison is replaced
        assert main(["report", str(two[0].root), str(two[1].root), "--out", str(again)]) == 0


def test_one_session_with_out_and_a_missing_session_are_clear_errors(two, tmp_path, capsys):
    assert main(["report", str(two[0].root), "--out", str(tmp_path / "x")]) == 1
    assert "two sessions or more" in capsys.readouterr().err
    assert main(["report", str(two[0].root), str(tmp_path / "nope")]) == 1
    assert "nope" in capsys.readouterr().err
    assert not (tmp_path / "psrig-compare").exists()
