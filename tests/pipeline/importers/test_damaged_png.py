"""A PNG frame cut short or damaged is refused at import in one line naming it (its header
alone opened, and decode later failed in 3-4 lines of libpng's)."""

import numpy as np
import pytest

from pipeline.cli import main
from pipeline.core.imageio import write_image


@pytest.fixture
def frames(tmp_path):
    src = tmp_path / "src"
    src.mkdir()
    rng = np.random.default_rng(3)
    for k in range(6):
        write_image(src / f"img{k + 1}.png", rng.random((40, 40, 3)).astype(np.float32))
    return src


@pytest.mark.parametrize("damage, said", [("cut", "truncated (it ends at byte"),
                                          ("flip", "corrupt (its 'IDAT' chunk at byte")])
def test_a_damaged_png_is_refused_at_import(tmp_path, frames, capfd, damage, said):
    path = frames / "img4.png"
    data = bytearray(path.read_bytes())
    if damage == "cut":
        data = data[:len(data) // 2]
    else:
        data[len(data) // 2] ^= 0x40
    path.write_bytes(bytes(data))
    assert main(["import", "images", str(tmp_path / "s"), "--object", str(frames / "img*.png")]) == 1
    err = capfd.readouterr().err   # the file descriptor: libpng writes there itself
    assert err.count("\n") == 1 and "Traceback" not in err, err
    assert f"{path}: the PNG file is {said}" in err, err
    assert not (tmp_path / "s").exists()


def test_grey_and_colour_frames_mixed_are_refused(tmp_path, frames, capsys):
    grey = frames / "img5.png"
    write_image(grey, np.full((40, 40), 0.5, np.float32), bits=16)
    assert main(["import", "images", str(tmp_path / "s"), "--object", str(frames / "img*.png")]) == 1
    err = capsys.readouterr().err
    assert f"{grey} is a grey image but {frames / 'img1.png'} is in colour" in err, err
    assert not (tmp_path / "s").exists()
