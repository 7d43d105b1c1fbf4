"""Capture holds the session lock: nothing else writes a session while it is being captured."""

import os
import subprocess
import sys
import time
from pathlib import Path

import yaml

from pipeline.core.session import Session
from tests.rig.test_capture import RIGS

REPO = Path(__file__).resolve().parents[2]


def test_run_during_a_capture_is_refused_and_the_capture_loses_nothing(tmp_path):
    """The reported case: `psrig run` while `psrig capture --resume` writes the session
    overwrote the capture's manifest (66 frames captured, 43 listed)."""
    rigs = tmp_path / "rigs.yaml"
    rigs.write_text(RIGS, encoding="utf-8")
    root = tmp_path / "s"
    env = {k: v for k, v in os.environ.items() if k != "PSRIG_SIM_FAULTS"}
    # the slow rig's 50 ms exposures make the capture last seconds
    capture = subprocess.Popen([sys.executable, "-m", "pipeline", "capture", str(root), "--rig", "slow",
                                "--config", str(rigs), "--resume"], cwd=REPO, env=env,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        while _frames_listed(root) < 3:  # capturing
            assert capture.poll() is None and time.monotonic() < deadline, capture.communicate()
            time.sleep(0.02)
        run = subprocess.run([sys.executable, "-m", "pipeline", "run", str(root)], cwd=REPO, env=env,
                             capture_output=True, text=True, timeout=300)
        out, err = capture.communicate(timeout=300)
    finally:
        if capture.poll() is None:
            capture.kill()
            capture.wait()
    assert run.returncode == 1, (run.stdout, run.stderr)
    assert "is being written by psrig capture" in run.stderr and "Traceback" not in run.stderr
    assert capture.returncode == 0, err
    session = Session.open(root)
    listed = {f["file"] for f in session.frames()}
    stored = {f"raw/{p.name}" for p in (root / "raw").iterdir() if p.is_file() and not p.name.startswith(".")}
    assert stored == listed and f"{len(listed)} in the session" in out
    assert session.stage("decode") is None  # run wrote nothing


def _frames_listed(root):
    try:
        return len(yaml.safe_load((root / "session.yaml").read_text())["frames"])
    except (OSError, TypeError, KeyError, yaml.YAMLError):
        return 0
