"""Ctrl-C of ``psrig run --jobs N`` (a process pool) and ``--scheduler local`` (Dask) prints
one line, ``psrig run: interrupted``: no worker prints a traceback (the terminal sends SIGINT
to the whole process group, workers included)."""

import os
import signal

import pytest

from pipeline.core.session import Session
from tests.pipeline.decode.test_interrupt import decoded, psrig, raw_session, wait_for


def interrupted_run(tmp_path, *extra):
    """Interrupt a batch of a small session and a big one once the small one is done: one
    worker is then idle (waiting for work) and the other busy."""
    small = raw_session(tmp_path / "small", frames=2, shape=(64, 64))
    big = raw_session(tmp_path / "big", frames=40, shape=(512, 512))
    proc = psrig("run", small, big, "--to", "decode", "-q", *extra, start_new_session=True)

    def small_done_big_started():
        record = (Session.open(small).stage("decode") or {}) if decoded(big) else {}
        return record.get("status") == "ok"
    wait_for(small_done_big_started, proc, timeout=180, what="the small session decoded")
    os.killpg(proc.pid, signal.SIGINT)
    out, err = proc.communicate(timeout=120)
    return proc.returncode, err


def test_ctrl_c_of_a_process_pool_batch_is_one_line(tmp_path):
    code, err = interrupted_run(tmp_path, "--jobs", "2")
    assert code == 130 and err.strip() == "psrig run: interrupted", err


def test_ctrl_c_of_a_dask_batch_is_one_line(tmp_path):
    pytest.importorskip("distributed")
    code, err = interrupted_run(tmp_path, "--jobs", "2", "--scheduler", "local")
    assert code == 130 and err.strip() == "psrig run: interrupted", err


def test_an_idle_decode_worker_ignores_ctrl_c(capfd):
    """Between two batches (the dark frames, then the lit ones) decode's workers wait for work;
    a Ctrl-C to the terminal's group reached them there and each printed a traceback."""
    import time

    from pipeline.decode.pool import start_pool

    with start_pool(2) as pool:
        pids = {pool.submit(os.getpid).result(timeout=60) for _ in range(4)}
        for pid in pids:
            os.kill(pid, signal.SIGINT)
        time.sleep(0.5)
        assert pool.submit(os.getpid).result(timeout=60) in pids   # the pool still works
    err = capfd.readouterr().err
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err


def test_ctrl_c_while_psrig_starts_is_one_line(tmp_path):
    """Ctrl-C while Python imports psrig and its commands, or its workers' fork server starts."""
    import subprocess
    import sys
    import time

    from tests.pipeline.decode.test_interrupt import REPO

    root = raw_session(tmp_path / "s", frames=4, shape=(64, 64))
    for delay in (0.05, 0.1, 0.15, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0):
        # up to when the workers' fork server imports its modules
        proc = subprocess.Popen([sys.executable, "-m", "pipeline", "decode", str(root), "--force"], cwd=REPO,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
        time.sleep(delay)
        os.killpg(proc.pid, signal.SIGINT)
        out, err = proc.communicate(timeout=60)
        assert "Traceback" not in err and len(err.strip().splitlines()) <= 1, (delay, err)
