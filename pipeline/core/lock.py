"""Who may write a session: one command at a time, and the worker processes it started.

A command that writes a session holds an exclusive OS lock (``fcntl.flock``) on the session's
lock file, ``SESSION/.psrig.lock``, for as long as it works on it. The kernel drops the lock
when the process ends, however it ends (SIGKILL included), so a lock is never stale: a lock
that cannot be taken is held by a live process. The holder writes who it is into the file
(command, pid, host, since, a token); a second writer reads that to name the holder in one
line, or waits (``wait=True``).

Worker processes act under their parent's lock instead of taking their own:

- process pools (decode, ``psrig run --jobs``) get a *lifeline* (:func:`lifeline`), the read
  end of a pipe whose only write end the parent holds; a thread in each worker
  (:func:`watch_lifeline`) kills the worker when the pipe reports end-of-file, that is when the
  parent is gone. No worker outlives the lock it works under.
- tasks on other machines (Dask) are handed the holder's token; :func:`act_under` registers it,
  and every write checks that the session's lock is still held by that token
  (:func:`authorize`): a task whose client died writes nothing.

Writers that hold no lock at all (library code, tests) take it for the instant of each
manifest write (:func:`authorize`), so they never overwrite the manifest under a command that
holds it.
"""

import contextlib
import datetime as _dt
import multiprocessing
import multiprocessing.forkserver
import errno
import fcntl
import json
import os
import signal
import site
import socket
import stat
import sys
import threading
import time
import uuid
from dataclasses import asdict, dataclass
from pathlib import Path

from .errors import SessionError

__all__ = ["SessionLock", "SessionLocked", "Holder", "LOCK_FILE", "acquire", "holder", "act_under",
           "authorize", "lifeline", "watch_lifeline", "worker_context"]

#: The lock file in every session folder (never removed: removing a lock file races its users).
LOCK_FILE = ".psrig.lock"
# how often a waiting writer looks again (flock would block without a way to time out)
_POLL = 0.2


class SessionLocked(SessionError):
    """Another live process holds the session's lock; the message names it."""


@dataclass(frozen=True)
class Holder:
    """Who holds a session lock, as written into the lock file."""

    command: str
    pid: int
    host: str
    since: str
    token: str

    def describe(self):
        """'psrig run (pid 4242 on lab1, since 2024-05-01T10:00:00+00:00)'."""
        return f"psrig {self.command} (pid {self.pid} on {self.host}, since {self.since})"


# Locks this process holds ({lock file: SessionLock}) and tokens it acts under ({lock file: token}).
_HELD = {}
_UNDER = {}
_GUARD = threading.Lock()


def _lock_path(root):
    return Path(os.path.realpath(root)) / LOCK_FILE


class SessionLock:
    """An exclusive lock on one session folder, held until :meth:`release` or the process ends.

    Re-entrant within a process: acquiring a lock this process holds returns the same object
    with one more user; it is released when the last user releases it.
    """

    def __init__(self, path, fd, holder, delegated=False):
        self.path, self.fd, self.holder, self.delegated = path, fd, holder, delegated
        self.users = 1

    @property
    def token(self):
        """The token workers are given to act under this lock (:func:`act_under`)."""
        return self.holder.token

    def release(self):
        """Give the lock up (for the last user); the lock file stays."""
        with _GUARD:
            self.users -= 1
            if self.users > 0 or self.fd is None:
                return
            if _HELD.get(self.path) is self:
                del _HELD[self.path]
            fd, self.fd = self.fd, None
        with contextlib.suppress(OSError):
            os.ftruncate(fd, 0)  # no stale name in the file (it is only read when locked anyway)
        os.close(fd)  # closing the last descriptor drops the flock

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.release()


def _open(path):
    """Open (or create) the lock file, never through a symlink: a session received as a folder
    or an archive may hold a ``.psrig.lock`` linking anywhere, and the holder record written
    into it would empty the file it names (or create one where a dangling link points)."""
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC | os.O_NOFOLLOW, 0o666)
    except OSError as exc:
        if exc.errno == errno.ELOOP or os.path.islink(path):
            raise SessionError(_not_regular(path)) from None
        raise SessionError(f"{path.parent}: cannot open the session's lock file {LOCK_FILE} "
                           f"({exc.strerror}); is the folder writable?") from None
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        os.close(fd)
        raise SessionError(_not_regular(path))
    return fd


def _not_regular(path):
    """The refusal of a lock file that is a symlink or not a regular file."""
    what = f"a symbolic link to {os.readlink(path)}" if os.path.islink(path) else "not a regular file"
    return (f"{path}: the session's lock file is {what}; psrig never writes through links in a "
            f"session: remove {LOCK_FILE} (psrig makes it again) and check where the session came from")


def _try_lock(path):
    """An open descriptor holding the flock on ``path``, or None when another process holds it.

    The lock is taken on the file that is at ``path`` afterwards: had it been replaced between
    the open and the lock (a session folder deleted and made again), the lock would guard
    nothing, and it is taken again.
    """
    while True:
        fd = _open(path)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            os.close(fd)
            if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                return None
            raise SessionError(f"{path}: cannot lock the session ({exc.strerror})") from None
        try:
            same = os.stat(path).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same = False
        if same:
            return fd
        os.close(fd)


def _write_holder(fd, holder):
    data = (json.dumps(asdict(holder)) + "\n").encode()
    os.ftruncate(fd, 0)
    os.pwrite(fd, data, 0)


def _read_holder(path):
    try:
        fd = os.open(path, os.O_RDONLY | os.O_CLOEXEC | os.O_NOFOLLOW)
        with open(fd, "rb") as fh:
            data = json.loads(fh.read(1 << 16).decode("utf-8") or "null")
        return Holder(**data) if isinstance(data, dict) else None
    except (OSError, ValueError, TypeError):
        return None


def _new_holder(command):
    now = _dt.datetime.now(_dt.timezone.utc).replace(microsecond=0).isoformat()
    return Holder(command, os.getpid(), socket.gethostname(), now, uuid.uuid4().hex)


def holder(root):
    """The :class:`Holder` of a session's lock, or None when no process holds it."""
    path = _lock_path(root)
    if not path.is_file() and not path.is_symlink():
        return None
    with _GUARD:
        if path in _HELD:
            return _HELD[path].holder
    fd = _try_lock(path)
    if fd is not None:  # nobody held it
        os.close(fd)
        return None
    return _described(path)


def _described(path):
    """The holder named in a lock file that is held (it may take a moment to write its name)."""
    for _ in range(10):
        found = _read_holder(path)
        if found is not None:
            return found
        time.sleep(0.01)
    return Holder("(unknown command)", 0, "?", "?", "")


def _locked_error(root, found):
    return SessionLocked(f"{root}: the session is being written by {found.describe()}; "
                         "wait for it to finish, or use --wait")


def acquire(root, command, *, wait=False, on_wait=None):
    """Take the session's lock for ``command`` (a sub-command name such as 'run').

    Parameters
    ----------
    root : path
        The session folder (it must exist).
    command : str
        Named to other writers while the lock is held.
    wait : bool
        Wait until the holder finishes instead of raising :class:`SessionLocked`.
    on_wait : callable, optional
        Called once with a line naming the holder (not the session) when ``wait`` has to wait.

    Returns
    -------
    SessionLock
        Held until released; in a process that acts under another's lock (:func:`act_under`),
        a stand-in that checks that lock is still held.
    """
    path = _lock_path(root)
    with _GUARD:
        held = _HELD.get(path)
        if held is not None:
            held.users += 1
            return held
        token = _UNDER.get(path)
    if token is not None:
        _check_under(root, path, token)
        return SessionLock(path, None, _read_holder(path), delegated=True)
    announced = False
    while True:
        fd = _try_lock(path)
        if fd is not None:
            break
        found = _described(path)
        if not wait:
            raise _locked_error(root, found)
        if not announced and on_wait is not None:
            on_wait(f"waiting for {found.describe()} to finish with the session")
        announced = True
        time.sleep(_POLL)
    lock = SessionLock(path, fd, _new_holder(command))
    _write_holder(fd, lock.holder)
    with _GUARD:
        _HELD[path] = lock
    return lock


def act_under(root, token):
    """Declare that this (worker) process writes ``root`` under the lock whose token is ``token``.

    Every later write to that session in this process checks that the lock is still held with
    that token (:func:`authorize`), and no lock is taken here.
    """
    with _GUARD:
        _UNDER[_lock_path(root)] = str(token)


def _check_under(root, path, token):
    found = holder(root)
    if found is None or found.token != token:
        raise SessionLocked(f"{root}: the command this task works for no longer holds the session "
                            "lock" + (f" (now {found.describe()})" if found else "")
                            + "; nothing is written")


@contextlib.contextmanager
def authorize(root):
    """Context of one write to a session: allowed when this process holds its lock or acts
    under a live holder's token; else the lock is taken for the write's duration (SessionLocked
    when another process holds it)."""
    path = _lock_path(root)
    with _GUARD:
        held = path in _HELD
        token = _UNDER.get(path)
    if held:
        yield
        return
    if token is not None:
        _check_under(root, path, token)
        yield
        return
    fd = _try_lock(path)
    if fd is None:
        raise _locked_error(root, _described(path))
    try:
        _write_holder(fd, _new_holder(f"{Path(sys.argv[0]).name or 'python'} (one write)"))
        yield
    finally:
        with contextlib.suppress(OSError):
            os.ftruncate(fd, 0)
        os.close(fd)


# -- worker processes: this psrig, and dying with their parent ------------------------------

def worker_context(preload=()):
    """The ``forkserver`` multiprocessing context psrig's process pools use, its server started.

    The server starts as ``python -c ...``, which puts the working directory first on
    ``sys.path`` (and Python 3.11 ignores the ``sys.path`` it is handed): run from a folder
    holding a ``pipeline`` of its own (an older checkout, a lab's own scripts), every worker
    would import that one and die. So the server starts with ``PYTHONSAFEPATH`` (no working
    directory) and the folder of the psrig this process runs first on ``PYTHONPATH``.
    """
    context = multiprocessing.get_context("forkserver")
    if preload:
        context.set_forkserver_preload(list(preload))
    home = str(Path(__file__).resolve().parents[1])
    shadow = Path.cwd() / "pipeline"
    if sys.version_info < (3, 11) and shadow.exists() and shadow.resolve() != Path(home, "pipeline"):
        raise SessionError(f"{Path.cwd()} holds a folder 'pipeline' that psrig's worker processes would import "
                           "instead of psrig on this Python (before 3.11); run psrig from another folder")
    # an installed psrig is found without help; a source checkout needs its folder on the path
    # (but a site-packages folder there would come before the standard library)
    installed = home in {str(Path(p).resolve()) for p in site.getsitepackages() + [site.getusersitepackages()]}
    with _GUARD:
        saved = {key: os.environ.get(key) for key in ("PYTHONSAFEPATH", "PYTHONPATH", "PYTHONWARNINGS")}
        os.environ["PYTHONSAFEPATH"] = "1"
        # the resource tracker (started here too) removes the pool's semaphores when psrig is
        # killed, and warned of them as "leaked" on the terminal: it is its job, not a fault
        os.environ["PYTHONWARNINGS"] = ",".join(
            [w for w in [saved["PYTHONWARNINGS"]] if w] + ["ignore:resource_tracker:UserWarning"])
        if not installed:
            os.environ["PYTHONPATH"] = os.pathsep.join([home] + ([saved["PYTHONPATH"]] if saved["PYTHONPATH"] else []))
        # the server starts ignoring SIGINT (an ignored signal stays ignored across exec): a
        # Ctrl-C while it imports its preloaded modules printed its traceback; it ignores SIGINT
        # from then on anyway, and psrig's workers set their own handling
        previous = (signal.signal(signal.SIGINT, signal.SIG_IGN)
                    if threading.current_thread() is threading.main_thread() else None)
        try:
            multiprocessing.forkserver.ensure_running()
        finally:
            if previous is not None:
                signal.signal(signal.SIGINT, previous)
            for key, value in saved.items():
                if value is None:
                    os.environ.pop(key, None)
                else:
                    os.environ[key] = value
    return context


_LIFELINE = None


def lifeline(context):
    """The read end of this process's lifeline pipe, to pass to workers of ``context`` (a
    multiprocessing context) in their initializer's arguments; :func:`watch_lifeline` there.

    The write end stays in this process, which never writes to it: when this process ends, the
    pipe reports end-of-file to every worker.
    """
    global _LIFELINE
    with _GUARD:
        if _LIFELINE is None:
            _LIFELINE = context.Pipe(duplex=False)
        return _LIFELINE[0]


def watch_lifeline(reader):
    """In a worker: kill this process (SIGKILL) as soon as the parent holding ``reader``'s
    other end is gone. Returns at once; a daemon thread watches."""
    def watch():
        with contextlib.suppress(EOFError, OSError):
            while True:
                reader.recv_bytes()  # the parent writes nothing: this returns only at its end
        os.kill(os.getpid(), signal.SIGKILL)

    threading.Thread(target=watch, name="psrig-lifeline", daemon=True).start()
