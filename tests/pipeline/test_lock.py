"""The session lock: one writer at a time, named to the others, never stale, and the workers of
a command acting under its lock."""

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from pipeline.core import lock
from pipeline.cli import main
from pipeline.core.lock import SessionLocked
from pipeline.core.session import Session
from tests.pipeline.tiny_session import make_session

REPO = Path(__file__).resolve().parents[2]
# takes a session's lock like a command would, says so in a file, then holds it
HOLDER = ("import sys, time\n"
          "from pipeline.core.session import Session\n"
          "s = Session.open(sys.argv[1], writer=sys.argv[2])\n"
          "open(sys.argv[3] + '.tmp', 'w').write(s.lock.token)\n"
          "import os; os.replace(sys.argv[3] + '.tmp', sys.argv[3])\n"
          "time.sleep(float(sys.argv[4]))\n")


def hold(root, command, seconds, tmp_path):
    """A process holding ``root``'s lock for ``command`` during ``seconds``; (Popen, token)."""
    ready = tmp_path / f"held-{time.monotonic_ns()}"
    proc = subprocess.Popen([sys.executable, "-c", HOLDER, str(root), command, str(ready), str(seconds)],
                            cwd=REPO)
    deadline = time.monotonic() + 60  # generous: the machine may be loaded
    while not ready.exists():
        if proc.poll() is not None or time.monotonic() > deadline:
            proc.kill()
            pytest.fail(f"the lock holder did not start (exit {proc.poll()})")
        time.sleep(0.02)
    return proc, ready.read_text()


@pytest.fixture
def holder_procs():
    procs = []
    yield procs
    for proc in procs:
        if proc.poll() is None:
            proc.kill()
        proc.wait(timeout=30)


def test_a_second_writer_gets_one_line_naming_the_holder(tmp_path, capsys, holder_procs):
    root = make_session(tmp_path).root
    proc, _ = hold(root, "capture", 120, tmp_path)
    holder_procs.append(proc)
    for command in (["run", str(root), "--force"], ["decode", str(root)], ["report", str(root)],
                    ["eval", str(root)]):
        assert main(command) == 1, command
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1, err
        assert re.search(rf"psrig capture \(pid {proc.pid} on .+, since \d{{4}}-\d\d-\d\dT", err[0]), err
        assert "--wait" in err[0] and "Traceback" not in err[0]
    assert not (root / "linear" / "object_000.exr").exists()  # nothing was written
    assert Session.open(root).stage("decode") is None


def test_a_killed_holder_leaves_no_stale_lock(tmp_path, holder_procs):
    root = make_session(tmp_path).root
    proc, _ = hold(root, "run", 120, tmp_path)
    holder_procs.append(proc)
    assert lock.holder(root).pid == proc.pid
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    assert lock.holder(root) is None
    assert main(["decode", str(root)]) == 0


def test_wait_waits_for_the_holder_to_finish(tmp_path, capsys, holder_procs):
    root = make_session(tmp_path).root
    proc, _ = hold(root, "normals", 2.0, tmp_path)
    holder_procs.append(proc)
    started = time.monotonic()
    assert main(["decode", str(root), "--wait"]) == 0
    assert proc.poll() is not None, "decode ran while the other command held the session"
    assert time.monotonic() - started > 0.5
    err = capsys.readouterr().err
    assert "waiting for psrig normals" in err and err.count("waiting") == 1


def test_a_second_forced_run_while_one_runs_is_refused(tmp_path):
    """Two `psrig run --force` at once both ran. The first is frozen (SIGSTOP) once it has
    decoded, so that the second surely starts while the first is still at work."""
    root = make_session(tmp_path).root
    run = [sys.executable, "-m", "pipeline", "run", str(root), "--force"]
    first = subprocess.Popen(run, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        for line in first.stdout:
            if "decode: ran" in line:
                break
        first.send_signal(signal.SIGSTOP)
        second = subprocess.run(run + ["--to", "decode"], cwd=REPO, capture_output=True, text=True, timeout=300)
        first.send_signal(signal.SIGCONT)
        first.stdout.read()
        assert first.wait(timeout=300) == 0
    finally:
        if first.poll() is None:
            first.send_signal(signal.SIGCONT)
            first.kill()
            first.wait()
    assert second.returncode == 1, second.stdout
    assert f"is being written by psrig run (pid {first.pid}" in second.stderr
    assert Session.open(root).stage("report")["status"] == "ok"


def test_a_library_write_under_a_held_lock_is_refused(tmp_path, holder_procs):
    session = make_session(tmp_path)
    proc, _ = hold(session.root, "capture", 120, tmp_path)
    holder_procs.append(proc)
    reader = Session.open(session.root)  # reading needs no lock
    reader.manifest["rig"]["note"] = "edited"
    with pytest.raises(SessionLocked, match=f"psrig capture \\(pid {proc.pid}"):
        reader.save()
    assert "note" not in Session.open(session.root).manifest["rig"]


def test_workers_act_under_the_holders_token_only_while_it_lives(tmp_path, holder_procs):
    session = make_session(tmp_path)
    proc, token = hold(session.root, "run", 120, tmp_path)
    holder_procs.append(proc)
    lock.act_under(session.root, "not-the-token")
    worker = Session.open(session.root)
    with pytest.raises(SessionLocked, match="no longer holds"):
        worker.save()
    lock.act_under(session.root, token)
    worker.manifest["rig"]["note"] = "by a worker"
    worker.save()
    assert Session.open(session.root, writer="run").swept == {}  # acting under it: no sweep
    proc.kill()
    proc.wait(timeout=30)
    with pytest.raises(SessionLocked, match="no longer holds"):
        worker.save()
    assert Session.open(session.root).manifest["rig"]["note"] == "by a worker"


def test_the_lock_is_reentrant_in_a_process_and_released_with_the_session(tmp_path):
    root = make_session(tmp_path).root
    first = Session.open(root, writer="run")
    second = Session.open(root, writer="decode")
    assert lock.holder(root).command == "run"
    second.release()
    assert lock.holder(root) is not None
    del first
    assert lock.holder(root) is None


def test_read_only_commands_need_no_lock(tmp_path, capsys, holder_procs):
    root = make_session(tmp_path).root
    proc, _ = hold(root, "run", 120, tmp_path)
    holder_procs.append(proc)
    assert main(["rigs"]) == 0
    assert "sim" in capsys.readouterr().out


def test_workers_import_this_psrig_whatever_the_working_folder(tmp_path):
    """Run from a folder holding a ``pipeline`` of its own (here an older checkout's flat
    layout), every decode worker imported that one and died: 'decoder crashed' for each frame
    and the workers' tracebacks on the terminal."""
    root = make_session(tmp_path).root
    checkout = tmp_path / "old-checkout"
    (checkout / "pipeline").mkdir(parents=True)
    (checkout / "pipeline" / "__init__.py").write_text("")
    (checkout / "pipeline" / "decode.py").write_text("raise ImportError('the other pipeline')\n")
    # a script, as the installed `psrig` is: its own folder leads sys.path, not the working one
    script = tmp_path / "bin" / "psrig_main.py"
    script.parent.mkdir()
    script.write_text("import sys\nfrom pipeline.cli import main\nif __name__ == '__main__':\n    sys.exit(main())\n")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")])))
    done = subprocess.run([sys.executable, str(script), "decode", str(root), "--jobs", "2", "--force"],
                          cwd=checkout, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "Traceback" not in done.stderr
