"""Read time of the decoded frames' EXR against their compression: what the normals stage pays.

    python benchmarks/exr_codecs.py FRAME.png [FRAME.png ...] [--repeat 3] [--threads 1]

Each 16-bit frame becomes the float32 RGB frame decode writes for it (linear, / 65535), written
by psrig's own encoder (:mod:`pipeline.decode.exr`: 'none' and 'zip', ISA-L level 1, what
``psrig decode`` writes) and by OpenImageIO with each lossless codec OpenEXR offers (none, rle,
zips, zip, piz). Per codec: bytes against the raw floats, the write seconds (one thread) and
the read seconds, wall and CPU (this process, OpenEXR's threads included), through
:func:`pipeline.core.imageio.read_image_native` (best of ``--repeat``,
OpenEXR's own thread pool set to ``--threads``; the normals stage reads frames with a thread
pool of its own, see :func:`pipeline.photometric.stage.read_workers`), summed over the frames.
"""

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import OpenImageIO as oiio

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pipeline.decode.exr import ExrBuffer, encode_exr  # noqa: E402
from pipeline.core.imageio import read_image, read_image_native, write_image  # noqa: E402

CODECS = ("psrig-none", "psrig-zip", "none", "rle", "zips", "zip", "piz")


def write(path, pixels, codec):
    if codec.startswith("psrig-"):
        exr = ExrBuffer(pixels.shape[0], pixels.shape[1], ("R", "G", "B"))
        exr.fill(pixels, ("R", "G", "B"))
        data, _ = encode_exr(exr, codec.split("-")[1])
        Path(path).write_bytes(data if isinstance(data, bytes) else data.tobytes())
    else:
        write_image(path, pixels, compression=codec)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("frames", nargs="+", type=Path)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--threads", type=int, default=1, help="OpenEXR's threads (exr_threads)")
    args = parser.parse_args()
    oiio.attribute("exr_threads", args.threads)
    frames = [read_image(path)[:, :, :3] for path in args.frames]
    raw = sum(f.nbytes for f in frames)
    print(f"{len(frames)} frames {frames[0].shape[1]} x {frames[0].shape[0]}, {raw / 1e6:.0f} MB of floats; "
          f"exr_threads {args.threads}")
    print(f"{'codec':11} {'ratio':>6} {'write s':>8} {'read s':>7} {'read MB/s':>9} {'read CPU s':>10}")
    with tempfile.TemporaryDirectory() as folder:
        for codec in CODECS:
            paths = [Path(folder) / f"{codec}-{i}.exr" for i in range(len(frames))]
            start = time.perf_counter()
            for path, pixels in zip(paths, frames):
                write(path, pixels, codec)
            wrote = time.perf_counter() - start
            reads, cpus = [], []
            for _ in range(args.repeat):
                start, cpu = time.perf_counter(), time.process_time()
                for path, pixels in zip(paths, frames):
                    back = read_image_native(path)
                reads.append(time.perf_counter() - start)
                cpus.append(time.process_time() - cpu)
            assert np.array_equal(back, pixels), codec   # lossless
            size = sum(p.stat().st_size for p in paths)
            print(f"{codec:11} {raw / size:6.2f} {wrote:8.2f} {min(reads):7.2f} {raw / min(reads) / 1e6:9.0f} "
                  f"{min(cpus):10.2f}",
                  flush=True)


if __name__ == "__main__":
    main()
