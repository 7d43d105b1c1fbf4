"""``--gamma auto`` for 8-bit image frames that declare no transfer: decided from the data.

An 8-bit file without colour metadata may hold sRGB-encoded values (what cameras and editors
write) or linear ones (many capture rigs and datasets). Under the photometric model the object
frames of a session, linearised correctly, form a pixels x lights matrix of rank 3 over the
observations that are lit, unshadowed and unsaturated (``I = albedo * n . l``). Each candidate
transfer (:data:`CANDIDATES`) is scored by how well a rank-3 factorisation ``B S`` (fitted by
alternating weighted least squares over the kept observations, with two rounds of outlier
rejection for highlights and cast shadows) explains the codes: the RMS residual in 8-bit code
levels of ``encode(B S)`` against the stored codes. Residuals are compared in code space, where
every candidate sees the same observations with the same quantisation.

Why in decode and why a rank test: decode is where codes become linear values (after it, an
ambient or dark frame has been subtracted and the codes cannot be recovered), and a sphere
session's lights are calibrated from the decoded frames, so decode cannot wait for lights. A
rank-3 test needs no lights.

What the test can and cannot tell (docs/decoding.md has the figures): linear data read as sRGB
(or any power law) leave a residual 1.7x to 4.6x that of linear on DiLiGenT objects, a clear
verdict; sRGB data read as linear fit only a little worse than sRGB on objects that are not
Lambertian (specular, interreflections): the per-pixel factorisation absorbs much of a
power law. So sRGB stays unless another candidate explains the stack :data:`MIN_RATIO` times
better; below that the choice is a guess, and said so.
"""

import numpy as np

from ..core.gamma import encode_gamma, inverse_gamma_lut
from .transfer import describe_transfer

__all__ = ["CANDIDATES", "MIN_RATIO", "MIN_FRAMES", "rank3_scores", "decide", "decide_transfer",
           "read_codes"]

#: transfers compared; sRGB is the default kept when the evidence is weak
CANDIDATES = ("linear", "srgb", 1.8, 2.2, 2.4)
#: another candidate replaces sRGB only when its residual is this many times smaller
MIN_RATIO = 1.3
#: fewer object frames than this cannot test rank 3 (3 unknowns per pixel + slack)
MIN_FRAMES = 6
#: pixels sampled for the test, and the grid the frames are read on (pixels, at most)
SAMPLED_PIXELS = 2000
_GRID_PIXELS = 200_000
_PAIRS = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))


def read_codes(paths):
    """8-bit codes of the frames on a regular subgrid: (F, N, C) uint8.

    The frames are read one at a time and strided to at most ``_GRID_PIXELS`` pixels, so a
    stack of 12 MP frames costs about 60 MB per 100 frames.
    """
    from .image import read_native

    planes, step = [], None
    for path in paths:
        native = read_native(path)[0]
        if step is None:
            step = max(1, int(np.ceil(np.sqrt(native.shape[0] * native.shape[1] / _GRID_PIXELS))))
        sub = native[::step, ::step, :min(3, native.shape[2])]
        planes.append(sub.reshape(-1, sub.shape[2]))
    return np.stack(planes)


def _solve(weights, basis, data):
    """Per-row weighted least squares: rows of ``data`` (N, F) ~ x (N, 3) @ basis.T (3, F)."""
    products = np.stack([basis[:, i] * basis[:, j] for i, j in _PAIRS], axis=1)   # (F, 6)
    upper = weights @ products                                                    # (N, 6)
    normal = np.empty((len(upper), 3, 3))
    for k, (i, j) in enumerate(_PAIRS):
        normal[:, i, j] = normal[:, j, i] = upper[:, k]
    normal += 1e-9 * np.eye(3)
    right = (weights * data) @ basis
    return np.linalg.solve(normal, right[..., None])[..., 0]


def _rank3_residual(linear, code, keep, transfer, offset=0.0, iterations=12):
    """RMS code-level residual of the best rank-3 fit of ``linear`` (P, F) minus ``offset``
    (P, 1: the pixel's linearised ambient or dark level) over ``keep``."""
    # weights: squared slope of code against linear value, so the fit minimises code error
    eps = 1e-3
    slope = (encode_gamma(np.clip(linear + eps, 0, 1), transfer)
             - encode_gamma(np.clip(linear - eps, 0, 1), transfer)) / (2 * eps)
    weight = slope.astype(np.float64) ** 2
    linear = linear - offset
    _, _, vt = np.linalg.svd(np.where(keep, linear, 0.0), full_matrices=False)
    lights = vt[:3].T
    for iteration in range(iterations):
        w = keep * weight
        normals = _solve(w, lights, linear)
        lights = _solve(w.T, normals, linear.T)
        if iteration in (iterations // 3, 2 * iterations // 3):
            # highlights and cast shadows are not rank 3: drop what is far off the fit
            off = np.abs(encode_gamma(np.clip(normals @ lights.T + offset, 0, 1), transfer) - code)
            spread = 1.4826 * np.median(off[keep])
            keep = keep & (off <= 2.5 * spread + 2 / 255)
    off = encode_gamma(np.clip(normals @ lights.T + offset, 0, 1), transfer) - code
    return float(np.sqrt(np.mean(off[keep] ** 2)) * 255)


def rank3_scores(codes, *, reference=None, pixels=SAMPLED_PIXELS, seed=0):
    """Rank-3 residual of each candidate transfer.

    Parameters
    ----------
    codes : ndarray (F, N, C) uint8
        The object frames' codes (F lights, N pixels, C channels).
    reference : ndarray (R, N, C) uint8, optional
        Ambient (else dark) frames' codes: their mean, linearised by each candidate, is the
        part of every observation that no light explains (decode subtracts it too).
    pixels : int
        Pixels sampled among the well-lit ones.

    Returns
    -------
    scores : dict
        {candidate: RMS residual in 8-bit code levels}.
    used : dict
        ``pixels`` and ``observations`` the test used.
    """
    frames = codes.shape[0]
    saturated = (codes == 255).any(axis=2)                  # (F, N)
    level = codes.mean(axis=2, dtype=np.float32)            # code of the grey value
    top = np.where(saturated, 0, level).max(axis=0)         # brightest unsaturated code per pixel
    lit = np.flatnonzero(top >= 40)
    if lit.size < 50:
        return None, {"pixels": int(lit.size), "observations": 0}
    chosen = np.random.default_rng(seed).choice(lit, min(pixels, lit.size), replace=False)
    chosen.sort()
    # the same observations for every candidate: chosen on the codes (transfers are monotonic),
    # the upper half of each pixel's range, away from shadow edges and dark noise
    keep = (~saturated[:, chosen].T) & (level[:, chosen].T >= np.maximum(0.5 * top[chosen][:, None], 16))
    rows = keep.sum(axis=1) >= min(6, frames)
    chosen, keep = chosen[rows], keep[rows]
    if chosen.size < 50:
        return None, {"pixels": int(chosen.size), "observations": int(keep.sum())}
    sample = codes[:, chosen]                               # (F, P, C)
    code = (sample.mean(axis=2, dtype=np.float64) / 255.0).T
    scores = {}
    for transfer in CANDIDATES:
        lut = inverse_gamma_lut(transfer, 256)
        linear = lut[sample].mean(axis=2, dtype=np.float64).T
        offset = 0.0 if reference is None else \
            lut[reference[:, chosen]].mean(axis=(0, 2), dtype=np.float64)[:, None]
        scores[transfer] = _rank3_residual(linear, code, keep, transfer, offset)
    return scores, {"pixels": int(chosen.size), "observations": int(keep.sum())}


def decide(scores):
    """(transfer, guess, ratio, against): the candidate that explains the stack best, unless
    it beats sRGB by less than :data:`MIN_RATIO` (then sRGB, a guess). ``ratio`` is how many
    times better the chosen one fits than ``against`` (the runner-up: sRGB, or linear when
    sRGB is chosen)."""
    best = min(scores, key=scores.get)
    if best != "srgb" and scores["srgb"] >= MIN_RATIO * scores[best]:
        return best, False, scores["srgb"] / scores[best], "srgb"
    against = best if best != "srgb" else "linear"
    ratio = scores[against] / scores["srgb"]
    return "srgb", ratio < MIN_RATIO, ratio, against


def decide_transfer(paths, references=()):
    """Decide the transfer of 8-bit object frames that declare none.

    Parameters
    ----------
    paths : list of Path
        The object frames (one per light), :data:`MIN_FRAMES` or more.
    references : list of Path
        The ambient (else dark) frames decode subtracts from them, 8-bit files that declare
        no transfer too (else leave them out).

    Returns
    -------
    dict or None
        ``transfer`` (chosen), ``guess`` (True: the data did not tell; sRGB kept), ``ratio``,
        ``against``, ``scores`` ({name: RMS residual, code levels}), ``frames``, ``pixels``,
        ``observations``, ``why`` (for the frame info) and ``message`` (the line printed).
        None when there are too few frames or too few well-lit pixels to test.
    """
    if len(paths) < MIN_FRAMES:
        return None
    reference = read_codes(references) if references else None
    scores, used = rank3_scores(read_codes(paths), reference=reference)
    if scores is None:
        return None
    transfer, guess, ratio, against = decide(scores)
    named = {describe_transfer(t): round(s, 3) for t, s in scores.items()}
    chosen, other = describe_transfer(transfer), describe_transfer(against)
    figures = f"rank-3 residual {scores[transfer]:.2f} vs {scores[against]:.2f} code levels"
    if guess:
        listed = ", ".join(f"{describe_transfer(t)} {s:.2f}" for t, s in sorted(scores.items(), key=lambda i: i[1]))
        figures = f"rank-3 residual in code levels {listed}: none {MIN_RATIO:g}x below sRGB's"
        why = f"assumed: the data do not tell ({figures})"
        message = (f"8-bit frames without colour metadata: the data do not tell the transfer ({figures}); "
                   "decoded as sRGB, a guess; give --gamma if you know it")
    else:
        why = f"chosen from the data: {chosen} explains the stack {ratio:.1f}x better than {other}"
        message = (f"8-bit frames without colour metadata: {chosen} explains the stack {ratio:.1f}x better "
                   f"than {other} ({figures}); decoded as {chosen}")
    return {"transfer": transfer, "guess": guess, "ratio": round(float(ratio), 3), "against": against,
            "scores": named, "frames": len(paths), **used, "why": why, "message": message}
