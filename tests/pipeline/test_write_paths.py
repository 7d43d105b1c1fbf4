"""Every write stays inside the session: an output folder replaced by a symlink to a folder
elsewhere is refused before anything is written there."""

import shutil

import pytest

from pipeline.cli import main
from pipeline.decode import decode_session
from pipeline.core.errors import SessionError
from pipeline.core.session import Session
from tests.pipeline.tiny_session import make_session

OUTPUTS = ("linear", "calibration", "normals", "depth", "report")


def link_away(root, name, tmp_path):
    """Replace ``root/name`` by a symlink to an empty folder outside the session."""
    elsewhere = tmp_path / f"elsewhere-{name}"
    elsewhere.mkdir()
    keep = tmp_path / f"kept-{name}"
    shutil.move(root / name, keep)
    (root / name).symlink_to(elsewhere, target_is_directory=True)
    return elsewhere


@pytest.mark.parametrize("name", OUTPUTS)
def test_a_symlinked_output_folder_is_refused_before_writing(tmp_path, capsys, name):
    root = make_session(tmp_path).root
    elsewhere = link_away(root, name, tmp_path)
    before = (root / "session.yaml").read_bytes()
    assert main(["run", str(root), "--force"]) == 1
    err = capsys.readouterr().err
    assert f"{root / name}: links to {elsewhere}, outside the session folder" in err, err
    assert "Traceback" not in err
    assert list(elsewhere.iterdir()) == []
    assert (root / "session.yaml").read_bytes() == before


def test_every_command_that_writes_checks_its_folders(tmp_path, capsys):
    root = make_session(tmp_path).root
    assert main(["run", str(root)]) == 0
    elsewhere = link_away(root, "normals", tmp_path)
    for command in (["normals", "--force"], ["integrate", "--force"], ["report", "--force"], ["eval"],
                    ["calibrate", "--force"], ["decode", "--force"]):
        assert main([command[0], str(root), *command[1:]]) == 1, command
        assert "outside the session folder" in capsys.readouterr().err
    assert list(elsewhere.iterdir()) == []


def test_stages_called_from_python_check_each_path_they_write(tmp_path):
    """Without a command's lock (library use) the folder check is not made up front; each
    output path is checked as it is made."""
    root = make_session(tmp_path).root
    elsewhere = link_away(root, "linear", tmp_path)
    with pytest.raises(SessionError, match="resolves outside the session folder"):
        decode_session(Session.open(root), jobs=1, progress=False)
    assert list(elsewhere.iterdir()) == []
