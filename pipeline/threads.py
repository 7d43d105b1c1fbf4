"""One BLAS thread for the code that runs its own threads, with the libraries found once.

``threadpoolctl.threadpool_limits`` looks up the loaded thread-pool libraries (BLAS, OpenMP) on
every call, which measured 2.6 ms here (numba and LLVM load many libraries): four calls were
about 4 % of a DiLiGenT estimation. :func:`single_threaded` keeps one controller and looks
again only when a module was imported since (a new import may load another BLAS).

>>> with single_threaded():          # every thread-pool library
...     run_chunks(...)
>>> with single_threaded("blas"):    # BLAS only
...     solve(...)
"""

import contextlib
import sys
import threading

__all__ = ["single_threaded"]

_LOCK = threading.Lock()
_CACHED = {"modules": -1, "controller": None}


def _controller():
    """The cached ``ThreadpoolController``, looked up again when ``sys.modules`` grew; None
    without threadpoolctl."""
    with _LOCK:
        if _CACHED["modules"] != len(sys.modules):
            try:
                from threadpoolctl import ThreadpoolController
            except ImportError:
                return None
            _CACHED["controller"] = ThreadpoolController()
            _CACHED["modules"] = len(sys.modules)
        return _CACHED["controller"]


def single_threaded(user_api=None):
    """A context in which the thread-pool libraries of ``user_api`` ('blas', 'openmp', None for
    all) run one thread; a no-op without threadpoolctl."""
    controller = _controller()
    if controller is None:
        return contextlib.nullcontext()
    return controller.limit(limits=1, user_api=user_api)
