"""Jacobi-preconditioned CG of the bilateral mode: the system, the compiled kernel, the fallback."""

import numpy as np
import pytest

import pipeline.integrate.pcg as pcg
from pipeline.core.jit import ENV_NO_JIT, Compiled
from pipeline.integrate.grid import assemble, build_problem


def problem_and_weights(seed=0):
    """Random unit normals over a mask with a hole and a second component, random weights."""
    rng = np.random.default_rng(seed)
    mask = np.zeros((20, 30), bool)
    mask[2:18, 2:20] = True
    mask[8:11, 8:12] = False  # a hole
    mask[5:9, 24:28] = True  # a second component
    mask[15, 27] = True  # an isolated pixel
    normals = np.concatenate([rng.normal(0, 0.3, (20, 30, 2)), np.ones((20, 30, 1))], axis=2)
    normals /= np.linalg.norm(normals, axis=2, keepdims=True)
    problem = build_problem(normals, mask, normal_weighting=True)
    forward = [rng.random(problem.size), rng.random(problem.size)]
    return problem, forward, rng


def test_grid_system_equals_the_assembled_normal_equations():
    problem, forward, rng = problem_and_weights()
    L, b = assemble(problem, forward)
    system = pcg.grid_system(problem, forward)
    x = rng.normal(size=problem.size)
    np.testing.assert_allclose(system.matvec(x), L @ x, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(system.rhs, b, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(system.diagonal, L.diagonal(), rtol=1e-12)


def test_compiled_kernel_equals_numpy(monkeypatch):
    assert pcg.KERNEL.get() is not None  # numba is a dependency: the compiled path must run here
    problem, forward, _ = problem_and_weights(1)
    system = pcg.grid_system(problem, forward)
    compiled = np.zeros(problem.size)
    its_compiled = pcg.pcg_jacobi(system, compiled, rtol=1e-8)
    monkeypatch.setenv(ENV_NO_JIT, "1")
    reference = np.zeros(problem.size)
    its_numpy = pcg.pcg_jacobi(system, reference, rtol=1e-8)
    assert its_compiled == its_numpy > 5
    np.testing.assert_allclose(compiled, reference, atol=1e-9)
    residual = system.rhs - system.matvec(reference)
    assert np.linalg.norm(residual) < 1e-8 * np.linalg.norm(system.rhs)


@pytest.mark.parametrize("jit", ["0", "1"])
def test_a_warm_start_meeting_the_tolerance_costs_nothing(monkeypatch, jit):
    monkeypatch.setenv(ENV_NO_JIT, jit)
    problem, forward, _ = problem_and_weights(2)
    system = pcg.grid_system(problem, forward)
    x = np.zeros(problem.size)
    assert pcg.pcg_jacobi(system, x, rtol=1e-3) > 0
    again = x.copy()
    assert pcg.pcg_jacobi(system, again, rtol=1e-3) == 0  # BiNI's rounds stop moving this way
    np.testing.assert_array_equal(again, x)
    system.rhs[:] = 0.0
    assert pcg.pcg_jacobi(system, again) == 0
    assert not again.any()


def test_compile_failure_falls_back_to_numpy_with_one_warning(monkeypatch):
    problem, forward, _ = problem_and_weights(3)
    system = pcg.grid_system(problem, forward)
    monkeypatch.setenv(ENV_NO_JIT, "0")
    monkeypatch.setattr(pcg, "KERNEL", Compiled(pcg.KERNEL.what, pcg.KERNEL.build))

    def broken():
        raise RuntimeError("no compiler")

    monkeypatch.setattr(pcg.KERNEL, "build", broken)
    x = np.zeros(problem.size)
    with pytest.warns(RuntimeWarning, match="using numpy"):
        pcg.pcg_jacobi(system, x, rtol=1e-6)
    assert np.linalg.norm(system.rhs - system.matvec(x)) < 1e-6 * np.linalg.norm(system.rhs)
