"""Light files with values that overflow or are not numbers are refused at import, naming the
file and the light (or, for a huge but valid direction, read exactly, without a numpy warning)."""

import warnings

import numpy as np
import pytest

from pipeline.cli import main
from pipeline.core.imageio import write_image
from pipeline.core.lightsio import read_lights
from pipeline.core.yamlio import dump_yaml
from tests.pipeline.tiny_session import lights, sphere


@pytest.fixture
def frames(tmp_path):
    normals, mask = sphere()
    src = tmp_path / "src"
    src.mkdir()
    for k, light in enumerate(lights()):
        write_image(src / f"img{k + 1}.png", np.repeat((np.clip(normals @ light, 0, None) * mask)[..., None], 3, 2))
    return src


def text_file(path, row3):
    rows = [" ".join(map(str, d)) for d in lights()]
    rows[3] = row3
    path.write_text(f"{len(rows)}\n" + "\n".join(rows) + "\n")
    return path


def import_with(tmp_path, frames, light_file):
    return main(["import", "images", str(tmp_path / "s"), "--object", str(frames / "img*.png"),
                 "--lights", str(light_file)])


def test_a_zero_direction_names_the_file_and_the_light(tmp_path, frames, capsys):
    path = text_file(tmp_path / "zero.txt", "0 0 0")
    assert import_with(tmp_path, frames, path) == 1
    err = capsys.readouterr().err
    assert f"{path}: light 3 has a zero direction vector" in err and "Traceback" not in err, err


def test_a_huge_direction_is_read_exactly_without_a_warning(tmp_path):
    path = text_file(tmp_path / "huge.txt", "1e308 1e308 1e308")
    with warnings.catch_warnings():
        warnings.simplefilter("error")   # numpy's overflow warning said 'zero direction' before
        read = read_lights(path)
    assert np.allclose(read.directions[3], np.full(3, 1 / np.sqrt(3)))


def test_a_nan_light_position_is_refused_at_import(tmp_path, frames, capsys):
    dirs = lights()
    positions = (dirs * 900).tolist()
    positions[5][1] = float("nan")
    path = tmp_path / "lights.yaml"
    path.write_text(dump_yaml({"directions": dirs.tolist(), "positions": positions}))
    assert import_with(tmp_path, frames, path) == 1
    err = capsys.readouterr().err
    assert f"{path}: positions: light 5 has a non-finite position" in err, err
    assert "Traceback" not in err and not (tmp_path / "s").exists()
