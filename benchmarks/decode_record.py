"""What recording an interrupted decode's progress costs (docs/sessions.md).

Runs ``decode_session(force=True)`` three ways, interleaved in one process (so the machine's
load hits them alike), ``--repeat`` rounds, and prints the medians and their ratios to a run
that records only at the end: the default (a save after a frame unless the last one was less
than ``RECORD_SHARE`` save-durations ago), a save after every frame, and one save.

    python benchmarks/decode_record.py [--repeat 4] [--jobs 2]
"""

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from pipeline.decode import decode_session
from pipeline.decode import stage as decode_stage
from pipeline.core.dng import write_dng
from pipeline.core.session import Session

CASES = {"24 frames of 1 MP": (24, (1024, 1024)), "66 frames of 64 x 96": (66, (64, 96))}
WAYS = {"default": decode_stage.RECORD_SHARE, "every frame": 0, "once": 1e12}


def make_session(root, frames, shape):
    rng = np.random.default_rng(7)
    session = Session.create(root, writer="benchmark")
    base = rng.integers(600, 9000, size=shape, dtype=np.uint16)
    session.add_frame("dark", write_dng(np.full(shape, 512, np.uint16)), save=False)
    for light in range(frames):
        session.add_frame("object", write_dng(base + np.uint16(light)), light=light, save=False)
    session.save()
    return session


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=4)
    parser.add_argument("--jobs", type=int, default=2)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        for name, (frames, shape) in CASES.items():
            session = make_session(Path(folder) / name.replace(" ", "_"), frames, shape)
            decode_session(session, jobs=args.jobs, force=True, progress=False)  # warm-up
            times = {way: [] for way in WAYS}
            for _ in range(args.repeat):
                for way, share in WAYS.items():
                    decode_stage.RECORD_SHARE = share
                    start = time.perf_counter()
                    decode_session(session, jobs=args.jobs, force=True, progress=False)
                    times[way].append(time.perf_counter() - start)
            once = statistics.median(times["once"])
            print(f"{name}: " + ", ".join(f"{way} {statistics.median(t):.3f} s "
                                          f"({statistics.median(t) / once:.2f}x)" for way, t in times.items()))


if __name__ == "__main__":
    main()
