"""Least-squares normal integration on the pixel grid: the linear system and its solver.

The unknown is one value per masked pixel: the height ``z`` (orthographic, pixel units) or the
log-depth ``log d`` (perspective, intrinsics K). Every pair of 4-neighbouring masked pixels
(i, j), j one step right of or below i, is an *edge*; each end of an edge contributes one
"half-equation" ``z_j - z_i = g`` where ``g`` is that pixel's gradient along the edge's axis,
derived from its normal. Half-equations carry weights (0.5 each for the smooth mode, the
bilateral weights otherwise); the normal equations are a weighted graph Laplacian, solved with
conjugate gradients preconditioned by an algebraic multigrid V-cycle (pyamg, classical
Ruge-Stuben by default).

Because only edges inside the mask enter, any mask shape, holes and several components are
handled; each 4-connected component keeps its own unknown offset.
"""

from dataclasses import dataclass

import numpy as np
import pyamg
import scipy.sparse as sp

#: multigrid flavour used by default (see amg_preconditioner; measured in benchmarks/integrate.py)
AMG_KIND = "rs"

__all__ = ["AMG_KIND", "GridProblem", "build_problem", "assemble", "energy", "solve_spd", "amg_preconditioner",
           "edge_terms"]


@dataclass
class GridProblem:
    """The integration problem over the masked pixels.

    Attributes
    ----------
    index : ndarray (H, W) int64
        Unknown number of each masked pixel, -1 outside the mask.
    edges : list of two (i, j) pairs of int64 arrays (E,)
        Neighbour pairs along image columns (j right of i) and rows (j below i).
    slopes : list of two ndarray (N,)
        Per-pixel target difference ``z(next) - z(this)`` per one-pixel step along each axis.
    scales : list of two ndarray (N,)
        Factor turning a difference of ``z`` into a pixel-scale depth step (``n_z`` or
        ``f * |n . r|``), used by the discontinuity detector.
    confidence : ndarray (N,)
        Extra weight of each pixel's half-equations (1, or the squared steepness factor).
    perspective : bool
        True when ``z`` is log-depth.
    """

    index: np.ndarray
    edges: list
    slopes: list
    scales: list
    confidence: np.ndarray
    perspective: bool

    @property
    def size(self):
        return int(self.confidence.size)


def build_problem(normals, mask, K=None, *, normal_weighting=True):
    """Build the grid problem from unit normals.

    Parameters
    ----------
    normals : ndarray (H, W, 3)
        Unit normals, camera frame (x right, y up, z toward the camera), checked by the caller.
    mask : ndarray (H, W) bool
    K : ndarray (3, 3) or None
        Intrinsics (pixel coordinates: column, row, 0-based); None for orthographic.
    normal_weighting : bool
        Weight each pixel's equations by its squared steepness factor (``n_z**2`` or
        ``(n . r)**2``), i.e. solve the equations multiplied out by the normal, as BiNI does;
        this keeps grazing pixels with huge slopes from dominating.
    """
    index = np.full(mask.shape, -1, dtype=np.int64)
    rows, cols = np.nonzero(mask)
    index[rows, cols] = np.arange(rows.size)
    n = normals[rows, cols].astype(np.float64)
    if K is None:
        slope_col, slope_row = -n[:, 0] / n[:, 2], n[:, 1] / n[:, 2]
        factor = n[:, 2]
        scales = [factor, factor]
    else:
        slope_col, slope_row, factor, scales = _perspective_slopes(n, rows, cols, np.asarray(K, float))
    edges = [_pairs(index, mask, axis=1), _pairs(index, mask, axis=0)]
    confidence = factor ** 2 if normal_weighting else np.ones_like(factor)
    return GridProblem(index, edges, [slope_col, slope_row], scales, confidence, K is not None)


def _perspective_slopes(n, rows, cols, K):
    """Log-depth slopes: n . dP/du = 0 with P = d K^-1 (u, v, 1) gives
    d(log d)/du = -(n . K^-1 e_u) / (n . r), r = K^-1 (u, v, 1), in OpenCV axes."""
    k_inv = np.linalg.inv(K)
    n_cv = n * np.array([1.0, -1.0, -1.0])  # x right, y down, z forward
    pix = np.stack([cols, rows, np.ones_like(rows)], axis=1).astype(np.float64)
    ray = pix @ k_inv.T
    along_ray = np.einsum("ij,ij->i", n_cv, ray)  # < 0 for a surface facing the camera
    slope_col = -(n_cv @ k_inv[:, 0]) / along_ray
    slope_row = -(n_cv @ k_inv[:, 1]) / along_ray
    factor = -along_ray
    return slope_col, slope_row, factor, [factor * K[0, 0], factor * K[1, 1]]


def _pairs(index, mask, axis):
    if axis == 1:
        both = mask[:, :-1] & mask[:, 1:]
        return index[:, :-1][both], index[:, 1:][both]
    both = mask[:-1, :] & mask[1:, :]
    return index[:-1, :][both], index[1:, :][both]


def edge_terms(problem, forward):
    """Per axis: endpoints, the two half-equation weights and targets of every edge."""
    for axis in (0, 1):
        i, j = problem.edges[axis]
        w_i = forward[axis][i] * problem.confidence[i]
        w_j = (1.0 - forward[axis][j]) * problem.confidence[j]
        slope = problem.slopes[axis]
        yield i, j, w_i, w_j, slope[i], slope[j]


def assemble(problem, forward):
    """Normal equations ``L z = b`` for the given forward weights.

    Parameters
    ----------
    forward : list of two ndarray (N,)
        Weight of each pixel's forward half-equation per axis; its backward one gets 1 - w.

    Returns
    -------
    L : csr_matrix (N, N)
        Weighted graph Laplacian plus a tiny ridge (so isolated pixels stay at 0).
    b : ndarray (N,)
    """
    size = problem.size
    rows, cols, vals = [], [], []
    b = np.zeros(size)
    diag = np.zeros(size)
    for i, j, w_i, w_j, g_i, g_j in edge_terms(problem, forward):
        weight = w_i + w_j
        target = w_i * g_i + w_j * g_j
        rows += [i, j]
        cols += [j, i]
        vals += [-weight, -weight]
        diag += np.bincount(i, weight, size) + np.bincount(j, weight, size)
        b += np.bincount(j, target, size) - np.bincount(i, target, size)
    ridge = 1e-10 * max(float(diag.mean()), 1e-12)
    rows.append(np.arange(size))
    cols.append(np.arange(size))
    vals.append(diag + ridge)
    L = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                      shape=(size, size))
    return L, b


def energy(problem, forward, z):
    """Weighted sum of squared half-equation residuals."""
    total = 0.0
    for i, j, w_i, w_j, g_i, g_j in edge_terms(problem, forward):
        step = z[j] - z[i]
        total += float(w_i @ (step - g_i) ** 2 + w_j @ (step - g_j) ** 2)
    return total


def amg_preconditioner(L, kind=None):
    """A multigrid V-cycle approximating ``L^-1`` (LinearOperator).

    ``kind`` 'rs' (classical Ruge-Stuben; the default, :data:`AMG_KIND`) or 'sa' (smoothed
    aggregation, whose setup spends most of its time estimating eigenvalues).
    """
    kind = kind or AMG_KIND
    if kind == "rs":
        # one forward sweep before and one backward sweep after keep the V-cycle symmetric
        # (as CG needs) at half the cost of symmetric sweeps on both sides
        ml = pyamg.ruge_stuben_solver(L, max_coarse=100,
                                      presmoother=("gauss_seidel", {"sweep": "forward"}),
                                      postsmoother=("gauss_seidel", {"sweep": "backward"}))
    else:
        ml = pyamg.smoothed_aggregation_solver(L, symmetry="symmetric", max_coarse=100)
    return ml.aspreconditioner(cycle="V")


def solve_spd(L, b, *, x0=None, M=None, rtol=1e-8, maxiter=500):
    """Preconditioned conjugate gradients on ``L x = b``; stops at ``|r| <= rtol |b|``.

    Written out here rather than scipy's ``cg`` because vector dot products go through
    ``einsum`` instead of multithreaded BLAS, which thrashes on a small, busy machine.
    ``M`` is a preconditioner operator (default: a fresh multigrid V-cycle).
    Returns (x, iterations).
    """
    M = amg_preconditioner(L) if M is None else M
    x = np.zeros_like(b) if x0 is None else np.array(x0, dtype=float)
    r = b - L @ x
    goal = rtol * np.sqrt(_dot(b, b))
    if np.sqrt(_dot(r, r)) <= goal:
        return x, 0
    z = M @ r
    p = z.copy()
    rz = _dot(r, z)
    for iteration in range(1, maxiter + 1):
        Lp = L @ p
        alpha = rz / _dot(p, Lp)
        x += alpha * p
        r -= alpha * Lp
        if np.sqrt(_dot(r, r)) <= goal:
            break
        z = M @ r
        rz, rz_old = _dot(r, z), rz
        p = z + (rz / rz_old) * p
    return x, iteration


def _dot(a, b):
    return float(np.einsum("i,i->", a, b))
