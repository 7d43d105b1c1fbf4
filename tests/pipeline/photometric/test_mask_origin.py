"""Without ``--mask`` the normals stage says how it made the mask: printed by ``psrig run``,
recorded, shown in the report with its outline; a made-up mask that looks like more than an
object is a warning naming ``--mask``."""

import numpy as np

from pipeline.cli import main
from pipeline.core.imageio import write_image
from pipeline.importers import import_images
from pipeline.core.session import Session

from tests.pipeline.tiny_session import lights, sphere


def _import(tmp_path, background=0.0, mask=None):
    normals, inside = sphere()
    src = tmp_path / "src"
    src.mkdir()
    for k, light in enumerate(lights()):
        shading = np.clip(normals @ light, 0, None) * 0.8 * inside + background * ~inside
        write_image(src / f"img{k + 1}.png", np.repeat(shading[..., None], 3, axis=2))
    (src / "lights.txt").write_text("".join(f"{x} {y} {z}\n" for x, y, z in lights()))
    return import_images(tmp_path / "s", str(src / "img*.png"), lights=src / "lights.txt", mask=mask)


def test_a_mask_made_from_brightness_is_said_recorded_and_shown(tmp_path, capsys):
    session = _import(tmp_path)
    assert main(["run", str(session.root), "--jobs", "1"]) == 0
    out = capsys.readouterr().out
    record = Session.open(session.root).stage("normals")
    mask = record["mask"]
    assert mask["source"] == "brightness" and mask["parts"] == 1 and mask["level"] == 0.05
    line = f"mask: none given; made from brightness, 5 % of the object's level: {mask['pixels']:,} pixels in 1 part"
    assert mask["text"] == line and line in out
    assert "warning" not in mask
    page = session.path("report/index.html").read_text()
    assert "<h2>Mask</h2>" in page or ">Mask<" in page
    assert "made from brightness" in page and session.path("report/mask.png").is_file()


def test_a_made_up_mask_over_most_of_the_frame_is_a_warning(tmp_path, capsys):
    session = _import(tmp_path, background=0.3)
    assert main(["run", str(session.root), "--jobs", "1", "--to", "normals"]) == 0
    captured = capsys.readouterr()
    mask = Session.open(session.root).stage("normals")["mask"]
    assert mask["share"] > 0.85 and "--mask" in mask["warning"]
    assert "it probably holds more than the object" in captured.err + captured.out
