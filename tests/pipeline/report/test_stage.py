"""HTML report: every <img src> and <a href> is relative, inside report/ and decodes."""

from html.parser import HTMLParser
from urllib.parse import unquote, urlparse

import pytest

from pipeline.cli import main
from pipeline.core.errors import StageError
from pipeline.core.imageio import read_image
from pipeline.report import report_session
from pipeline.core.session import Session
from tests.pipeline.tiny_session import lambert_stage


class Links(HTMLParser):
    def __init__(self):
        super().__init__()
        self.links = []

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        for key in ("src", "href"):
            if attrs.get(key) is not None:
                self.links.append((tag, attrs[key]))


def links_of(index):
    parser = Links()
    parser.feed(index.read_text(encoding="utf-8"))
    return parser.links


def test_report_links_are_relative_and_decode(processed):
    record = report_session(processed)
    index = processed.path("report/index.html")
    links = links_of(index)
    images = [src for tag, src in links if tag == "img"]
    assert len(images) >= len(processed.frames()) + 5  # thumbnails + normals, albedo, status, error, shaded
    report_dir = index.parent.resolve()
    for tag, link in links:
        parsed = urlparse(link)
        assert not parsed.scheme and not parsed.netloc and not link.startswith("/"), link
        target = (report_dir / unquote(parsed.path)).resolve()
        assert target.is_relative_to(report_dir) and target.is_file(), link
        if tag == "script":
            assert target.suffix == ".js" and target.stat().st_size > 0
        else:
            assert read_image(target).size > 0
    for rel in record["outputs"]:
        assert processed.path(rel).is_file()
    text = index.read_text(encoding="utf-8")
    for word in ("decode", "normals", "integrate", "mean_deg", "frames/object_007.png",
                 "maps/error.png", "maps/shaded.png", "maps/depth.png", 'class="psrig-mesh"'):
        assert word in text
    assert [src for tag, src in links if tag == "script"] == ["relight_model.js", "relight.js", "mesh_depth.js",
                                                             "viewer.js"]


def test_report_skips_when_current_and_reruns_on_change(processed, capsys):
    assert report_session(processed) is not None
    assert report_session(processed) is None
    assert main(["report", str(processed.root)]) == 0
    assert "up to date" in capsys.readouterr().out
    lambert_stage(processed, {"method": "tilted"}, False, None)
    assert report_session(processed) is not None


def test_report_needs_frames(tmp_path):
    with pytest.raises(StageError, match="no frames"):
        report_session(Session.create(tmp_path / "empty"))
