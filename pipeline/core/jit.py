"""How psrig's numeric kernels run: compiled with numba on first use, or numpy; on one BLAS
thread where the caller runs threads of its own. The one place that decides these (the memory
a stage may use is :mod:`pipeline.core.memory`'s).

Kernels in psrig are plain Python over scalars, compiled with numba the first time they are
needed (or loaded from numba's on-disk cache). Nothing is compiled at import. A compilation
happens once, under a lock, so concurrent threads wait for it. Any failure there (numba
missing, an unwritable cache, a compiler error) gives one RuntimeWarning and the numpy
implementation from then on: a missing compiler must never stop a run.

``PSRIG_NO_JIT=1`` in the environment selects the numpy implementations everywhere (they are
the reference the compiled kernels are tested against).

>>> KERNEL = Compiled("integration kernel", build)   # build() compiles and warms up
>>> kernel = KERNEL.get()                              # None: use numpy

:func:`single_threaded` limits BLAS (and OpenMP) to one thread, for code whose own threads
share the cores (the photometric engine's chunks) or whose products are too small for BLAS
threads (the integration's solver). ``threadpoolctl.threadpool_limits`` looks the thread-pool
libraries up on every call, which is slow once numba and LLVM have loaded many libraries:
one controller is kept, looked up again
only when a module was imported since (an import may load another BLAS).

>>> with single_threaded():          # every thread-pool library
...     run_chunks(...)
"""

import contextlib
import os
import sys
import threading
import time
import warnings

__all__ = ["Compiled", "ENV_NO_JIT", "NOTICE_SECONDS", "VECTORISE", "jit_allowed", "njit", "single_threaded"]

ENV_NO_JIT = "PSRIG_NO_JIT"


def jit_allowed():
    """False when ``PSRIG_NO_JIT`` is set to anything but '' or '0'."""
    return os.environ.get(ENV_NO_JIT, "") in ("", "0")


#: The fast-math flags a kernel may ask for (``njit(func, fastmath=VECTORISE)``): reassociation and
#: contraction, so that sums over a pixel's observations vectorise (SIMD) and fuse (FMA); never
#: 'nnan' or 'ninf', since kernels test for NaN and infinity. Results then differ from numpy's in
#: the last bits, which the kernels' tests bound.
VECTORISE = frozenset({"reassoc", "contract"})


def njit(func, fastmath=False):
    """``numba.njit`` with psrig's flags: cached on disk, GIL released, numpy's error model.

    fastmath is off unless asked for (:data:`VECTORISE`): then the same rounding on every
    machine, so compiled and numpy results agree bit for bit where the arithmetic is the same.
    """
    import numba

    return numba.njit(cache=True, nogil=True, fastmath=set(fastmath) if fastmath else False,
                      error_model="numpy")(func)


#: a build that takes longer than this is a compilation (loading from numba's cache takes about
#: 0.5 s), which is said on stderr (:meth:`Compiled.get`)
NOTICE_SECONDS = 2.0


def _say(text):
    """``psrig: text`` on stderr, unless progress is off (``psrig run -q``); above a progress bar."""
    from .progress import progress_mode

    mode = progress_mode()
    if mode == "off":
        return
    if mode == "bar":
        from tqdm import tqdm

        tqdm.write(f"psrig: {text}", file=sys.stderr)
    else:
        print(f"psrig: {text}", file=sys.stderr, flush=True)


class Compiled:
    """Something compiled lazily by ``build()`` (any object: a dispatcher, a dict of them).

    Parameters
    ----------
    what : str
        Named in the warning when compiling fails ("photometric-stereo kernels").
    build : callable
        Compiles (and warms up) on first :meth:`get`; its exceptions mean "use numpy".
    """

    def __init__(self, what, build):
        self.what = what
        self.build = build
        self._lock = threading.Lock()
        self._value = None
        self.failed = False
        self.seconds = None   # spent compiling or loading from the cache, once known

    def enabled(self):
        """True unless the environment says numpy or compiling has failed."""
        return jit_allowed() and not self.failed

    def get(self):
        """The compiled object, or None when the numpy implementation must be used.

        A build that takes longer than :data:`NOTICE_SECONDS` (a compilation, not a load from
        numba's cache) says so on stderr while it runs, and when it ends: meanwhile no progress
        moves, and a run that seems to hang is worse than one that says why it waits.
        """
        if not self.enabled():
            return None
        with self._lock:
            if self._value is None and not self.failed:
                start = time.perf_counter()
                said = threading.Event()

                def announce():
                    _say(f"compiling the {self.what} (the first run on this machine or after an update; "
                         f"cached for later runs)")
                    said.set()

                notice = threading.Timer(NOTICE_SECONDS, announce)
                notice.daemon = True
                notice.start()
                try:
                    self._value = self.build()
                except Exception as exc:  # any failure here must degrade to numpy, never stop a run
                    self.failed = True
                    warnings.warn(f"psrig: compiled {self.what} unavailable, using numpy "
                                  f"({type(exc).__name__}: {exc})", RuntimeWarning, stacklevel=3)
                    return None
                finally:
                    notice.cancel()
                self.seconds = time.perf_counter() - start
                if said.is_set():
                    _say(f"compiled the {self.what} in {self.seconds:.0f} s")
        return self._value

    def reset(self):
        """Forget the compiled object and any failure (tests, or after changing the build)."""
        with self._lock:
            self._value, self.failed, self.seconds = None, False, None


_POOLS_LOCK = threading.Lock()
_POOLS = {"modules": -1, "controller": None}


def _controller():
    """The cached ``ThreadpoolController``, looked up again when ``sys.modules`` grew; None
    without threadpoolctl."""
    with _POOLS_LOCK:
        if _POOLS["modules"] != len(sys.modules):
            try:
                from threadpoolctl import ThreadpoolController
            except ImportError:
                return None
            _POOLS["controller"] = ThreadpoolController()
            _POOLS["modules"] = len(sys.modules)
        return _POOLS["controller"]


def single_threaded(user_api=None):
    """A context in which the thread-pool libraries of ``user_api`` ('blas', 'openmp', None for
    all) run one thread; a no-op without threadpoolctl."""
    controller = _controller()
    if controller is None:
        return contextlib.nullcontext()
    return controller.limit(limits=1, user_api=user_api)
