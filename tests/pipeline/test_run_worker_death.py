"""``psrig run --jobs N`` survives a worker process that dies (the OOM killer, ``kill -9``): that
session is named as failed with the signal, the others finish, the exit status says one failed,
and no traceback is printed.

The CLI runs in a subprocess started from a script that replaces a stage of
``pipeline.runner.RUNNERS``: the worker processes' fork server imports the script as its main
module, so the workers run the replaced stage too."""

import os
import subprocess
import sys
from pathlib import Path

from pipeline.core.session import Session
from tests.pipeline.tiny_session import make_session

REPO = Path(__file__).resolve().parents[2]

SCRIPT = '''
import os, signal, sys
from pipeline import runner
from pipeline.cli import main

real = runner.RUNNERS["decode"]


def decode(session, options, force, jobs):
    if session.root.name == "victim":
        os.kill(os.getpid(), signal.SIGKILL)
    return real(session, options, force, jobs)


runner.RUNNERS["decode"] = decode
if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
'''


def test_a_worker_killed_by_sigkill_fails_its_session_only(tmp_path):
    roots = [make_session(tmp_path, name).root for name in ("first", "victim", "third", "fourth")]
    script = tmp_path / "killer.py"
    script.write_text(SCRIPT)
    env = {**os.environ, "PYTHONPATH": str(REPO), "PSRIG_PROGRESS": "off"}
    done = subprocess.run([sys.executable, str(script), "run", *map(str, roots), "--jobs", "2", "--to", "decode"],
                          capture_output=True, text=True, env=env, cwd=tmp_path, timeout=300)
    assert done.returncode == 1, done.stderr
    assert "Traceback" not in done.stderr + done.stdout, done.stderr
    assert "BrokenProcessPool" not in done.stderr + done.stdout
    victim = roots[1]
    errors = [line for line in done.stderr.splitlines() if line.strip()]
    assert errors == [f"psrig run: error: {victim}: worker died: killed by signal 9 (SIGKILL); the stages it "
                      "finished are kept, run it again to go on"], done.stderr
    for root in roots[:1] + roots[2:]:
        assert f"{root}: decode: ran in" in done.stdout, done.stdout
        assert Session.open(root).stage("decode")["status"] == "ok"
    assert Session.open(victim).stage("decode") is None
