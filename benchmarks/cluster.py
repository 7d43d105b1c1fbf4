"""Tiled photometric stereo on a Dask LocalCluster: throughput per worker, speed-up, peak memory.

    python benchmarks/cluster.py [--megapixels 24] [--lights 50] [--workers 1,2]
                                 [--fraction 1.0] [--tile-pixels 262144] [--dir DIR]

A synthetic stack (``--megapixels`` x ``--lights``, glossy bumps under a 35-degree light cone,
so the biquadratic method fits its shared shape) is written to DIR/normals/.tiles/ as the
memory-mapped scratch stack of :mod:`pipeline.cluster_tiles`, one block of rows at a time. The
shared context is fitted once; then, for each worker count, a fresh LocalCluster (one thread per
worker) solves the first ``--fraction`` of the tiles. Printed per run: pixels, seconds,
pixels/s per worker, each worker's peak resident memory (VmHWM, includes the mapped stack pages
it touched), the speed-up over the first worker count (target: near 2 from 1 to 2 workers; peak
per worker < 2 GB), and, because the cores are shared with other users, the share of a core
each worker actually got and the speed-up per core received (pixels per CPU-second of all
workers over the first run's per worker). ``--fraction`` < 1 keeps the run short on a shared machine;
every tile is the same kind of work, so throughput does not depend on it.
"""

import argparse
import logging
import os
import resource
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np


from pipeline.photometric import SCRATCH, TilePlan, plan_solve, run_tile
from pipeline.photometric.engine import CHUNK_SIZE
from pipeline.photometric.tiles import frame_check, pixel_tiles, tile_context

BLOCK_ROWS = 64


def cone_lights(count, degrees=35.0):
    """(K, 3) unit directions on a spiral inside a cone around +z."""
    k = np.arange(count) + 0.5
    polar = np.radians(degrees) * np.sqrt(k / count)
    azimuth = k * np.pi * (3 - np.sqrt(5))
    return np.stack([np.sin(polar) * np.cos(azimuth), np.sin(polar) * np.sin(azimuth), np.cos(polar)], -1)


def bump_normals(rows, width, period=200.0):
    """Unit normals (R, W, 3) of a field of smooth bumps for image rows ``rows``."""
    yy, xx = np.meshgrid(rows.astype(np.float32), np.arange(width, dtype=np.float32), indexing="ij")
    gx = 0.6 * np.cos(2 * np.pi * xx / period) * np.sin(2 * np.pi * yy / period)
    gy = 0.6 * np.sin(2 * np.pi * xx / period) * np.cos(2 * np.pi * yy / period)
    n = np.stack([-gx, -gy, np.ones_like(gx)], -1)
    return n / np.linalg.norm(n, axis=-1, keepdims=True)


def write_synthetic(folder, height, width, lights):
    """stack.npy (K, H, W) float32, valid.npy, mask.npy in ``folder``, BLOCK_ROWS rows at a time."""
    k = len(lights)
    stack = np.lib.format.open_memmap(folder / "stack.npy", "w+", np.float32, (k, height, width))
    valid = np.lib.format.open_memmap(folder / "valid.npy", "w+", bool, (k, height, width))
    half = lights + np.array([0.0, 0.0, 1.0])
    half /= np.linalg.norm(half, axis=1, keepdims=True)
    for r0 in range(0, height, BLOCK_ROWS):
        n = bump_normals(np.arange(r0, min(r0 + BLOCK_ROWS, height)), width)
        diffuse = np.clip(np.einsum("rwc,kc->krw", n, lights.astype(np.float32)), 0, None)
        gloss = np.clip(np.einsum("rwc,kc->krw", n, half.astype(np.float32)), 0, None) ** 30
        block = np.clip(0.6 * diffuse + 0.3 * gloss * (diffuse > 0), 0, 1)
        stack[:, r0:r0 + len(n)] = block
        valid[:, r0:r0 + len(n)] = block < 1
    stack.flush()
    valid.flush()
    np.save(folder / "mask.npy", np.ones((height, width), bool))


def _reusable(folder, shape):
    try:
        return np.load(folder / "stack.npy", mmap_mode="r").shape == shape and (folder / "mask.npy").is_file()
    except (OSError, ValueError):
        return False


def _peak_mb():
    """This process's peak resident memory (VmHWM), in MB.

    Not ru_maxrss: Linux carries the parent's resident size at fork into the child's
    ru_maxrss across exec, so a worker forked from a process that wrote the stack would
    report the whole stack.
    """
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def run(plan, tiles, workers):
    from distributed import Client, LocalCluster

    for path in plan.scratch().glob("tile-*.npz"):
        path.unlink()
    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None,
                      silence_logs=logging.ERROR) as cluster, Client(cluster) as client:
        cpu = client.run(time.process_time)  # workers up before timing
        start = time.perf_counter()
        futures = [client.submit(run_tile, plan, tile, pure=False) for tile in tiles]
        client.gather(futures)
        seconds = time.perf_counter() - start
        used = client.run(time.process_time)
        peaks = sorted(client.run(_peak_mb).values())
    # CPU seconds each worker got per wall second: below 1 when other users hold the cores
    shares = sorted((used[w] - cpu[w]) / seconds for w in used)
    return seconds, peaks, shares


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--megapixels", type=float, default=24.0)
    parser.add_argument("--lights", type=int, default=50)
    parser.add_argument("--workers", default="1,2")
    parser.add_argument("--fraction", type=float, default=1.0, help="share of the tiles solved per run")
    parser.add_argument("--tile-pixels", type=int, default=1 << 18)
    parser.add_argument("--dir", type=Path, help="scratch folder, kept and reused when it holds a stack "
                                                 "of this size (default: a temporary one, removed)")
    args = parser.parse_args(argv)
    width = int(round(np.sqrt(args.megapixels * 1e6 * 1.5)))
    height = int(round(args.megapixels * 1e6 / width))
    root = Path(args.dir or tempfile.mkdtemp(prefix="psrig-cluster-bench-"))
    folder = root / SCRATCH
    folder.mkdir(parents=True, exist_ok=True)
    try:
        lights = cone_lights(args.lights)
        start = time.perf_counter()
        if not _reusable(folder, (args.lights, height, width)):
            write_synthetic(folder, height, width, lights)
        stack_gb = args.lights * height * width * 5 / 1e9
        print(f"stack {height} x {width} x {args.lights} lights ({stack_gb:.1f} GB on disk, float32 + valid) "
              f"ready in {time.perf_counter() - start:.0f} s")
        mask = np.load(folder / "mask.npy")
        solve = frame_check(folder, mask, plan_solve("biquadratic", lights, {}))
        options = solve.options
        start = time.perf_counter()
        context = tile_context(folder, mask, solve)
        print(f"shared context fitted once in {time.perf_counter() - start:.1f} s "
              f"(shape prior {'on' if context else 'off'}, selection {options['selection']})")
        chunk = CHUNK_SIZE
        tiles = pixel_tiles(mask, args.tile_pixels, chunk)
        chosen = tiles[:max(1, int(round(len(tiles) * args.fraction)))]
        pixels = sum(tile[4] for tile in chosen)
        plan = TilePlan(str(root), solve, context, (height, width), tiles, chunk)
        del mask
        print(f"{len(chosen)} of {len(tiles)} tiles, {pixels / 1e6:.2f} Mpx solved per run")
        base = base_cpu = None
        for workers in (int(w) for w in args.workers.split(",")):
            seconds, peaks, shares = run(plan, chosen, workers)
            rate = pixels / seconds
            per_cpu = rate / max(sum(shares), 1e-9)  # pixels per CPU-second, all workers
            base, base_cpu = base or rate, base_cpu or per_cpu / workers
            print(f"workers {workers}: {seconds:.1f} s, {rate / workers:,.0f} px/s per worker, "
                  f"{rate:,.0f} px/s total, speed-up {rate / base:.2f} "
                  f"(per core received: {per_cpu / base_cpu:.2f}), "
                  f"peak RSS per worker {', '.join(f'{p:.0f}' for p in peaks)} MB (target < 2048), "
                  f"core share per worker {', '.join(f'{c:.2f}' for c in shares)}, "
                  f"load average {os.getloadavg()[0]:.1f}")
    finally:
        if args.dir is None:
            shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    main()
