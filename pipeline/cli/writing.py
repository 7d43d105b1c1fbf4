"""Opening a session from a command that writes it: the session lock, ``--wait``, the sweep note.

Every sub-command that writes a session (:data:`WRITERS`) takes the session's lock for as long
as it runs (:mod:`pipeline.core.lock`); a second writer is refused with one line naming the holder,
or waits with ``--wait``. The others only read (``rigs``, ``experiments``, ``reflectometry``,
``integrate --normals ... --out DIR``, which writes outside any session).
"""

import sys

__all__ = ["WRITERS", "add_wait_option", "open_session", "say"]

#: Sub-commands that write sessions (and so take the session lock).
WRITERS = ("capture", "import", "decode", "calibrate", "normals", "integrate", "run", "eval",
           "report", "demo")


def add_wait_option(parser):
    """``--wait``: wait for another command writing the session instead of stopping."""
    parser.add_argument("--wait", action="store_true",
                        help="if another psrig command is writing the session, wait for it to "
                             "finish (default: stop with a message naming it)")


def say(args, line):
    """A note of the command on stderr, prefixed like its errors."""
    print(f"psrig {args.command}: {line}", file=sys.stderr, flush=True)


def open_session(folder, args):
    """Open ``folder`` for the command of ``args``: lock taken (waiting with ``--wait``), the
    temporaries an interrupted run left removed and said."""
    from ..core.session import Session   # imported when a command runs: psrig --help stays fast

    session = Session.open(folder, writer=args.command, wait=getattr(args, "wait", False),
                           on_wait=lambda line: say(args, f"{folder}: {line}"))
    if session.swept:
        say(args, session.describe_swept())
    return session
