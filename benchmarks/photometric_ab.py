"""The default estimator of the working tree against a git revision's, in one process.

    python benchmarks/photometric_ab.py REV [DILIGENT_DIR] [--repeat 12] [--objects ball,reading]

On a shared machine the time of one run moves by 20-50 % from minute to minute, and a ratio to
``pinv(L) @ I`` moves with the baseline (on ball 0.4-1.2 ms within an hour), so two versions
timed minutes apart cannot be told apart by a few percent. Here both run in the same process on
the same stacks, alternately (which goes first swaps every repeat), and what is printed is the
median over the repeats of new / old for each pair of neighbouring runs: the drift of the
machine cancels within a pair. Also printed: whether the two give identical normals, and each
version's median wall time and its ratio to the baseline timed alongside.

REV's ``pipeline`` package is taken with ``git archive`` into a temporary folder and imported
under another name (``pipeline_rev``); this works because the package imports itself only
relatively (checked: a revision that does otherwise is refused). Its kernels compile on its
first run, untimed: the copy is new each time, so numba's on-disk cache never has them.
"""

import argparse
import importlib
import re
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from pipeline.importers import read_diligent
from pipeline.photometric import estimate_normals

from diligent import git_archive, pinv_seconds  # the one baseline, beside this script

ROOT = Path(__file__).resolve().parents[1]
NAME = "pipeline_rev"


def load_revision(rev, folder):
    """``estimate_normals`` of revision ``rev``'s pipeline, unpacked into ``folder``."""
    git_archive(rev, folder, "pipeline", who="photometric_ab")
    package = Path(folder) / NAME
    (Path(folder) / "pipeline").rename(package)
    absolute = re.compile(r"^\s*(from|import)\s+pipeline\b", re.MULTILINE)
    for path in package.rglob("*.py"):
        if absolute.search(path.read_text()):
            sys.exit(f"photometric_ab: {rev}: {path.relative_to(folder)} imports pipeline absolutely; "
                     "it cannot be loaded beside the working tree")
    sys.path.insert(0, str(folder))
    return importlib.import_module(f"{NAME}.photometric").estimate_normals


def compare(name, images, valid, lights, mask, old, repeat):
    """Print one object's line (see the module docstring); ``valid`` the saturation flags."""
    same = np.array_equal(old(images, lights, mask, valid=valid).normals,
                          estimate_normals(images, lights, mask, valid=valid).normals)
    times = {"old": [], "new": []}
    baselines = []
    for i in range(repeat):
        order = (("old", old), ("new", estimate_normals)) if i % 2 else (("new", estimate_normals), ("old", old))
        for key, run in order:
            start = time.perf_counter()
            run(images, lights, mask, valid=valid)
            times[key].append(time.perf_counter() - start)
        baselines.append(pinv_seconds(images, lights, mask))
    old_s, new_s, base = np.array(times["old"]), np.array(times["new"]), float(np.median(baselines))
    print(f"{name:8} identical normals {str(same):5}  "
          f"old {np.median(old_s):6.3f} s ({np.median(old_s) / base:4.0f} x)  "
          f"new {np.median(new_s):6.3f} s ({np.median(new_s) / base:4.0f} x)  pinv {base * 1e3:5.2f} ms  "
          f"new / old {np.median(new_s / old_s):.3f} (pairs {np.percentile(new_s / old_s, 25):.3f}-"
          f"{np.percentile(new_s / old_s, 75):.3f})", flush=True)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("rev", help="the git revision to compare with (e.g. HEAD, main~3)")
    parser.add_argument("data", nargs="?", default=str(ROOT.parent / "shared/data/diligent"))
    parser.add_argument("--repeat", type=int, default=12, help="pairs of runs per object")
    parser.add_argument("--objects", default="", help="comma-separated object names (default: every one found)")
    args = parser.parse_args(argv)
    wanted = {name for name in args.objects.split(",") if name}
    with tempfile.TemporaryDirectory(prefix="psrig-ab-") as folder:
        old = load_revision(args.rev, folder)
        for path in sorted(p for p in Path(args.data).iterdir() if (p / "filenames.txt").is_file()):
            obj = read_diligent(path)
            if wanted and obj.name not in wanted:
                continue
            # saturated observations left out, as the command line does
            compare(obj.name, *obj.load_images(), obj.directions, obj.mask, old, args.repeat)


if __name__ == "__main__":
    main()
