"""Inputs psrig cannot use are refused with one line naming the file; degenerate ones are
handled; a closed output pipe ends a command quietly."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from pipeline.cli import main
from pipeline.core.imageio import write_image
from pipeline.core.session import Session
from tests.pipeline.tiny_session import lights, make_session

REPO = Path(__file__).resolve().parents[2]


def one_error_line(capsys, *command):
    code = main(list(command))
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if "error" in line]
    assert code == 1 and len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


def import_frames(tmp_path, images, light_file=None):
    src = tmp_path / "src"
    src.mkdir()
    for k, image in enumerate(images):
        write_image(src / f"img{k}.{'exr' if image.dtype == np.float32 else 'png'}", image)
    dirs = lights(len(images))
    text = light_file or f"{len(dirs)}\n" + "".join(f"{x} {y} {z}\n" for x, y, z in dirs)
    name = "lights.yaml" if light_file else "lights.txt"
    (src / name).write_text(text)
    root = tmp_path / "s"
    assert main(["import", "images", str(root), "--object", str(src / "img*"), "--lights", str(src / name)]) == 0
    return root


def test_a_session_of_1x1_images_runs_to_the_end(tmp_path, capsys):
    images = [np.full((1, 1, 3), 20000 + 3000 * k, np.uint16) for k in range(8)]
    root = import_frames(tmp_path, images)
    assert main(["run", str(root)]) == 0, capsys.readouterr().err
    info = yaml.safe_load((root / "depth" / "integration.yaml").read_text())
    assert (info["mesh"]["vertices"], info["mesh"]["faces"]) == (1, 0)


def test_nan_in_a_frame_is_an_error_naming_the_file(tmp_path, capsys):
    images = [np.full((24, 24, 3), 0.1 + 0.05 * k, np.float32) for k in range(6)]
    images[3][5, 7, 1] = np.nan
    images[4][0, 0, 0] = np.inf
    root = import_frames(tmp_path, images)
    line = one_error_line(capsys, "run", str(root))
    assert "raw/object_003.exr: 1 value NaN or infinite" in line and "object_004.exr" in line
    record = Session.open(root).stage("decode")
    assert record["status"] == "partial" and set(record["failed"]) == {"object_003", "object_004"}


@pytest.mark.parametrize("value", [".nan", ".inf"])
def test_a_non_finite_light_intensity_is_refused(tmp_path, capsys, value):
    dirs = lights(8)
    intensities = [[1.0]] * 8
    text = yaml.safe_dump({"directions": dirs.tolist(), "intensities": intensities})
    root = import_frames(tmp_path, [np.full((8, 8, 3), 20000, np.uint16)] * 8, light_file=text)
    lights_yaml = root / "calibration" / "lights.yaml"
    data = lights_yaml.read_text().replace("- - 1.0", f"- - {value}", 1)
    lights_yaml.write_text(data)
    line = one_error_line(capsys, "run", str(root))
    assert f"{lights_yaml}: intensities: light 0 has a non-finite intensity" in line
    assert Session.open(root).stage("normals") is None  # nothing succeeded silently
    assert one_error_line(capsys, "import", "images", str(tmp_path / "again"), "--object",
                          str(tmp_path / "src" / "img*"), "--lights", str(lights_yaml))


@pytest.mark.parametrize("command", [["rigs"], ["eval", "SESSION"]])
def test_a_closed_output_pipe_ends_the_command_quietly(tmp_path, command):
    if "SESSION" in command:
        root = make_session(tmp_path).root
        assert main(["run", str(root)]) == 0
        command = [str(root) if c == "SESSION" else c for c in command]
    proc = subprocess.Popen([sys.executable, "-m", "pipeline", *command], cwd=REPO,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    proc.stdout.close()  # as `| head -1` does once it has its line
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=300) == 141, err
    assert "Traceback" not in err and "BrokenPipe" not in err and "Exception ignored" not in err, err
