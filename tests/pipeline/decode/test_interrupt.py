"""Interrupted decodes: Ctrl-C is resumed from the frames already on disk, what a kill leaves
is swept by the next writer, and a SIGKILLed ``psrig run`` leaves no process behind.

These drive real ``psrig`` processes on sessions of a few dozen 1-megapixel DNGs, big enough to
be interrupted mid-decode on a loaded machine; waits are generous but bounded.
"""

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from pipeline.core.dng import write_dng
from pipeline.core.imageio import read_image
from pipeline.core.session import Session

REPO = Path(__file__).resolve().parents[3]
FRAMES = 24
SHAPE = (1024, 1024)


def raw_session(root, frames=FRAMES, shape=SHAPE):
    """A session of one dark frame and ``frames`` object frames (distinct noisy DNGs)."""
    rng = np.random.default_rng(7)
    session = Session.create(root)
    base = rng.integers(600, 9000, size=shape, dtype=np.uint16)
    session.add_frame("dark", write_dng(np.full(shape, 512, np.uint16)), save=False)
    for light in range(frames):
        session.add_frame("object", write_dng(base + np.uint16(light)), light=light, save=False)
    session.save()
    return session.root


def _default_sigint():
    """In a child before exec: Ctrl-C's default disposition. A shell starts a background job
    (``pytest &``, ``nohup``) with SIGINT ignored, and an ignored signal stays ignored across
    exec: Python would then install no KeyboardInterrupt handler and the child would ignore
    the Ctrl-C the test sends."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


@pytest.fixture
def sigint_raises():
    """SIGINT raises KeyboardInterrupt in this process while the test runs (whatever the
    disposition pytest was started with), and is put back after."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


def psrig(*args, **kwargs):
    return subprocess.Popen([sys.executable, "-m", "pipeline", *map(str, args)], cwd=REPO,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **kwargs)


def wait_for(condition, proc, timeout=120, what="condition"):
    deadline = time.monotonic() + timeout
    while not condition():
        if proc.poll() is not None:
            pytest.fail(f"psrig ended (exit {proc.returncode}) before {what}: {proc.communicate()}")
        if time.monotonic() > deadline:
            proc.kill()
            pytest.fail(f"no {what} within {timeout} s")
        time.sleep(0.01)


def decoded(root):
    """Frame ids whose EXR is in linear/ (renamed into place: complete)."""
    return {p.stem for p in (Path(root) / "linear").glob("*.exr") if not p.name.startswith(".")}


def test_ctrl_c_during_the_first_decode_is_resumed(tmp_path):
    root = raw_session(tmp_path / "s")
    proc = psrig("decode", root, "--jobs", "2", start_new_session=True, preexec_fn=_default_sigint)
    wait_for(lambda: len(decoded(root)) >= 4, proc, what="4 decoded frames")
    os.killpg(proc.pid, signal.SIGINT)  # Ctrl-C: the terminal signals the whole process group
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 130 and "interrupted" in err and "Traceback" not in err, err
    done = decoded(root)
    assert not [p.name for p in (root / "linear").iterdir() if p.name.startswith(".")], \
        "Ctrl-C leaves no temporaries behind"
    record = Session.open(root).stage("decode")
    assert record["status"] == "incomplete"
    assert set(record["frames"]) == done, "every frame on disk is recorded"
    assert len(done) < FRAMES + 1, "the decode was interrupted before the end"
    stamps = {f: (root / "linear" / f"{f}.exr").stat().st_mtime_ns for f in done}
    again = psrig("decode", root, "--jobs", "2")
    out, err = again.communicate(timeout=600)
    assert again.returncode == 0, err
    record = Session.open(root).stage("decode")
    assert record["status"] == "ok" and len(record["frames"]) == FRAMES + 1
    assert {f: (root / "linear" / f"{f}.exr").stat().st_mtime_ns for f in done} == stamps, \
        "the frames decoded before Ctrl-C were not decoded again"
    assert not [p for p in (root / "linear").iterdir() if p.name.startswith(".")]


def test_temporaries_a_kill_left_are_swept_by_the_next_command(tmp_path):
    root = raw_session(tmp_path / "s", frames=3, shape=(64, 64))
    proc = psrig("run", root, "--to", "decode")
    assert proc.wait(timeout=300) == 0
    stale = [root / "linear" / ".object_001.a1b2c3.tmp.exr", root / "normals" / ".normals.x7y8.tmp.exr",
             root / "depth" / ".depth.q1w2.tmp.exr", root / "report" / "maps" / ".status.k9.tmp.png",
             root / ".session.abc123.tmp.yaml", root / "normals" / ".tiles" / "stack.npy"]
    for path in stale:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(b"x" * 1000)
    proc = psrig("run", root, "--to", "decode")
    out, err = proc.communicate(timeout=300)
    assert proc.returncode == 0 and "decode: up to date" in out
    assert "removed 6 temporary files" in out, out  # said, not done silently
    assert not any(path.exists() for path in stale)
    assert not (root / "normals" / ".tiles").exists()
    assert (root / ".psrig.lock").exists() and Session.open(root).stage("decode")["status"] == "ok"


# -- orphans ----------------------------------------------------------------------------------

def _processes():
    """{pid: (ppid, start time, state)} of every process, from /proc."""
    table = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            stat = Path(f"/proc/{entry}/stat").read_text()
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2:].split()
        table[int(entry)] = (int(fields[1]), fields[19], fields[0])
    return table


def _descendants(pid):
    table = _processes()
    found, frontier = {}, [pid]
    while frontier:
        parent = frontier.pop()
        for child, (ppid, start, _) in table.items():
            if ppid == parent and child not in found:
                found[child] = start
                frontier.append(child)
    return found


def _alive(pids):
    """Those of {pid: start time} still running (not zombies, not a reused pid)."""
    table = _processes()
    return [pid for pid, start in pids.items()
            if pid in table and table[pid][1] == start and table[pid][2] != "Z"]


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads the process table from /proc")
@pytest.mark.parametrize("kills, sessions", [(0, 1), (1, 1), (2, 1), (0, 2)])
def test_sigkill_of_psrig_run_during_decode_leaves_no_process(tmp_path, kills, sessions):
    """One session: the decode pool; two with --jobs 2: the pool of sessions."""
    roots = [raw_session(tmp_path / f"s{i}") for i in range(sessions)]
    root = roots[0]
    proc = psrig("run", *roots, *(["--jobs", "2"] if sessions > 1 else []))
    family = {}
    try:
        # the fork server, the resource tracker and the decode workers, once they all run
        def started():
            family.update(_descendants(proc.pid))
            return len(family) >= 4 and decoded(root)
        wait_for(started, proc, what="the decode pool at work")
        time.sleep(0.05 * kills)  # a little later into the decode each time
        family.update(_descendants(proc.pid))
        proc.kill()
        proc.wait(timeout=30)
        deadline = time.monotonic() + 20  # "within a few seconds", generous for a loaded machine
        while _alive(family) and time.monotonic() < deadline:
            time.sleep(0.05)
        survivors = _alive(family)
        assert survivors == [], f"still running after the kill: {survivors} of {sorted(family)}"
    finally:
        for pid in _alive(family):  # never leave a process behind, even when failing
            os.kill(pid, signal.SIGKILL)
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    # and the sessions are resumed from there by the next run
    again = psrig("run", *roots, "--to", "decode")
    out, err = again.communicate(timeout=600)
    assert again.returncode == 0, err
    assert all(Session.open(r).stage("decode")["status"] == "ok" for r in roots)


# -- exposure brackets ------------------------------------------------------------------------

SHUTTERS = ("1/60", "1/15")   # as a bracketed capture records them


def bracketed_session(root, groups=12, shape=SHAPE, gain=4):
    """A bracketed session: a dark frame and ``groups`` object frames, each shot at 1/60 and
    1/15 s (the long exposure ``gain`` x the light, clipped at white: 4 as the shutter times
    say)."""
    rng = np.random.default_rng(8)
    session = Session.create(root)
    signal = rng.integers(80, 4500, size=shape).astype(np.int64)   # 1/15 s clips the top fifth

    def add(kind, light, name, mosaic, n):
        bracket = {"group": name, "index": n, "shutter": SHUTTERS[n], "of": len(SHUTTERS)}
        session.add_frame(kind, write_dng(mosaic), light=light, frame_id=f"{name}_b{n}", save=False,
                          bracket=bracket)

    for n, _ in enumerate(SHUTTERS):
        add("dark", None, "dark_000", np.full(shape, 512, np.uint16), n)
    for light in range(groups):
        for n, scale in enumerate((1, gain)):
            add("object", light, f"object_{light:03d}",
                np.minimum(512 + (signal + light) * scale, 16383).astype(np.uint16), n)
    session.save()
    return session.root


@pytest.mark.slow
def test_a_bracketed_decode_killed_mid_way_resumes_from_the_merges_done(tmp_path):
    # The run saves its record every RECORD_SHARE saves' worth of time, so on a busy machine the
    # first record with a merge can come as the last merges finish: the kill then lands on a run
    # that has ended (seen once in a full local run). A session three times as long then leaves
    # the kill a run to stop.
    for groups in (12, 36):
        root = bracketed_session(tmp_path / f"s{groups}", groups=groups)
        pristine = shutil.copytree(root, tmp_path / f"pristine{groups}")
        proc = psrig("decode", root, "--jobs", "2")

        def merges_recorded():   # kill once the record has a merge
            merged = (Session.open(root).stage("decode") or {}).get("merged") or {}
            return any(group.startswith("object") for group in merged)
        wait_for(merges_recorded, proc, what="a merged bracket in the record")
        proc.kill()
        if proc.wait(timeout=30) != 0:   # killed, not ended
            break
    record = Session.open(root).stage("decode")
    assert record["status"] == "incomplete"
    kept = list(record["frames"]) + list(record.get("merged") or {})
    assert any(group.startswith("object") for group in kept), "the run recorded merges before the kill"
    stamps = {f: (root / "linear" / f"{f}.exr").stat().st_mtime_ns for f in kept}
    again = psrig("decode", root)
    out, err = again.communicate(timeout=600)
    assert again.returncode == 0, err
    record = Session.open(root).stage("decode")
    assert record["status"] == "ok" and len(record["merged"]) == groups + 1 and list(record["frames"]) == [
        "dark_000_b0", "dark_000_b1"]
    assert {f: (root / "linear" / f"{f}.exr").stat().st_mtime_ns for f in kept} == stamps, \
        "what was recorded before the kill was neither decoded nor merged again"
    fresh = psrig("decode", pristine)
    assert fresh.wait(timeout=600) == 0
    for group in record["merged"]:
        assert np.array_equal(read_image(root / "linear" / f"{group}.exr"),
                              read_image(pristine / "linear" / f"{group}.exr")), group


def test_a_ctrl_c_inside_a_commit_is_held_until_it_is_reported(sigint_raises):
    # the bookkeeping of a committed frame runs to its end; the Ctrl-C is raised right after
    from pipeline.decode.pool import deferred_interrupt

    steps = []
    with pytest.raises(KeyboardInterrupt):
        with deferred_interrupt():
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.05)   # the signal is delivered here, and held
            steps.append("reported")
        steps.append("after")   # never reached: the held Ctrl-C is raised at the block's end
    assert steps == ["reported"]
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_the_signal_tests_pass_when_started_with_sigint_ignored():
    # what `python -m pytest &` or `nohup` does to a test run: SIGINT ignored from the start
    def ignore_sigint():
        signal.signal(signal.SIGINT, signal.SIG_IGN)

    done = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                           f"{__file__}::test_a_ctrl_c_inside_a_commit_is_held_until_it_is_reported"],
                          cwd=REPO, capture_output=True, text=True, timeout=120, preexec_fn=ignore_sigint)
    assert done.returncode == 0, done.stdout + done.stderr
