"""Per-frame camera capture overhead through the real PtpCamera and the simulated USB camera.

Rendering is excluded: the simulated sensor returns precomputed bytes (default 20 MB), so the
time measured is the PTP/USB path only: trigger, events, GetObjectInfo, chunked GetObject,
size check, DeleteObject. Target: under 20 ms per frame.

    /work/venv/bin/python benchmarks/capture_overhead.py [--mb 20] [--frames 10]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

from rig.camera import PtpCamera
from rig.sim.usb_camera import make_backend

TARGET_MS = 20.0


def measure(behaviour: str, payload: bytes, frames: int, chunk: int) -> list[float]:
    """Milliseconds per capture() for ``frames`` captures (after one warm-up)."""
    backend = make_backend(lambda: payload, behaviour=behaviour)
    times = []
    with PtpCamera(backend=backend, chunk_size=chunk) as cam:
        cam.capture()
        for _ in range(frames):
            t0 = time.perf_counter()
            img = cam.capture()
            times.append((time.perf_counter() - t0) * 1000.0)
            if img.size != len(payload):
                raise SystemExit(f"{behaviour}: got {img.size} bytes, expected {len(payload)}")
    return times


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mb", type=float, default=20.0, help="object size in MB (1e6 bytes)")
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--chunk", type=int, default=1 << 20, help="bulk read size in bytes")
    args = ap.parse_args(argv)
    payload = os.urandom(int(args.mb * 1e6))
    worst = 0.0
    print(f"object {len(payload) / 1e6:.1f} MB, {args.frames} frames, chunk {args.chunk} B")
    for behaviour in ("generic", "canon", "nikon"):
        t = measure(behaviour, payload, args.frames, args.chunk)
        med = statistics.median(t)
        worst = max(worst, med)
        print(f"{behaviour:8s} median {med:6.2f} ms/frame  min {min(t):6.2f}  max {max(t):6.2f}"
              f"  ({len(payload) / med / 1e3:6.0f} MB/s)  ratio to {TARGET_MS:g} ms target "
              f"{med / TARGET_MS:.2f}")
    print(f"worst median {worst:.2f} ms/frame: {'PASS' if worst < TARGET_MS else 'FAIL'}")
    return 0 if worst < TARGET_MS else 1


if __name__ == "__main__":
    raise SystemExit(main())
