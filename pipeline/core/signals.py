"""SIGTERM handled as Ctrl-C is: the command stops the same way, says so in one line, and what
it finished stays recorded (a batch system or ``kill`` sends SIGTERM, a person Ctrl-C)."""

import contextlib
import signal
import threading

__all__ = ["sigterm_raises"]


@contextlib.contextmanager
def sigterm_raises(error):
    """Within the block, SIGTERM raises ``error("terminated (SIGTERM)")`` (an exception class,
    a KeyboardInterrupt's kind) in the main thread; elsewhere, and after the block, it does
    what it did before. Only the main thread may install signal handlers: in another the block
    changes nothing."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def terminate(signum, frame):
        raise error("terminated (SIGTERM)")

    previous = signal.signal(signal.SIGTERM, terminate)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous if previous is not None else signal.SIG_DFL)
