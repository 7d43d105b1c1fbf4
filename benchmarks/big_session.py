"""A synthetic N-megapixel x K-light session through every stage of the CLI: time and memory.

    python benchmarks/big_session.py [--mp 4] [--lights 96] [--folder /tmp/psrig-big]
                                     [--stages import,decode,calibrate,lambert,normals,integrate,report]
                                     [--memory SIZE] [--keep] [--force]

Renders a glossy RGB sphere on a dark, slightly noisy background under ``--lights`` known
directions (a hemisphere of elevations 20-80 degrees) into 16-bit PNG frames (cached in
``--folder``/frames-<mp>mp-<lights>, so later runs skip the rendering), then runs, each as its
own ``python -m pipeline`` process: ``import images`` (with the lights file), ``decode``,
``calibrate`` (the imported lights), ``normals --method lambert``, ``normals`` (the default),
``integrate`` and ``report``. Per stage it prints the wall time, the CPU time of the stage's
processes (``wait4``: user + system, every thread and waited-for child; on a loaded shared
machine the steadier figure), the peak RSS of the stage's
process tree (psutil, sampled every 50 ms: the decode workers' memory is summed) and of its
largest single process (``ru_maxrss`` from ``wait4``) and the tree's peak without file-backed
pages (``anon``: RSS less psutil's ``shared``), each against the grey float32 stack
(K x H x W x 4 bytes), and for the normals stages the shares of the stage's record ``timings``
(read, solve, registration, write). Then the issue's targets at this size: ``normals --method
lambert`` / ``decode`` wall (<= 0.5), the default's solve share (>= 75 %), every stage's peak /
grey stack (<= 1.5).

Memory: the normals stage needs about 1.5-2.6 x the grey stack, so 4 MP x 96 lights is the
largest run to start on a shared 24 GB machine.
"""

import argparse
import os
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import psutil

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pipeline.core.atomic import atomic_path  # noqa: E402
from pipeline.core.session import Session  # noqa: E402

STAGES = ("import", "decode", "calibrate", "lambert", "normals", "integrate", "report")
TARGET_LAMBERT = 0.5
TARGET_SOLVE = 0.75
TARGET_PEAK = 1.5


def frame_shape(megapixels):
    """(H, W) of a 4:3 frame of about ``megapixels`` million pixels."""
    width = int(round(np.sqrt(megapixels * 1e6 * 4 / 3) / 8) * 8)
    return int(round(width * 3 / 4 / 8) * 8), width


def hemisphere(count, seed=3):
    """``count`` unit light directions (K, 3) at elevations 20-80 degrees, all azimuths."""
    rng = np.random.default_rng(seed)
    golden = np.pi * (3 - np.sqrt(5))
    azimuth = (np.arange(count) * golden) % (2 * np.pi)
    elevation = np.radians(20 + 60 * rng.random(count))
    return np.stack([np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth),
                     np.sin(elevation)], axis=1)


def render_frames(folder, shape, lights):
    """Write frame-NNN.png (16-bit RGB) of a glossy sphere lit by each of ``lights`` (K, 3) and
    lights.txt; frames already there are kept."""
    folder.mkdir(parents=True, exist_ok=True)
    height, width = shape
    radius = 0.45 * min(shape)
    ys, xs = np.mgrid[0:height, 0:width].astype(np.float32)
    x, y = (xs - width / 2) / radius, (height / 2 - ys) / radius
    inside = x * x + y * y < 1
    normals = np.stack([x[inside], y[inside], np.sqrt(1 - x[inside] ** 2 - y[inside] ** 2)], axis=1)
    # a slow albedo texture, so that the colour channels differ from pixel to pixel
    albedo = (0.55 + 0.25 * np.sin(7 * x[inside]) * np.cos(5 * y[inside]))[:, None] * np.array(
        [0.9, 0.7, 0.5], np.float32)
    np.savetxt(folder / "lights.txt", lights, fmt="%.6f")
    for k, light in enumerate(lights):
        path = folder / f"frame-{k:03d}.png"
        if path.is_file():
            continue
        rng = np.random.default_rng(k)
        half = light + np.array([0, 0, 1.0])
        half /= np.linalg.norm(half)
        shade = np.maximum(normals @ light.astype(np.float32), 0)
        gloss = 0.6 * np.maximum(normals @ half.astype(np.float32), 0) ** 60 * (shade > 0)
        image = rng.standard_normal((height, width, 3), dtype=np.float32)
        image = np.abs(image, out=image) * np.float32(0.002)
        image[inside] += 0.75 * albedo * shade[:, None] + gloss[:, None]
        # the rounding of pipeline.core.imageio.write_image; OpenCV's fast PNG level (a 4 MP frame
        # in a fifth of OpenImageIO's default level's time, for 1 % more bytes)
        pixels = np.clip(np.rint(image * 65535), 0, 65535).astype(np.uint16)
        with atomic_path(path) as tmp:
            if not cv2.imwrite(str(tmp), pixels[:, :, ::-1], [cv2.IMWRITE_PNG_COMPRESSION, 1]):
                sys.exit(f"{path}: cannot write the frame")
        print(f"\rrendered {k + 1}/{len(lights)} frames", end="", flush=True)
    print()


class PeakSampler:
    """Peak summed RSS (bytes) of a process and its descendants, sampled every ``interval`` s;
    ``anon`` the peak of RSS less its file-backed pages (memory-mapped files, which the kernel
    reclaims under pressure: what a memory-mapped stack leaves is no cause for the OOM killer)."""

    def __init__(self, pid, interval=0.05):
        self.pid, self.interval, self.peak, self.anon = pid, interval, 0, 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self):
        try:
            top = psutil.Process(self.pid)
        except psutil.NoSuchProcess:
            return
        while not self._stop.is_set():
            total = anon = 0
            try:
                for proc in [top] + top.children(recursive=True):
                    try:
                        info = proc.memory_info()
                        total, anon = total + info.rss, anon + info.rss - info.shared
                    except psutil.NoSuchProcess:
                        pass
            except psutil.NoSuchProcess:
                return
            self.peak, self.anon = max(self.peak, total), max(self.anon, anon)
            self._stop.wait(self.interval)

    def stop(self):
        self._stop.set()
        self._thread.join()
        return self.peak


def run_stage(args):
    """Run ``python -m pipeline ARGS`` from the repository; (wall s, tree peak bytes, process
    peak bytes). A failing stage stops the benchmark with its output."""
    command = [sys.executable, "-m", "pipeline", *args]
    start = time.perf_counter()
    child = subprocess.Popen(command, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    sampler = PeakSampler(child.pid)
    output = []
    reader = threading.Thread(target=lambda: output.append(child.stdout.read()), daemon=True)
    reader.start()
    _, status, usage = os.wait4(child.pid, 0)
    wall = time.perf_counter() - start
    tree = sampler.stop()
    reader.join()
    child.returncode = os.waitstatus_to_exitcode(status)
    if child.returncode:
        sys.exit(f"`{' '.join(command)}` failed ({child.returncode}):\n{output[0].decode(errors='replace')}")
    return wall, max(tree, usage.ru_maxrss * 1024), usage.ru_maxrss * 1024, usage.ru_utime + usage.ru_stime, \
        sampler.anon


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--mp", type=float, default=4.0, help="megapixels per frame (default 4)")
    parser.add_argument("--lights", type=int, default=96, help="lights, one frame each (default 96)")
    parser.add_argument("--folder", type=Path, default=Path("/tmp/psrig-big"),
                        help="where the frames (cached) and the session go")
    parser.add_argument("--stages", default=",".join(STAGES), help="stages to run, in order")
    parser.add_argument("--memory", help="--memory given to normals and integrate (when the CLI has it)")
    parser.add_argument("--keep", action="store_true", help="keep the session folder afterwards")
    parser.add_argument("--force", action="store_true",
                        help="pass --force to decode, calibrate, normals, integrate and report (a kept session)")
    args = parser.parse_args()
    stages = [s for s in args.stages.split(",") if s]
    unknown = set(stages) - set(STAGES)
    if unknown:
        parser.error(f"unknown stages {sorted(unknown)}; known: {', '.join(STAGES)}")

    shape = frame_shape(args.mp)
    frames = args.folder / f"frames-{shape[0]}x{shape[1]}-{args.lights}"
    render_frames(frames, shape, hemisphere(args.lights))
    session = args.folder / f"session-{shape[0]}x{shape[1]}-{args.lights}"
    if "import" in stages and session.exists():
        shutil.rmtree(session)
    grey = args.lights * shape[0] * shape[1] * 4
    print(f"{shape[1]} x {shape[0]} ({shape[0] * shape[1] / 1e6:.2f} MP) x {args.lights} lights; "
          f"grey float32 stack {grey / 1e9:.2f} GB; load {os.getloadavg()[0]:.2f}; {sys.executable}")
    print(f"stages from {ROOT}")
    memory = ["--memory", args.memory] if args.memory else []
    force = ["--force"] if args.force else []
    commands = {
        "import": ["import", "images", str(session), "--object", str(frames / "frame-*.png"),
                   "--lights", str(frames / "lights.txt")],
        "decode": ["decode", str(session), *force],
        "calibrate": ["calibrate", str(session), *force],
        "lambert": ["normals", str(session), "--method", "lambert", *memory, *force],
        "normals": ["normals", str(session), *memory, *force],
        "integrate": ["integrate", str(session), *memory, *force],
        "report": ["report", str(session), "--no-eval", *force],
    }
    print(f"{'stage':10} {'wall s':>8} {'cpu s':>7} " + " ".join(f"{name:>8} {'x grey':>7}" for name in
                                                         ("tree GB", "proc GB", "anon GB")) + "  timings")
    walls, peaks, shares, cpus, anons = {}, {}, {}, {}, {}
    for stage in stages:
        wall, tree, proc, cpu, anon = run_stage(commands[stage])
        walls[stage], peaks[stage], cpus[stage], anons[stage] = wall, tree, cpu, anon
        note = ""
        if stage in ("lambert", "normals"):
            timings = dict(Session.open(session).stage("normals").get("timings") or {})
            steps = timings.pop("cpu", {})
            shares[stage] = timings.get("solve", 0.0) / wall
            note = " ".join(f"{k} {v:.1f}" for k, v in timings.items()) + \
                f" (solve {shares[stage]:.0%} of the stage's wall"
            if steps:
                note += f", {steps.get('solve', 0) / max(sum(steps.values()), 1e-9):.0%} of its CPU; CPU " + \
                    " ".join(f"{k} {v:.1f}" for k, v in steps.items())
            note += ")"
        sizes = " ".join(f"{size / 1e9:8.2f} {size / grey:7.2f}" for size in (tree, proc, anon))
        print(f"{stage:10} {wall:8.1f} {cpu:7.1f} {sizes}  {note}", flush=True)

    print("targets:")
    if "lambert" in walls and "decode" in walls:
        ratio = walls["lambert"] / walls["decode"]
        print(f"  normals --method lambert / decode wall: {ratio:.2f} (target <= {TARGET_LAMBERT})")
    if "normals" in shares:
        print(f"  default normals: solve share of the stage's wall: {shares['normals']:.0%} "
              f"(target >= {TARGET_SOLVE:.0%})")
    if peaks:
        worst = max(peaks, key=peaks.get)
        print(f"  largest peak / grey stack: {peaks[worst] / grey:.2f} ({worst}; target <= {TARGET_PEAK}); "
              f"without file-backed pages {max(anons.values()) / grey:.2f} ({max(anons, key=anons.get)})")
    per_pixel = {s: (walls[s] / (shape[0] * shape[1] * args.lights) * 1e9, peaks[s] / (shape[0] * shape[1]))
                 for s in walls}
    print("per pixel x light (ns) and peak bytes per pixel:",
          ", ".join(f"{s} {t:.1f} ns {b:.0f} B" for s, (t, b) in per_pixel.items()))
    if not args.keep and "import" in stages:
        shutil.rmtree(session, ignore_errors=True)


if __name__ == "__main__":
    main()
