"""Decode speed on 12-megapixel DNGs (4000 x 3000) against the 0.3 s-per-frame target.

Prints seconds per frame for decode_frame alone (each path), for writing its outputs, and the
frames per second of ``decode_session`` with the process pool (``--jobs``, default 2).

    /work/venv/bin/python benchmarks/decode.py [--frames 4] [--jobs 2] [--repeat 3]
"""

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from pipeline.decode import decode_frame, decode_session
from pipeline.dng import write_dng, write_dng_file
from pipeline.decode_pool import write_saturation
from pipeline.imageio import write_image
from pipeline.session import Session

TARGET = 0.3  # seconds per 12 MP frame on the unbiased (mosaic) path
SHAPE = (3000, 4000)


def mosaic(seed):
    """A noisy 14-bit Bayer mosaic with a few clipped photosites."""
    rng = np.random.default_rng(seed)
    values = rng.normal(3000, 800, SHAPE).clip(0, 16383).astype(np.uint16)
    values[::997, ::991] = 16383
    return values


def best_of(repeat, function):
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        result = function()
        times.append(time.perf_counter() - start)
    return min(times), result


def frame_timings(folder, repeat):
    path = Path(folder) / "frame.dng"
    write_dng_file(path, mosaic(0), black_level=(512, 510, 514, 509))
    for method, binning in (("mosaic", 1), ("mosaic", 2), ("postprocess", 1), ("postprocess", 2)):
        seconds, (linear, saturated, _) = best_of(
            repeat, lambda: decode_frame(path, method=method, binning=binning))
        print(f"decode_frame {method:11s} bin {binning}: {seconds:.3f} s/frame "
              f"({seconds / TARGET:.2f} x target), output {linear.shape}")
        write_s, _ = best_of(repeat, lambda: (write_image(Path(folder) / "out.exr", linear, compression="none"),
                                              write_saturation(Path(folder) / "out_sat.png", saturated)))
        print(f"  + writing EXR (uncompressed) and mask: {write_s:.3f} s")


def session_timing(folder, frames, jobs, binning):
    session = Session.create(Path(folder) / f"session_{jobs}_{binning}")
    for light in range(frames):
        session.add_frame("object", write_dng(mosaic(light + 1)), light=light)
    start = time.perf_counter()
    record = decode_session(session, jobs=jobs, binning=binning, progress=False)
    seconds = time.perf_counter() - start
    assert record["status"] == "ok", record["failed"]
    print(f"decode_session {frames} frames, jobs {jobs}, bin {binning}: {seconds:.2f} s, "
          f"{frames / seconds:.2f} frames/s, {seconds / frames:.3f} s/frame "
          f"({seconds / frames / TARGET:.2f} x target)")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=4)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    print(f"cores {os.cpu_count()}, load average before {os.getloadavg()[0]:.2f} "
          "(other processes on the machine slow every figure below)")
    with tempfile.TemporaryDirectory(prefix="psrig-bench-decode-") as folder:
        frame_timings(folder, args.repeat)
        for binning in (1, 2):
            session_timing(folder, args.frames, args.jobs, binning)
        session_timing(folder, args.frames, 1, 1)
    print(f"load average after {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
