"""``--gamma auto`` on full objects: 8-bit linear and sRGB versions of DiLiGenT ball, cat and
reading (all 96 lights, full frames), and the PSBox object frames as shipped.

    python benchmarks/autotransfer.py

Printed per stack: the true encoding, what auto chose (and whether a guess), the candidates'
rank-3 residuals in 8-bit code levels, and the seconds the decision took (reading included).
"""

import glob
import tempfile
import time

from pipeline.decode.autotransfer import decide_transfer
from tests import SHARED_DATA
from tests.pipeline.decode.eightbit import write_eightbit_diligent


def show(label, files):
    start = time.perf_counter()
    decision = decide_transfer(files)
    scores = ", ".join(f"{name} {value:.2f}" for name, value in decision["scores"].items())
    print(f"{label:18s} -> {decision['transfer']}{' (guess)' if decision['guess'] else ''}: {scores}; "
          f"{decision['pixels']} px, {time.perf_counter() - start:.1f} s", flush=True)


def main():
    for name in ("ball", "cat", "reading"):
        for truth in ("linear", "srgb"):
            with tempfile.TemporaryDirectory() as folder:
                show(f"{name} {truth}", write_eightbit_diligent(name, truth, folder))
    show("PSBox Objects", sorted(glob.glob(str(SHARED_DATA / "psbox" / "Objects" / "*.png"))))


if __name__ == "__main__":
    main()
