"""``--gamma auto`` on full objects: 8-bit linear and sRGB versions of DiLiGenT ball, cat and
reading (all 96 lights, full frames), and the PSBox object frames as shipped.

    python benchmarks/autotransfer.py [--ambient]

Printed per stack: the true encoding, what auto chose (and whether a guess), the candidates'
rank-3 residuals in 8-bit code levels, and the seconds the decision took (reading included).
``--ambient``: instead, ball (every third light, scaled to 0.85 at the 99.5th percentile) over a
linear pedestal of 0.08, both encodings, decided without and with the pedestal's frame.
"""

import glob
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from pipeline.decode.autotransfer import decide_transfer
from pipeline.core.gamma import encode_gamma
from tests import SHARED_DATA
from tests.pipeline.decode.eightbit import DILIGENT, write_eightbit_diligent


def show(label, files):
    start = time.perf_counter()
    decision = decide_transfer(files)
    scores = ", ".join(f"{name} {value:.2f}" for name, value in decision["scores"].items())
    print(f"{label:18s} -> {decision['transfer']}{' (guess)' if decision['guess'] else ''}: {scores}; "
          f"{decision['pixels']} px, {time.perf_counter() - start:.1f} s", flush=True)


def ambient():
    folder = DILIGENT / "ballPNG"
    names = (folder / "filenames.txt").read_text().split()[::3]
    gains = np.loadtxt(folder / "light_intensities.txt")[::3]
    stack = np.stack([cv2.imread(str(folder / n), cv2.IMREAD_UNCHANGED)[:, :, ::-1].astype(np.float32) / 65535 / g
                      for n, g in zip(names, gains)])
    stack = stack / np.percentile(stack, 99.5) * 0.85
    pedestal = np.full(stack.shape[1:], 0.08, np.float32)
    for truth in ("linear", "srgb"):
        with tempfile.TemporaryDirectory() as folder_name:
            out = Path(folder_name)
            files = []
            for k, frame in enumerate(stack):
                files.append(out / f"{k:03d}.png")
                codes = np.round(encode_gamma(np.clip(frame + pedestal, 0, 1), truth) * 255).astype(np.uint8)
                cv2.imwrite(str(files[-1]), codes[:, :, ::-1])
            cv2.imwrite(str(out / "ambient.png"), np.round(encode_gamma(pedestal, truth) * 255).astype(np.uint8))
            for label, refs in (("without", []), ("with", [out / "ambient.png"])):
                decision = decide_transfer(files, refs)
                scores = ", ".join(f"{n} {v:.2f}" for n, v in decision["scores"].items())
                print(f"ball {truth} + 0.08, {label} the ambient frame -> {decision['transfer']}"
                      f"{' (guess)' if decision['guess'] else ''}: {scores}", flush=True)


def main():
    if "--ambient" in sys.argv[1:]:
        return ambient()
    for name in ("ball", "cat", "reading"):
        for truth in ("linear", "srgb"):
            with tempfile.TemporaryDirectory() as folder:
                show(f"{name} {truth}", write_eightbit_diligent(name, truth, folder))
    show("PSBox Objects", sorted(glob.glob(str(SHARED_DATA / "psbox" / "Objects" / "*.png"))))


if __name__ == "__main__":
    main()
