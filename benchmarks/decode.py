"""Decode speed and disk on 12-megapixel DNGs (4000 x 3000) against the 0.3 s-per-frame target.

Prints, best of ``--repeat`` (wall and CPU seconds; CPU = time.process_time of this process,
threads included): decode_frame alone (each path); one pool task (decode into the EXR bytes,
sha256, write + fsync + rename of EXR and mask) as a worker runs it; and ``decode_session``
(``--jobs``, default 2; a forced rerun of the same session, so the pool start-up is included
every time; the first run of the process also boots the fork server, which later runs
reuse). Session CPU is this process only with the pool: the workers' CPU is another
process's (see the jobs 1 line for the whole CPU cost of a frame). Every session line also
gives the EXR bytes per frame and how the frames were written (``--compression``, default auto:
ZIP where a sample shrinks by a quarter); ``--compare`` times auto, zip and none in turn in
this process, so their ratios share the machine's load.

A bracketed session (``--bracket`` alone, or last in a full run): the same scene's ``--frames``
lights each shot at 1/60 and 1/15 s (the long exposure 4 x the signal, clipped at white) and
decoded with their merges, against the same lights shot once, decoded in turn in this process
(``--repeat`` rounds): seconds per light, the ratio, and the EXR bytes per light.

    python benchmarks/decode.py [--frames 4] [--jobs 2] [--repeat 3] [--compression auto] [--compare] [--bracket]
"""

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from pipeline.decode import decode_frame, decode_session
from pipeline.core.dng import write_dng, write_dng_file
from pipeline.decode.pool import decode_task
from pipeline.core.session import Session

TARGET = 0.3  # seconds per 12 MP frame on the unbiased (mosaic) path
SHAPE = (3000, 4000)


def mosaic(seed):
    """A noisy 14-bit Bayer mosaic with a few clipped photosites."""
    rng = np.random.default_rng(seed)
    values = rng.normal(3000, 800, SHAPE).clip(0, 16383).astype(np.uint16)
    values[::997, ::991] = 16383
    return values


def best_of(repeat, function, walls=None):
    """(best wall s, best CPU s, last result) over ``repeat`` calls; every wall time is
    appended to ``walls`` when given."""
    walls, cpus = [] if walls is None else walls, []
    for _ in range(repeat):
        start, cpu = time.perf_counter(), time.process_time()
        result = function()
        walls.append(time.perf_counter() - start)
        cpus.append(time.process_time() - cpu)
    return min(walls), min(cpus), result


def frame_timings(folder, repeat):
    path = Path(folder) / "frame.dng"
    write_dng_file(path, mosaic(0), black_level=(512, 510, 514, 509))
    for method, binning in (("mosaic", 1), ("mosaic", 2), ("postprocess", 1), ("postprocess", 2)):
        seconds, cpu, (linear, _, _) = best_of(
            repeat, lambda: decode_frame(path, method=method, binning=binning))
        print(f"decode_frame {method:11s} bin {binning}: {seconds:.3f} s/frame, CPU {cpu:.3f} s "
              f"({seconds / TARGET:.2f} x target), output {linear.shape}")
        task = {"id": "frame", "source": str(path), "linear": str(Path(folder) / "out.exr"),
                "saturation": str(Path(folder) / "out_sat.png"), "size": linear.shape[:2],
                "options": {"method": method, "channels": "rgb", "binning": binning,
                            "gamma": "auto", "compression": "auto"}}
        task_s, task_cpu, _ = best_of(repeat, lambda: decode_task(task))
        print(f"  pool task (decode + sha256 + atomic EXR and mask): {task_s:.3f} s, "
              f"CPU {task_cpu:.3f} s")


def session_timing(folder, frames, jobs, binning, repeat, compression="auto"):
    root = Path(folder) / f"session_{jobs}_{binning}"
    session = Session.open(root) if root.is_dir() else Session.create(root)
    for light in range(len(session.frames()), frames):
        session.add_frame("object", write_dng(mosaic(light + 1)), light=light)
    walls = []
    seconds, cpu, record = best_of(repeat, lambda: decode_session(
        session, jobs=jobs, binning=binning, progress=False, force=True, compression=compression), walls)
    assert record["status"] == "ok", record["failed"]
    written = ", ".join(f"{n} {kind}" for kind, n in sorted(record["compression"].items()))
    print(f"decode_session {frames} frames, jobs {jobs}, bin {binning}, compression {compression}: "
          f"{seconds:.2f} s, {frames / seconds:.2f} frames/s, {seconds / frames:.3f} s/frame "
          f"({seconds / frames / TARGET:.2f} x target); CPU of this process "
          f"{cpu / frames:.3f} s/frame; EXR {record['linear_bytes'] / frames / 1e6:.1f} MB/frame ({written}); "
          "every run: " + " ".join(f"{wall / frames:.3f}" for wall in walls) + " s/frame")


BRACKET = (("1/60", 1), ("1/15", 4))   # shutter as recorded, and the light it gathers


def bracketed_session(root, frames):
    """``frames`` lights, each at every shutter of :data:`BRACKET` (the signal above black
    scaled, clipped at white): frames ``object_<k>_b<n>`` with their ``bracket`` entries."""
    session = Session.create(root)
    for light in range(frames):
        signal = mosaic(light + 1).astype(np.int64) - 512
        for n, (shutter, gain) in enumerate(BRACKET):
            data = write_dng(np.clip(512 + signal * gain, 0, 16383).astype(np.uint16))
            session.add_frame("object", data, light=light, frame_id=f"object_{light:03d}_b{n}", save=False,
                              bracket={"group": f"object_{light:03d}", "index": n, "shutter": shutter,
                                       "of": len(BRACKET)})
    session.save()
    return session


def bracket_timing(folder, frames, jobs, repeat, compression="auto"):
    """Decode (exposures + merges) of a bracketed session against the same lights shot once."""
    plain = Session.create(Path(folder) / "plain")
    for light in range(frames):
        plain.add_frame("object", write_dng(mosaic(light + 1)), light=light, save=False)
    plain.save()
    sessions = {"single": plain, "bracketed": bracketed_session(Path(folder) / "bracketed", frames)}
    walls = {name: [] for name in sessions}
    records = {}
    for _ in range(repeat):   # interleaved: both see about the same load
        for name, session in sessions.items():
            _, _, records[name] = best_of(1, lambda: decode_session(
                session, jobs=jobs, progress=False, force=True, compression=compression), walls[name])
            assert records[name]["status"] == "ok", records[name]["failed"]
    best = {name: min(times) for name, times in walls.items()}
    merged = records["bracketed"]["merged"]
    taken = np.mean([info["from"][f"{group}_b0"] for group, info in merged.items()])
    print(f"bracketed decode, {frames} lights x {len(BRACKET)} exposures + {len(merged)} merges, jobs {jobs}: "
          f"{best['bracketed'] / frames:.3f} s per light against {best['single'] / frames:.3f} s shot once: "
          f"{best['bracketed'] / best['single']:.2f} x; EXR {records['bracketed']['linear_bytes'] / frames / 1e6:.1f} "
          f"MB per light against {records['single']['linear_bytes'] / frames / 1e6:.1f}; "
          f"{100 * taken:.1f} % of the pixels from the short exposure; every run (s): "
          + ", ".join(f"{name} " + " ".join(f"{w:.2f}" for w in times) for name, times in walls.items()))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=4)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--compression", default="auto", choices=("auto", "zip", "none"))
    parser.add_argument("--compare", action="store_true",
                        help="only the jobs-N session, with auto, zip and none in turn (--repeat rounds)")
    parser.add_argument("--bracket", action="store_true",
                        help="only the bracketed session against the same lights shot once (--repeat rounds)")
    args = parser.parse_args()
    print(f"cores {os.cpu_count()}, load average before {os.getloadavg()[0]:.2f} "
          "(other processes on the machine slow every figure below)")
    with tempfile.TemporaryDirectory(prefix="psrig-bench-decode-") as folder:
        if args.compare:
            for _ in range(args.repeat):   # interleaved: each round sees about the same load
                for compression in ("auto", "zip", "none"):
                    session_timing(folder, args.frames, args.jobs, 1, 1, compression)
            return
        if args.bracket:
            bracket_timing(folder, args.frames, args.jobs, args.repeat, args.compression)
            return
        frame_timings(folder, args.repeat)
        for binning in (1, 2):
            session_timing(folder, args.frames, args.jobs, binning, args.repeat, args.compression)
        session_timing(folder, args.frames, 1, 1, args.repeat, args.compression)
        bracket_timing(folder, args.frames, args.jobs, args.repeat, args.compression)
    print(f"load average after {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
