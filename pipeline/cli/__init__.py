"""The ``psrig`` command line.

Each sub-command lives in its own module of this package and exposes ``register(subparsers)``,
which adds its parser and sets ``func`` (called with the parsed arguments, returning an exit
code or None). :data:`COMMANDS` lists them in the order ``psrig --help`` shows them.
"""

import argparse
import importlib
import os
import sys

from .. import __version__
from ..errors import PsrigError
from .writing import WRITERS, add_wait_option

__all__ = ["main", "COMMANDS"]

COMMANDS = (
    "rigs", "capture", "preview", "importers", "decode", "calibrate", "normals", "integrate",
    "run", "eval", "report", "export", "demo", "experiments", "reflectometry",
)


def build_parser():
    parser = argparse.ArgumentParser(prog="psrig", description="Photometric stereo on a lab rig.")
    parser.add_argument("--version", action="version", version=f"psrig {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        try:
            module = importlib.import_module(f"{__name__}.{name}")
        except ModuleNotFoundError as exc:
            if exc.name != f"{__name__}.{name}":
                raise
            continue
        module.register(sub)
    for name in WRITERS:
        if name in sub.choices:
            add_wait_option(sub.choices[name])
    return parser


def main(argv=None):
    """Entry point of the ``psrig`` console script. Returns the process exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        code = args.func(args)
        sys.stdout.flush()  # a closed pipe shows here, not in the interpreter's exit
    except PsrigError as exc:
        print(f"psrig {args.command}: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"psrig {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return _closed_pipe()
    return int(code or 0)


def _closed_pipe():
    """The reader of our output went away (``psrig eval S | head -1``): stop quietly, as a
    command killed by SIGPIPE would, with its exit status 141."""
    # what is still buffered for stdout would fail again when Python flushes it at exit
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    os.close(devnull)
    return 128 + 13


if __name__ == "__main__":
    sys.exit(main())
