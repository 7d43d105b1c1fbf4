"""Nothing psrig writes in a session goes through a link: a session received as a folder or an
archive may hold a ``.psrig.lock``, a ``session.yaml`` or an output file that is a symlink to a
file elsewhere (or to another file of the session); the command refuses in one line and the file
linked to stays byte-identical."""

import os

import pytest

from pipeline.core.atomic import atomic_write_text, is_temp_name
from pipeline.cli import main
from pipeline.core.errors import SessionError
from tests.pipeline.tiny_session import make_session


@pytest.fixture
def session_and_outside(tmp_path):
    root = make_session(tmp_path).root
    outside = tmp_path / "home" / ".bashrc"
    outside.parent.mkdir()
    outside.write_bytes(b"export PATH=/precious\n")
    return root, outside


def one_error_line(err):
    lines = [line for line in err.splitlines() if line.strip()]
    assert "Traceback" not in err, err
    assert len(lines) == 1, err
    return lines[0]


@pytest.mark.parametrize("command", [["report"], ["eval"], ["decode", "--force"], ["run"]])
def test_a_symlinked_lock_file_is_refused_and_its_target_untouched(session_and_outside, capsys, command):
    root, outside = session_and_outside
    lock = root / ".psrig.lock"
    if lock.exists():
        lock.unlink()
    lock.symlink_to(os.path.relpath(outside, root))
    capsys.readouterr()
    assert main([command[0], str(root), *command[1:]]) == 1
    line = one_error_line(capsys.readouterr().err)
    assert f"{root.resolve() / '.psrig.lock'}: the session's lock file is a symbolic link" in line, line
    assert outside.read_bytes() == b"export PATH=/precious\n"
    assert lock.is_symlink()


def test_a_dangling_lock_link_creates_nothing(session_and_outside, capsys):
    root, outside = session_and_outside
    target = outside.parent / "created-by-psrig"
    lock = root / ".psrig.lock"
    if lock.exists():
        lock.unlink()
    lock.symlink_to(target)
    assert main(["decode", str(root), "--force"]) == 1
    assert "symbolic link" in one_error_line(capsys.readouterr().err)
    assert not target.exists() and not os.path.lexists(target)


def test_a_symlinked_manifest_is_refused_on_save(session_and_outside, capsys):
    root, outside = session_and_outside
    manifest = root / "session.yaml"
    copy = outside.parent / "session.yaml"
    copy.write_bytes(manifest.read_bytes())
    manifest.unlink()
    manifest.symlink_to(copy)
    before = copy.read_bytes()
    assert main(["decode", str(root), "--force"]) == 1
    line = one_error_line(capsys.readouterr().err)
    assert f"{manifest}: is a symbolic link to {copy}" in line, line
    assert copy.read_bytes() == before
    assert manifest.is_symlink()
    # the frames decoded before the save was refused leave no temporary file behind
    assert not [p.name for p in (root / "linear").iterdir() if is_temp_name(p.name)]


def test_an_output_linked_to_a_raw_frame_of_the_session_is_refused(session_and_outside, capsys):
    """A link inside the session resolves inside it: written through, it would replace a raw file."""
    root, _ = session_and_outside
    raw = sorted((root / "raw").iterdir())[0]
    before = raw.read_bytes()
    assert main(["decode", str(root)]) == 0
    linear = sorted((root / "linear").glob("*.exr"))[0]
    linear.unlink()
    linear.symlink_to(os.path.relpath(raw, linear.parent))
    capsys.readouterr()
    assert main(["decode", str(root), "--force"]) == 1
    err = capsys.readouterr().err
    assert f"{linear}: is a symbolic link to" in err, err
    assert "Traceback" not in err
    assert raw.read_bytes() == before


def test_the_atomic_writer_never_replaces_a_link_or_a_folder(tmp_path):
    outside = tmp_path / "outside.txt"
    outside.write_text("keep")
    link = tmp_path / "index.html"
    link.symlink_to(outside)
    with pytest.raises(SessionError, match=f"{link}: is a symbolic link to {outside}"):
        atomic_write_text(link, "<html>")
    (tmp_path / "folder.html").mkdir()
    with pytest.raises(SessionError, match="is a folder"):
        atomic_write_text(tmp_path / "folder.html", "<html>")
    assert outside.read_text() == "keep" and link.is_symlink()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["folder.html", "index.html", "outside.txt"]
