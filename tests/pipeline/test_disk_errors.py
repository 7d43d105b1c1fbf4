"""A full disk (or a read-only or protected folder) met by any command is one line naming the
file and what the error means, never a traceback; the session stays as it was. The disk is
filled by making the atomic writer's fsync (where a real full disk often shows first, and
always before the rename) fail with ENOSPC for the files of one folder."""

import errno
import os

import pytest

from pipeline.core import atomic
from pipeline.cli import main
from pipeline.core.session import Session
from tests.pipeline.tiny_session import make_session


def fill_disk(monkeypatch, where, code=errno.ENOSPC):
    """Make every atomic write whose temporary file's path contains ``where`` fail with ``code``."""
    real = atomic._fsync_file

    def fsync(tmp):
        if where in str(tmp):
            raise OSError(code, os.strerror(code))
        return real(tmp)
    monkeypatch.setattr(atomic, "_fsync_file", fsync)


def one_line(capsys):
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert "Traceback" not in err and len(lines) == 1, err
    return lines[0]


def test_integrate_on_a_full_disk(tmp_path, monkeypatch, capsys):
    root = make_session(tmp_path).root
    assert main(["run", str(root), "--to", "normals", "-q"]) == 0
    capsys.readouterr()
    fill_disk(monkeypatch, f"{os.sep}depth{os.sep}")
    assert main(["integrate", str(root)]) == 1
    line = one_line(capsys)
    assert line.startswith(f"psrig integrate: error: {root.resolve() / 'depth'}"), line
    assert line.endswith(": disk full (No space left on device)"), line
    assert Session.open(root).stage("integrate") is None
    assert not [p for p in (root / "depth").iterdir() if atomic.is_temp_name(p.name)]


@pytest.mark.parametrize("code,meaning", [(errno.ENOSPC, "disk full (No space left on device)"),
                                          (errno.EROFS, "Read-only file system"),
                                          (errno.EACCES, "Permission denied")])
def test_a_manifest_save_that_fails(tmp_path, monkeypatch, capsys, code, meaning):
    root = make_session(tmp_path).root
    before = (root / "session.yaml").read_bytes()
    fill_disk(monkeypatch, f"{os.sep}.session.", code)
    assert main(["decode", str(root)]) == 1
    line = one_line(capsys)
    assert f"{root / 'session.yaml'}: {meaning}" in line, line
    assert (root / "session.yaml").read_bytes() == before


def test_run_names_the_stage_and_the_file(tmp_path, monkeypatch, capsys):
    root = make_session(tmp_path).root
    fill_disk(monkeypatch, f"{os.sep}linear{os.sep}")
    assert main(["run", str(root), "-q"]) == 1
    line = one_line(capsys)
    assert "stage decode" in line and f"{root.resolve() / 'linear'}" in line, line
    assert "disk full (No space left on device)" in line, line


def test_capture_on_a_full_disk(tmp_path, monkeypatch, capsys):
    from tests.rig.test_capture import RIGS

    rigs = tmp_path / "rigs.yaml"
    rigs.write_text(RIGS, encoding="utf-8")
    root = tmp_path / "s"
    fill_disk(monkeypatch, f"{os.sep}raw{os.sep}.object_003.")
    assert main(["capture", str(root), "--rig", "sim8", "--config", str(rigs)]) == 1
    line = one_line(capsys)
    assert f"frame object_003 (light 3): cannot store {root.resolve() / 'raw' / 'object_003.dng'}: disk full (No space left on device)" in line, line
    assert "--resume" in line
    session = Session.open(root)   # valid, the frames before kept
    assert [f["id"] for f in session.frames()][-1] == "object_002"
    monkeypatch.undo()
    assert main(["capture", str(root), "--rig", "sim8", "--config", str(rigs), "--resume"]) == 0


def test_a_short_write_on_a_full_disk_is_called_disk_full(tmp_path, monkeypatch, capsys):
    """numpy reports a full disk as a short write without an errno ("18432 requested and 18400
    written"): with the file system full, it is said to be one."""
    root = make_session(tmp_path).root
    assert main(["run", str(root), "--to", "normals", "-q"]) == 0
    capsys.readouterr()
    real = atomic._fsync_file

    def fsync(tmp):
        if f"{os.sep}depth{os.sep}" in str(tmp):
            raise OSError("18432 requested and 18400 written")
        return real(tmp)
    monkeypatch.setattr(atomic, "_fsync_file", fsync)
    monkeypatch.setattr(atomic, "_disk_full", lambda folder: True)
    assert main(["integrate", str(root)]) == 1
    line = one_line(capsys)
    assert ": disk full (No space left on device: 18432 requested and 18400 written)" in line, line
