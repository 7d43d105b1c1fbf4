"""Digests remembered against the file system's word: an unchanged file is hashed once, a changed
one always again, and the cache is only ever a hint."""

import os
import time

import pytest

from pipeline.core import hashes as module
from pipeline.core import session as session_module
from pipeline.core.errors import SessionError
from pipeline.core.hashes import HASHES_FILE, HashCache
from pipeline.core.session import Session, file_sha256
from pipeline.decode import decode_session
from pipeline.photometric import normals_session
from tests.pipeline.tiny_session import make_session


class Counting:
    def __init__(self):
        self.paths = []

    def __call__(self, path):
        self.paths.append(os.path.basename(path))
        return file_sha256(path)


@pytest.fixture
def settled(monkeypatch):
    # every file counts as settled (the suite's files are all seconds old at most)
    monkeypatch.setattr(module, "SETTLE_SECONDS", -1.0)


def test_an_unchanged_file_is_hashed_once_across_runs(tmp_path, settled):
    (tmp_path / "a.bin").write_bytes(b"a" * 1000)
    hasher = Counting()
    first = HashCache(tmp_path)
    digest = first.digest("a.bin", tmp_path / "a.bin", hasher)
    first.save()
    again = HashCache(tmp_path)   # another process, reading the saved cache
    assert again.digest("a.bin", tmp_path / "a.bin", hasher) == digest == file_sha256(tmp_path / "a.bin")
    assert hasher.paths == ["a.bin"]


def test_a_changed_file_is_hashed_again_whatever_its_size_and_mtime(tmp_path, settled):
    path = tmp_path / "a.bin"
    path.write_bytes(b"a" * 1000)
    cache, hasher = HashCache(tmp_path), Counting()
    cache.digest("a.bin", path, hasher)
    stat = os.stat(path)
    time.sleep(0.05)   # past the file system's clock tick
    path.write_bytes(b"b" * 1000)   # same size, and the modification time set back
    os.utime(path, ns=(stat.st_atime_ns, stat.st_mtime_ns))
    assert cache.digest("a.bin", path, hasher) == file_sha256(path)
    assert len(hasher.paths) == 2
    replaced = tmp_path / "new.bin"
    replaced.write_bytes(b"c" * 1000)
    os.replace(replaced, path)   # another file moved in: another inode
    assert cache.digest("a.bin", path, hasher) == file_sha256(path) and len(hasher.paths) == 3


def test_a_file_just_written_is_not_remembered(tmp_path):
    (tmp_path / "a.bin").write_bytes(b"a")
    cache, hasher = HashCache(tmp_path), Counting()
    cache.digest("a.bin", tmp_path / "a.bin", hasher)
    cache.digest("a.bin", tmp_path / "a.bin", hasher)
    cache.save()
    assert len(hasher.paths) == 2 and not (tmp_path / HASHES_FILE).exists()


def test_a_damaged_or_unwritable_cache_is_ignored(tmp_path, settled):
    (tmp_path / "a.bin").write_bytes(b"a")
    (tmp_path / HASHES_FILE).write_text("{not json")
    cache = HashCache(tmp_path)
    assert cache.digest("a.bin", tmp_path / "a.bin", file_sha256) == file_sha256(tmp_path / "a.bin")
    (tmp_path / HASHES_FILE).unlink()
    (tmp_path / HASHES_FILE).mkdir()   # in the way: saving fails quietly
    cache.save()
    assert (tmp_path / HASHES_FILE).is_dir()


def test_an_up_to_date_stage_reads_no_frame_again(tmp_path, settled, monkeypatch):
    session = make_session(tmp_path)
    decode_session(session)
    assert normals_session(session, method="lambert", show_progress=False) is not None
    hasher = Counting()
    monkeypatch.setattr(session_module, "file_sha256", hasher)
    again = Session.open(session.root)
    assert normals_session(again, method="lambert", show_progress=False) is None   # up to date
    assert hasher.paths == []
    frame = again.linear_path(again.manifest["frames"][0])
    time.sleep(0.05)
    frame.write_bytes(frame.read_bytes())   # rewritten, the same bytes: hashed again, still current
    assert normals_session(again, method="lambert", show_progress=False) is None
    assert hasher.paths == [frame.name]


def test_a_capture_changed_behind_the_cache_still_stops_decode(tmp_path, settled):
    session = make_session(tmp_path)
    decode_session(session)   # every capture hashed and remembered
    frame = session.manifest["frames"][0]
    raw = session.path(frame["file"])
    stat = os.stat(raw)
    data = bytearray(raw.read_bytes())
    data[-1] ^= 1
    time.sleep(0.05)
    raw.write_bytes(bytes(data))   # same size, the modification time put back
    os.utime(raw, ns=(stat.st_atime_ns, stat.st_mtime_ns))
    with pytest.raises(SessionError, match="does not match its sha256"):
        decode_session(Session.open(session.root), force=True)
