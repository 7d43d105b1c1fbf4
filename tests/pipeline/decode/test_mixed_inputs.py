"""Mixed inputs are named: one 8-bit frame among 16-bit ones is a decode warning naming it, and
the frame check's rescaled frames are listed farthest first."""

import numpy as np

from pipeline.cli import main
from pipeline.core.imageio import write_image
from pipeline.photometric.summary import _gain_warnings
from pipeline.core.session import Session

from tests.pipeline.tiny_session import lights


def test_one_8_bit_frame_among_16_bit_ones_is_named(tmp_path, capsys):
    src = tmp_path / "src"
    src.mkdir()
    for k in range(8):
        write_image(src / f"img{k + 1}.png", np.full((12, 16, 3), 0.3 + 0.01 * k, np.float32), bits=8 if k == 5 else 16)
    (src / "lights.txt").write_text("".join(f"{x} {y} {z}\n" for x, y, z in lights()))
    assert main(["import", "images", str(tmp_path / "s"), "--object", str(src / "img*.png"),
                 "--lights", str(src / "lights.txt")]) == 0
    capsys.readouterr()
    assert main(["decode", str(tmp_path / "s"), "--jobs", "1"]) == 0
    out = capsys.readouterr().out
    warnings = Session.open(tmp_path / "s").stage("decode")["warnings"]
    assert len(warnings) == 1 and warnings[0] in out
    assert warnings[0].startswith("mixed object frames: object_005 is 8-bit PNG, decoded as sRGB, while the other 7 "
                                  "are 16-bit PNG, decoded as linear")


def test_rescaled_frames_are_listed_farthest_first():
    rescaled = {f"object_{k:03d}": 1.2 for k in range(12)}
    rescaled["object_013"] = 0.09
    [line] = _gain_warnings({"rescaled": rescaled}, 16)
    assert line.startswith("frame(s) object_013 (0.09x), object_000 (1.20x)")
    [line] = _gain_warnings({"rescaled": rescaled, "uncalibrated": True}, 16)
    assert "farthest object_013 (0.09x)" in line
