"""pipeline.jit: how kernels run (the compiled kernels' own tests are beside each kernel)."""

import numpy as np
import pytest

from pipeline.jit import single_threaded

threadpoolctl = pytest.importorskip("threadpoolctl")


def _blas_threads():
    return {lib["filepath"]: lib["num_threads"] for lib in threadpoolctl.threadpool_info() if lib["user_api"] == "blas"}


def test_single_threaded_limits_blas_and_restores_it():
    np.ones((4, 4)) @ np.ones((4, 4))   # BLAS loaded
    before = _blas_threads()
    with single_threaded():
        assert set(_blas_threads().values()) <= {1}
    with single_threaded("blas"):
        assert set(_blas_threads().values()) <= {1}
    assert _blas_threads() == before


def test_single_threaded_looks_again_after_an_import(monkeypatch):
    # the cached controller is kept while no module is imported, and replaced after one
    import sys

    from pipeline import jit

    with single_threaded():
        pass
    kept = jit._POOLS["controller"]
    with single_threaded():
        pass
    assert jit._POOLS["controller"] is kept
    monkeypatch.setitem(sys.modules, "psrig_test_new_module", object())
    with single_threaded():
        pass
    assert jit._POOLS["controller"] is not kept
