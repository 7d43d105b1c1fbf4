"""Capture speed on the simulated rig, through the real drivers and rig.capture.

(a) Overhead per frame with rendering excluded: the simulated sensor returns one precomputed
    DNG of the default scene (360 x 480), so what is timed is the capture's own work per frame:
    the light command over the pty, the PTP capture and download, the atomic raw write (fsync)
    and the manifest update. Target: under 20 ms per frame.
(b) A full capture of the default simulated rig (32 lights: dark, ambient, 32 object and 32
    sphere frames, default scene size), rendering included. Target: under 30 s.
(c) The same rig bracketed, exposure: {bracket: [1/60, 1/15]}: every frame at both shutters
    (132 frames; each simulated exposure lasts its shutter time), printed beside (b).

    /work/venv/bin/python benchmarks/capture.py [--mb MB] [--keep DIR]

``--mb`` replaces the sensor's DNG in (a) by MB megabytes of random bytes, to see how the
overhead grows with a real camera's file size (sha256, write, fsync, USB chunks).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

from rig.capture import capture_session
from rig.config import get_rig, parse_rigs
from rig.sim.rig import SimulatedRig

OVERHEAD_TARGET_MS = 20.0
FULL_TARGET_S = 30.0


def overhead_ms(rig, folder, mb=None, repeats=3):
    """Median over ``repeats`` captures of the milliseconds per frame, rendering excluded."""
    per_frame = []
    for n in range(repeats):
        with SimulatedRig(rig) as sim:
            payload = (sim.scenes["object"].render_dng(0) if mb is None
                       else os.urandom(int(mb * 1e6)))
            sim.backend.camera.render = lambda: payload  # the sensor's output is precomputed
            start = time.perf_counter()
            session = capture_session(folder / f"overhead{n}", rig, sim=sim, progress=False,
                                      echo=lambda line: None)
            per_frame.append((time.perf_counter() - start) * 1000.0 / len(session.frames()))
    return statistics.median(per_frame), len(session.frames()), len(payload)


def full_capture_s(rig, folder):
    """Seconds for a whole capture of the simulated rig (devices opened and closed included)."""
    start = time.perf_counter()
    session = capture_session(folder / "full", rig, progress=False, echo=lambda line: None)
    return time.perf_counter() - start, len(session.frames())


def bracketed_rig(rig):
    """The rig with exposure: {bracket: [1/60, 1/15]} (same lights, camera, frames)."""
    text = f"""
rigs:
  bracketed:
    lights: {{driver: sim, count: {rig.lights.count}, directions: {rig.lights.directions.tolist()}}}
    camera: {{driver: sim, path: generic}}
    exposure: {{bracket: [1/60, 1/15]}}
    frames: {dict(rig.frames)}
"""
    return parse_rigs(text)["bracketed"]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mb", type=float, help="frame size for (a) in MB (default: the scene's DNG)")
    ap.add_argument("--keep", metavar="DIR", help="write the sessions here instead of a temp folder")
    args = ap.parse_args(argv)
    rig = get_rig("sim")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(args.keep or tmp)
        folder.mkdir(parents=True, exist_ok=True)
        ms, frames, size = overhead_ms(rig, folder, args.mb, repeats=1 if args.mb else 3)
        print(f"(a) overhead per frame, rendering excluded ({frames} frames of {size / 1e6:.2f} MB): "
              f"{ms:.1f} ms (target {OVERHEAD_TARGET_MS:.0f} ms, ratio {ms / OVERHEAD_TARGET_MS:.2f})")
        seconds, frames = full_capture_s(rig, folder)
        print(f"(b) full capture of the simulated rig ({frames} frames, default scene): "
              f"{seconds:.2f} s (target {FULL_TARGET_S:.0f} s, ratio {seconds / FULL_TARGET_S:.2f})")
        start = time.perf_counter()
        session = capture_session(folder / "bracketed", bracketed_rig(rig), progress=False,
                                  echo=lambda line: None)
        bracketed = time.perf_counter() - start
        count = len(session.frames())
        print(f"(c) bracketed capture [1/60, 1/15] ({count} frames, simulated exposures "
              f"included): {bracketed:.2f} s, {1000 * bracketed / count:.1f} ms per frame "
              f"({bracketed / seconds:.2f} x (b))")
    return 0


if __name__ == "__main__":
    sys.exit(main())
