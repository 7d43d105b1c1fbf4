"""psrig preview, and capture's refusal to start when the brightest light's preview clips."""

import pytest

from pipeline.cli import main
from pipeline.core.imageio import read_image

RIGS = """
rigs:
  small:
    lights: {driver: sim, count: 8, timeout: 0.4, rings: [{elevation: 45, count: 8}]}
    camera: {driver: sim, path: generic}
    frames: {dark: 0, ambient: 0, sphere: false}
    scene: {shape: [48, 64]}
  bright:
    lights: {driver: sim, count: 8, timeout: 0.4, rings: [{elevation: 45, count: 8}]}
    camera: {driver: sim, path: generic}
    exposure: {shutter: 1/4}
    frames: {dark: 0, ambient: 0, sphere: false}
    scene: {shape: [48, 64], time_scale: 50}
"""


@pytest.fixture
def rigs(tmp_path):
    path = tmp_path / "rigs.yaml"
    path.write_text(RIGS, encoding="utf-8")
    return str(path)


def test_preview_prints_histogram_clipping_shutter_and_focus(rigs, tmp_path, capsys):
    assert main(["preview", "--rig", "small", "--config", rigs, "--light", "2", "--light", "5",
                 "--out", str(tmp_path / "pv")]) == 0
    out = capsys.readouterr().out
    assert "preview light 2:" in out and "preview light 5:" in out
    assert "G: p1 " in out and "p99.9" in out and "clipped 0.00 %" in out
    assert "suggested shutter: 1/" in out and "focus (variance of the Laplacian, green)" in out
    picture = read_image(tmp_path / "pv" / "preview_light_005.png")
    assert picture.shape[:2] == (24, 32) and picture.max() > 0
    assert main(["preview", "--rig", "small", "--config", rigs, "--light", "8"]) == 1
    assert "--light 8: rig 'small' has lights 0-7" in capsys.readouterr().err


def test_a_clipping_preview_stops_the_capture_unless_told(rigs, tmp_path, capsys):
    session = tmp_path / "s"
    assert main(["capture", str(session), "--rig", "bright", "--config", rigs]) == 1
    err = capsys.readouterr().err
    assert "the preview of light" in err and "--no-preview-check" in err and "Traceback" not in err
    assert "a shutter of 1/" in err
    assert not session.exists()  # refused before anything was written
    assert main(["capture", str(session), "--rig", "bright", "--config", rigs,
                 "--no-preview-check"]) == 0


def test_the_default_simulated_rig_passes_its_preview(rigs, tmp_path, capsys):
    assert main(["capture", str(tmp_path / "s"), "--rig", "small", "--config", rigs]) == 0
    err_out = capsys.readouterr()
    assert "preview of light" in err_out.out + err_out.err
    import yaml

    manifest = yaml.safe_load((tmp_path / "s" / "session.yaml").read_text())
    assert manifest["rig"]["preview"]["max_clipped"] == 0.01
    assert max(manifest["rig"]["preview"]["clipped"].values()) <= 0.01
