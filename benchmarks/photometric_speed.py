"""Photometric stereo speed on the real shared objects, against a plain Lambertian solve; memory.

    python benchmarks/photometric_speed.py [DILIGENT_DIR] [--repeat 3] [--workers N] [--big-mp 4]
                                           [--big-lights 50] [--skip-big] [--stage] [--against REV]

1. Every DiLiGenT object found (ball, cat, reading, ...): the default estimator's wall and
   process CPU seconds (best of ``--repeat``), each next to the plain baseline run in the same
   process just before each run, a BLAS Lambertian solve ``np.linalg.pinv(L) @ I`` over the
   masked pixels (best of 7 before each of the ``--repeat`` runs), and the ratio of the bests
   (target: within 100x). The machines are shared and noisy: the ratio, not the seconds, is the
   figure to compare; the load average is printed. Beside it, the median over the repeats of
   each run's ratio to the baseline timed just before it (``pairs``): the best of 7 x repeat
   baselines against the best of ``--repeat`` runs favours the baseline on a noisy machine.
2. With ``--stage``: the whole ``normals`` stage as a user runs it, per object: each object
   imported (``psrig import diligent``) and run to its normals once, then ``psrig normals S
   --force`` timed (best wall of ``--repeat``, its own process, as the command line runs it),
   with the stage record's ``timings`` (read, solve, registration, prediction, write) and the
   ratio of the stage to its own solve. ``--against REV`` runs the same from a ``git archive``
   of revision REV in a folder of its own (its own import, sessions and process) and prints the
   ratio of the two stages' wall times (the issue's target: at most 2 x).
3. A large synthetic stack (``--big-mp`` megapixels x ``--big-lights`` lights): peak traced memory
   beyond the input stack, as a ratio to it (target: peak < 2 x input). ``--big-mp 24`` for the
   24-megapixel check (slow).
"""

import argparse
import os
import subprocess
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np

from pipeline.core.session import Session
from pipeline.experiments.synthetic import cook_torrance_images, hemisphere_lights, sphere_normals
from pipeline.importers import read_diligent
from pipeline.photometric import estimate_normals, kernels

from diligent import git_archive, pinv_seconds  # the one baseline, beside this script

TARGET_RATIO = 100


def timed(images, lights, mask, repeat, workers, valid=None):
    """Best wall and CPU seconds of the default estimator, the last result, the baseline's best
    seconds, timed just before each run (so that both see the same minutes of a shared machine:
    measured once beforehand, ball's baseline alone moved 0.7-1.5 ms between runs), and the
    median over the runs of each one's wall time over the baseline timed before it."""
    walls, cpus, baselines = [], [], []
    for _ in range(repeat):
        baselines.append(pinv_seconds(images, lights, mask))
        start, cpu = time.perf_counter(), time.process_time()
        result = estimate_normals(images, lights, mask, workers=workers, valid=valid)
        walls.append(time.perf_counter() - start)
        cpus.append(time.process_time() - cpu)
    return result, min(walls), min(cpus), min(baselines), float(np.median(np.array(walls) / np.array(baselines)))


def load_average():
    return " ".join(f"{v:.2f}" for v in os.getloadavg()) if hasattr(os, "getloadavg") else "n/a"


def real_objects(folder, repeat, workers):
    print(f"{'object':8} {'pixels':>7} {'lights':>6} {'pinv ms':>8} {'default s':>9} {'cpu s':>6} "
          f"{'x pinv':>7} {'pairs':>6}  anchor")
    worst = 0.0
    for path in sorted(p for p in Path(folder).iterdir() if (p / "filenames.txt").is_file()):
        obj = read_diligent(path)
        images, valid = obj.load_images()
        result, wall, cpu, baseline, pairs = timed(images, obj.directions, obj.mask, repeat, workers, valid)
        ratio = wall / baseline
        worst = max(worst, ratio)
        print(f"{obj.name:8} {int(obj.mask.sum()):7d} {len(images):6d} {baseline * 1e3:8.2f} {wall:9.3f} {cpu:6.2f} "
              f"{ratio:7.0f} {pairs:6.0f}  {result.options.get('anchor', '-')}", flush=True)
    verdict = "PASS" if worst <= TARGET_RATIO else "MISS"
    print(f"worst ratio {worst:.0f}x pinv(L) @ I (target {TARGET_RATIO}x): {verdict}")


ROOT = Path(__file__).resolve().parents[1]


def checkout(rev, folder):
    """The code of revision ``rev`` (its pipeline, rig and calibration packages) under ``folder``."""
    return git_archive(rev, folder, "pipeline", "rig", "calibration", who="photometric_speed")


def psrig(code, *args):
    """Run ``python -m pipeline ARGS`` on the code in ``code``; its wall seconds."""
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "pipeline", *map(str, args)], cwd=code, capture_output=True,
                          text=True, env=dict(os.environ, PYTHONPATH=str(code)))
    if done.returncode:
        sys.exit(f"photometric_speed: psrig {' '.join(map(str, args))} ({code}): {done.stderr.strip()[-400:]}")
    return time.perf_counter() - start


def stage_seconds(code, source, folder, repeat):
    """Best wall seconds of ``psrig normals S --force`` on ``source`` imported with ``code``, and
    the record's timings of that run."""
    session = Path(folder) / source.name
    psrig(code, "import", "diligent", source, session)
    psrig(code, "run", session, "--to", "normals")
    best, timings = np.inf, {}
    for _ in range(repeat):
        seconds = psrig(code, "normals", session, "--force")
        if seconds < best:
            best, timings = seconds, Session.open(session).stage("normals").get("timings", {})
    return best, timings


def whole_stage(folder, repeat, against):
    """Print each object's normals stage (see the module docstring, 2.)."""
    objects = sorted(p for p in Path(folder).iterdir() if (p / "filenames.txt").is_file())
    with tempfile.TemporaryDirectory(prefix="psrig-speed-") as scratch:
        old_code = checkout(against, Path(scratch) / "old") if against else None
        for source in objects:
            (Path(scratch) / "new").mkdir(exist_ok=True)
            wall, timings = stage_seconds(ROOT, source, Path(scratch) / "new", repeat)
            parts = " ".join(f"{k} {v:.2f}" for k, v in timings.items() if isinstance(v, (int, float)))
            solve = timings.get("solve")
            line = f"{source.name:12} stage {wall:6.2f} s ({parts}; stage / solve {wall / solve:.1f})" if solve \
                else f"{source.name:12} stage {wall:6.2f} s"
            if old_code is not None:
                (Path(scratch) / "old-sessions").mkdir(exist_ok=True)
                old_wall, _ = stage_seconds(old_code, source, Path(scratch) / "old-sessions", repeat)
                line += f"  {against}: {old_wall:6.2f} s, now / then {wall / old_wall:.2f} (target <= 2)"
            print(line, flush=True)


def large_stack(megapixels, lights_count, workers):
    side = int(np.sqrt(megapixels * 1e6))
    normals, mask = sphere_normals(side)
    lights = hemisphere_lights(lights_count, seed=3, min_elevation_deg=15)
    stack = cook_torrance_images(normals, mask, lights, roughness=0.4)
    start = time.perf_counter()
    estimate_normals(stack, lights, mask, workers=workers)
    seconds = time.perf_counter() - start
    tracemalloc.start()
    estimate_normals(stack, lights, mask, workers=workers)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    print(f"large stack: {side}x{side} px ({int(mask.sum())} masked) x {lights_count} lights, input "
          f"{stack.nbytes / 2**20:.0f} MiB: {seconds:.1f} s; peak extra memory {peak / 2**20:.0f} MiB = "
          f"{peak / stack.nbytes:.2f} x input (peak total {1 + peak / stack.nbytes:.2f} x, target < 2 x)")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("data", nargs="?", default=str(Path(__file__).resolve().parents[2] / "shared/data/diligent"))
    parser.add_argument("--repeat", type=int, default=3, help="timed runs per object; the best is reported")
    parser.add_argument("--workers", type=int, default=None, help="threads (default: all cores)")
    parser.add_argument("--big-mp", type=float, default=4.0)
    parser.add_argument("--big-lights", type=int, default=50)
    parser.add_argument("--skip-big", action="store_true", help="only the real objects")
    parser.add_argument("--stage", action="store_true", help="also time the whole normals stage per object")
    parser.add_argument("--against", metavar="REV", help="with --stage: the same stage from git revision REV")
    args = parser.parse_args(argv)
    kernels.kernels()   # compiled (or loaded from the cache) before anything is timed
    print(f"load average before: {load_average()}")
    real_objects(args.data, args.repeat, args.workers)
    print(f"load average after: {load_average()}")
    if args.stage or args.against:
        whole_stage(args.data, args.repeat, args.against)
    if not args.skip_big:
        large_stack(args.big_mp, args.big_lights, args.workers)


if __name__ == "__main__":
    main()
