"""Golden-section minimisation of a unimodal function, batched over arrays of intervals."""

import numpy as np

__all__ = ["golden_section", "golden_steps"]

GOLDEN = (np.sqrt(5.0) - 1.0) / 2.0


def golden_section(func, lo, hi, steps):
    """Minimise ``func`` over [lo, hi] by ``steps`` golden-section steps; returns the argmin.

    ``lo``, ``hi`` are scalars or arrays of one shape (one interval per element); ``func`` maps
    such an array of points to their values. Each step shrinks the intervals by GOLDEN (0.618)
    and costs one call of ``func``, after two to start.
    """
    c = hi - GOLDEN * (hi - lo)
    d = lo + GOLDEN * (hi - lo)
    fc, fd = func(c), func(d)
    for _ in range(steps):
        left = fc <= fd
        hi = np.where(left, d, hi)
        lo = np.where(left, lo, c)
        new = np.where(left, hi - GOLDEN * (hi - lo), lo + GOLDEN * (hi - lo))
        fnew = func(new)
        c, d = np.where(left, new, d), np.where(left, c, new)
        fc, fd = np.where(left, fnew, fd), np.where(left, fc, fnew)
    return np.where(fc <= fd, c, d)


def golden_steps(width, tol):
    """Steps that shrink an interval of ``width`` to at most ``tol``."""
    return max(0, int(np.ceil(np.log(tol / width) / np.log(GOLDEN)))) if width > tol else 0
