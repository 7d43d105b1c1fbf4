"""pipeline.core.jit: how kernels run (the compiled kernels' own tests are beside each kernel)."""

import numpy as np
import pytest

from pipeline.core.jit import single_threaded

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

    from pipeline.core import jit

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


def _slow_build(seconds):
    import time

    def build():
        time.sleep(seconds)
        return "built"
    return build


@pytest.mark.parametrize("mode", ["lines", "bar"])
def test_a_long_compilation_says_so_while_it_runs(monkeypatch, capsys, mode):
    # a first run compiles for ~15 s while no progress moves: it says why it waits, and when done
    from pipeline.core import jit

    monkeypatch.setattr(jit, "NOTICE_SECONDS", 0.05)
    monkeypatch.setenv("PSRIG_PROGRESS", mode)
    assert jit.Compiled("test kernels", _slow_build(0.4)).get() == "built"
    err = capsys.readouterr().err
    assert "psrig: compiling the test kernels (the first run on this machine" in err
    assert "psrig: compiled the test kernels in 0 s" in err


@pytest.mark.parametrize("mode, build", [("lines", _slow_build(0.0)), ("off", _slow_build(0.4))])
def test_a_load_from_the_cache_or_a_quiet_run_says_nothing(monkeypatch, capsys, mode, build):
    from pipeline.core import jit

    monkeypatch.setattr(jit, "NOTICE_SECONDS", 0.2 if mode == "lines" else 0.05)
    monkeypatch.setenv("PSRIG_PROGRESS", mode)
    assert jit.Compiled("test kernels", build).get() == "built"
    assert capsys.readouterr().err == ""
