"""Stage records cover what each stage reads from the manifest: editing a frame's ``light`` or
``file`` in session.yaml reruns the stages that read it, and only those."""

import numpy as np
import yaml

from pipeline.cli import main
from pipeline.core.imageio import read_image
from pipeline.core.session import Session
from tests.pipeline.tiny_session import make_session


def edit(root, change):
    path = root / "session.yaml"
    data = yaml.safe_load(path.read_text())
    change(data)
    path.write_text(yaml.safe_dump(data, sort_keys=False))


def stages_run(capsys, *command):
    assert main(list(command)) == 0
    out = capsys.readouterr().out
    return {line.split(": ")[1] for line in out.splitlines() if ": ran in" in line}


def swap(data, i, j, *keys):
    frames = data["frames"]
    for key in keys:
        frames[i][key], frames[j][key] = frames[j][key], frames[i][key]


def test_swapping_two_frames_lights_reruns_normals(tmp_path, capsys):
    root = make_session(tmp_path).root
    assert stages_run(capsys, "run", str(root)) >= {"decode", "normals", "integrate", "report"}
    before = read_image(root / "normals" / "normals.exr")
    edit(root, lambda data: swap(data, 0, 1, "light"))
    assert stages_run(capsys, "run", str(root)) == {"normals", "integrate", "report"}
    after = read_image(root / "normals" / "normals.exr")
    assert not np.array_equal(before, after)  # the frames now face other lights
    assert stages_run(capsys, "run", str(root)) == set()


def test_pointing_a_frame_at_another_raw_file_reruns_decode(tmp_path, capsys):
    root = make_session(tmp_path).root
    assert stages_run(capsys, "run", str(root), "--to", "decode") == {"decode"}
    old = {k: read_image(root / "linear" / f"object_00{k}.exr") for k in (2, 5)}
    edit(root, lambda data: swap(data, 2, 5, "file", "sha256"))
    assert stages_run(capsys, "run", str(root), "--to", "decode") == {"decode"}
    # each frame's output is now the decode of the file its entry names
    assert np.array_equal(read_image(root / "linear" / "object_002.exr"), old[5])
    assert np.array_equal(read_image(root / "linear" / "object_005.exr"), old[2])
    record = Session.open(root).stage("decode")
    assert record["frames"]["object_002"]["file"] == "raw/object_005.png"


def test_an_ambient_frame_for_other_kinds_reruns_decode(tmp_path, capsys):
    session = make_session(tmp_path)
    session = Session.open(session.root, writer="test")
    session.add_frame("ambient", source=session.path("raw/object_000.png"), applies_to=["sphere"])
    session.release()
    root = session.root
    stages_run(capsys, "run", str(root), "--to", "decode")
    lit = read_image(root / "linear" / "object_003.exr")
    edit(root, lambda data: data["frames"][-1].update(applies_to=["object"]))
    assert stages_run(capsys, "run", str(root), "--to", "decode") == {"decode"}
    assert not np.array_equal(read_image(root / "linear" / "object_003.exr"), lit)  # now subtracted


def test_swapping_two_sphere_frames_lights_reruns_calibrate(tmp_path, capsys):
    from rig.capture import capture_session
    from rig.config import get_rig
    from tests.rig.test_capture import RIGS

    rigs = tmp_path / "rigs.yaml"
    rigs.write_text(RIGS, encoding="utf-8")
    root = capture_session(tmp_path / "s", get_rig("sim8", rigs), progress=False, echo=lambda line: None).root
    assert {"decode", "calibrate"} <= stages_run(capsys, "run", str(root), "--to", "calibrate")
    spheres = [i for i, f in enumerate(Session.open(root).frames()) if f["kind"] == "sphere"]
    edit(root, lambda data: swap(data, spheres[0], spheres[1], "light"))
    assert stages_run(capsys, "run", str(root), "--to", "calibrate") == {"calibrate"}
