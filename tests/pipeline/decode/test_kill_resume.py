"""A decode killed (SIGKILL) between finishing frames and recording them: the next run keeps
every frame whose outputs were both in place (their receipts and hashes checked) and decodes
only the others; and a finished frame is recorded within about a second however long a
manifest save takes."""

import os
import signal
import time

import pytest

from pipeline.decode import stage as decode_stage
from pipeline.core.session import Session
from tests.pipeline.decode.test_interrupt import psrig, raw_session


def complete(root):
    """Frame ids with both outputs renamed into place (EXR and saturation mask)."""
    linear = root / "linear"
    return {p.stem for p in linear.glob("*.exr") if not p.name.startswith(".")
            and (linear / f"{p.stem}_sat.png").is_file()}


def keepable(root, listed=None):
    """The frames of :func:`complete` whose receipt was written after the outputs, or recorded
    (``listed``: the receipt is gone then): what the next run may keep. A kill between the
    outputs and the receipt leaves a frame the next run rightly decodes again; on a loaded
    machine that gap is wider than the test's wait."""
    linear = root / "linear"
    return {f for f in complete(root) if (linear / f".{f}.receipt.json").is_file() or f in (listed or ())}


def recorded(root):
    try:
        return set((Session.open(root).stage("decode") or {}).get("frames") or {})
    except Exception:  # noqa: BLE001 - read while psrig writes it: try again
        return None


def test_a_kill_before_the_record_redoes_no_finished_frame(tmp_path):
    for attempt in range(4):
        root = raw_session(tmp_path / f"s{attempt}", frames=24, shape=(512, 512))
        proc = psrig("decode", root, "--jobs", "2", start_new_session=True)
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and proc.poll() is None:
            listed = recorded(root)
            done = keepable(root, listed)
            if listed is not None and len(done) >= 4 and done - listed:
                time.sleep(0.05)   # the receipt follows the outputs by a fraction of a millisecond
                break
            time.sleep(0.005)
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
        listed = recorded(root) or set()
        done = keepable(root, listed)
        if done - listed and len(done) < 25:   # the kill landed between finishing and recording
            break
    else:
        pytest.skip("no kill landed between a frame's outputs and its record in 4 tries")
    stamps = {f: ((root / "linear" / f"{f}.exr").stat().st_mtime_ns,
                  (root / "linear" / f"{f}_sat.png").stat().st_mtime_ns) for f in done}
    again = psrig("decode", root, "--jobs", "2")
    out, err = again.communicate(timeout=600)
    assert again.returncode == 0, err
    record = Session.open(root).stage("decode")
    assert record["status"] == "ok" and len(record["frames"]) == 25
    after = {f: ((root / "linear" / f"{f}.exr").stat().st_mtime_ns,
                 (root / "linear" / f"{f}_sat.png").stat().st_mtime_ns) for f in done}
    redone = sorted(f for f in done if after[f] != stamps[f])
    assert redone == [], f"{len(redone)} finished frames decoded again: {redone} (recorded before the kill: {len(listed)})"
    assert set(record.get("adopted") or []) == done - listed
    assert "were kept (their receipts and outputs' hashes checked)" in out
    assert not [p.name for p in (root / "linear").iterdir() if p.name.startswith(".")], "no receipt left"


def test_a_slow_save_does_not_stretch_the_recording_window(tmp_path, monkeypatch):
    """A save that took 2 s (a loaded disk) would, at RECORD_SHARE saves' worth, leave 40 s of
    frames unrecorded; the window is at most RECORD_INTERVAL. The clock is the stage's own,
    moved by hand: each frame takes 0.2 s, the first save 2 s."""
    from pipeline.decode import decode_session

    root = raw_session(tmp_path / "s", frames=12, shape=(64, 64))
    clock = [0.0]
    monkeypatch.setattr(decode_stage.time, "perf_counter", lambda: clock[0])
    saves = []
    real_record, real_finished = decode_stage._record, decode_stage._Run.finished

    def record(session, frames, run, seconds, status=None):
        saves.append((status, len(run.infos)))
        if len(saves) == 1:
            clock[0] += 2.0
        return real_record(session, frames, run, seconds, status)

    def finished(run, *args):
        clock[0] += 0.2
        return real_finished(run, *args)

    monkeypatch.setattr(decode_stage, "_record", record)
    monkeypatch.setattr(decode_stage._Run, "finished", finished)
    with Session.open(root, writer="decode") as session:
        decode_session(session, jobs=1, progress=False)
    incomplete = [count for status, count in saves if status == "incomplete"]
    # 13 frames 0.2 s apart after a 2 s save: recorded again after 1 s (5 frames), and so on
    assert len(incomplete) >= 3, saves
    assert all(b - a <= 6 for a, b in zip(incomplete, incomplete[1:])), saves


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL], ids=["SIGTERM", "SIGKILL"])
def test_a_killed_decode_prints_no_leaked_semaphore_warning(tmp_path, sig):
    """SIGTERM stops decode as Ctrl-C does (one line, status 143, what is on disk recorded);
    after SIGKILL the resource tracker removes the pool's semaphores without a warning."""
    from tests.pipeline.decode.test_interrupt import decoded, wait_for

    root = raw_session(tmp_path / "s", frames=24, shape=(512, 512))
    proc = psrig("decode", root, "--jobs", "2", start_new_session=True)
    wait_for(lambda: len(decoded(root)) >= 3, proc, what="3 decoded frames")
    os.kill(proc.pid, sig)
    out, err = proc.communicate(timeout=120)
    time.sleep(0.5)   # the resource tracker notices its end
    assert "leaked" not in err and "Traceback" not in err, err
    if sig == signal.SIGTERM:
        assert proc.returncode == 143 and err.strip() == "psrig decode: terminated (SIGTERM)", err
        record = Session.open(root).stage("decode")
        assert record["status"] == "incomplete" and set(record["frames"]) == complete(root)
