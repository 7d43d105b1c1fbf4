"""Jacobi-preconditioned conjugate gradients on the integration grid (for the bilateral mode).

Bilateral Normal Integration (Cao et al., ECCV 2022) solves each reweighted system with
warm-started, Jacobi-preconditioned CG stopped at ``|r| < 1e-3 |b|``. Those loose solves are
part of the method, not only of its speed: after a few rounds the previous depth already meets
the tolerance for the new weights, CG takes no step, the energy stops changing and the rounds
end, well before the exact reweighting fixed point (which over-segments; see
:mod:`pipeline.integrate.bilateral`). So this module reproduces that solver: same
preconditioner, same stopping test.

The system ``L z = b`` is stored per pixel in a fixed-width ("ELL") layout: the diagonal and,
for each of the four grid directions, the neighbour's unknown number and the edge weight (the
pixel itself and 0 where there is no neighbour). Every row has the same length, so the compiled
matrix-vector product needs no row pointers.

The kernel is compiled with numba at the first call (or loaded from numba's on-disk cache).
``PSRIG_NO_JIT=1`` selects a numpy implementation of the same iteration (same mathematics,
about 1.7x slower on cat); so does a missing numba or a compile/cache failure, with one warning.
"""

from dataclasses import dataclass

import numpy as np

from ..core.jit import Compiled, njit
from .grid import edge_terms

__all__ = ["GridSystem", "grid_system", "pcg_jacobi", "KERNEL"]


@dataclass
class GridSystem:
    """``L z = b`` in fixed-width layout.

    Attributes
    ----------
    neighbours : ndarray (4, N) int64
        Unknown number of the right, left, lower and upper neighbour of each pixel (itself when
        absent).
    weights : ndarray (4, N) float64
        Weight of the edge to that neighbour (0 when absent); ``L[i, nb] = -weight``.
    diagonal : ndarray (N,) float64
        Sum of the pixel's edge weights plus a tiny ridge (as in ``integrate_ls.assemble``).
    rhs : ndarray (N,) float64
    """

    neighbours: np.ndarray
    weights: np.ndarray
    diagonal: np.ndarray
    rhs: np.ndarray

    def matvec(self, x):
        """``L @ x`` for ``x`` (N,)."""
        return self.diagonal * x - np.einsum("sn,sn->n", self.weights, x[self.neighbours])


def grid_system(problem, forward):
    """The normal equations of :func:`pipeline.integrate.grid.assemble`, in fixed-width layout.

    Parameters
    ----------
    problem : GridProblem
    forward : list of two ndarray (N,)
        Weight of each pixel's forward half-equation per axis (backward: ``1 - w``).

    Returns
    -------
    GridSystem
    """
    size = problem.size
    neighbours = np.tile(np.arange(size, dtype=np.int64), (4, 1))
    weights = np.zeros((4, size))
    rhs = np.zeros(size)
    # each pixel has at most one forward and one backward neighbour per axis: no collisions
    for axis, (i, j, w_i, w_j, g_i, g_j) in enumerate(edge_terms(problem, forward)):
        weight = w_i + w_j
        target = w_i * g_i + w_j * g_j
        neighbours[2 * axis, i], weights[2 * axis, i] = j, weight
        neighbours[2 * axis + 1, j], weights[2 * axis + 1, j] = i, weight
        rhs += np.bincount(j, target, size) - np.bincount(i, target, size)
    diagonal = weights.sum(axis=0)
    diagonal += 1e-10 * max(float(diagonal.mean()), 1e-12)  # isolated pixels stay at 0
    return GridSystem(neighbours, weights, diagonal, rhs)


def pcg_jacobi(system, x, *, rtol=1e-3, maxiter=5000):
    """Jacobi-preconditioned CG, in place on ``x``; stops when ``|r| < rtol |b|`` (BiNI's test).

    Parameters
    ----------
    system : GridSystem
    x : ndarray (N,) float64
        Start (warm start), overwritten with the result.
    rtol : float
        Relative residual, against ``|b|`` (not against the starting residual, so a start that
        already meets it costs no iteration).
    maxiter : int

    Returns
    -------
    iterations : int
    """
    kernel = KERNEL.get()
    if kernel is not None:
        return int(kernel(system.neighbours, system.weights, system.diagonal, system.rhs, x,
                          float(rtol), int(maxiter)))
    return _pcg_numpy(system, x, rtol, maxiter)


def _pcg_numpy(system, x, rtol, maxiter):
    """The kernel's iteration in numpy (reference and fallback)."""
    b, inverse = system.rhs, 1.0 / system.diagonal
    if not b.any():
        x[:] = 0.0
        return 0
    goal = rtol * np.sqrt(_dot(b, b))
    r = b - system.matvec(x)
    p = np.zeros_like(b)
    rz_old = 1.0
    for iteration in range(int(maxiter)):
        if np.sqrt(_dot(r, r)) < goal:
            return iteration
        z = inverse * r
        rz = _dot(r, z)
        p = z + (rz / rz_old) * p
        q = system.matvec(p)
        alpha = rz / _dot(p, q)
        x += alpha * p
        r -= alpha * q
        rz_old = rz
    return int(maxiter)


def _dot(a, b):
    # einsum, not BLAS: multithreaded BLAS thrashes on a small, busy machine
    return float(np.einsum("i,i->", a, b))


def _compile():
    kernel = njit(_pcg_kernel)
    tiny = _warm_up_system()
    kernel(tiny.neighbours, tiny.weights, tiny.diagonal, tiny.rhs, np.zeros(2), 1e-3, 5)
    return kernel


def _warm_up_system():
    """Two connected pixels (compiles the kernel for the argument types always passed)."""
    return GridSystem(np.array([[1, 1], [0, 0], [0, 1], [0, 1]], dtype=np.int64),
                      np.array([[1.0, 0.0], [0.0, 1.0], [0.0, 0.0], [0.0, 0.0]]),
                      np.array([1.0 + 1e-10, 1.0 + 1e-10]), np.array([-1.0, 1.0]))


def _pcg_kernel(neighbours, weights, diagonal, b, x, rtol, maxiter):
    """Compiled body of :func:`pcg_jacobi` (plain loops over pixels, for numba)."""
    n = b.size
    n0, n1, n2, n3 = neighbours[0], neighbours[1], neighbours[2], neighbours[3]
    w0, w1, w2, w3 = weights[0], weights[1], weights[2], weights[3]
    inverse = 1.0 / diagonal
    r = np.empty(n)
    p = np.zeros(n)
    q = np.empty(n)
    bb = 0.0
    rr = 0.0
    for i in range(n):
        bb += b[i] * b[i]
        r[i] = b[i] - (diagonal[i] * x[i] - w0[i] * x[n0[i]] - w1[i] * x[n1[i]]
                       - w2[i] * x[n2[i]] - w3[i] * x[n3[i]])
        rr += r[i] * r[i]
    if bb == 0.0:  # L z = 0 has the solution 0 (the ridge makes L definite)
        x[:] = 0.0
        return 0
    goal = rtol * np.sqrt(bb)
    rz_old = 1.0
    for iteration in range(maxiter):
        if np.sqrt(rr) < goal:
            return iteration
        rz = 0.0
        for i in range(n):
            rz += r[i] * r[i] * inverse[i]
        beta = rz / rz_old
        pq = 0.0
        for i in range(n):
            p[i] = inverse[i] * r[i] + beta * p[i]
        for i in range(n):
            s = (diagonal[i] * p[i] - w0[i] * p[n0[i]] - w1[i] * p[n1[i]]
                 - w2[i] * p[n2[i]] - w3[i] * p[n3[i]])
            q[i] = s
            pq += p[i] * s
        alpha = rz / pq
        rr = 0.0
        for i in range(n):
            x[i] += alpha * p[i]
            r[i] -= alpha * q[i]
            rr += r[i] * r[i]
        rz_old = rz
    return maxiter


#: The compiled body of :func:`pcg_jacobi`, built on first use
KERNEL = Compiled("integration kernel", _compile)
