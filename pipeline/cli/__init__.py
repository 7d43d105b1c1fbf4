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
    "run", "eval", "report", "demo", "experiments", "reflectometry",
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
    args, extra = parser.parse_known_args(argv)
    if extra:
        _unrecognized(parser, args, extra)
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


def _subparsers(parser):
    """The sub-command action of ``parser``, or None."""
    return next((a for a in parser._actions if isinstance(a, argparse._SubParsersAction)), None)


def _unrecognized(parser, args, extra):
    """Refuse arguments the command does not take with the command's own usage (argparse would
    show psrig's top-level one), naming the commands that take the first unknown option."""
    target, path = parser, []
    while (action := _subparsers(target)) is not None and getattr(args, action.dest, None) in action.choices:
        path.append(getattr(args, action.dest))
        target = action.choices[path[-1]]
    option = next((e.split("=")[0] for e in extra if e.startswith("-")), None)
    hint = ""
    if option:
        owners = []
        for name, sub in (_subparsers(parser).choices.items() if _subparsers(parser) else ()):
            inner = _subparsers(sub)
            for full, leaf in ([(f"{name} {k}", v) for k, v in inner.choices.items()] if inner else [(name, sub)]):
                if option in leaf._option_string_actions and full != " ".join(path):
                    owners.append(full)
        if owners:
            hint = f" ({option} is an option of psrig {', psrig '.join(owners[:4])}{' ...' if len(owners) > 4 else ''})"
    target.error(f"unrecognized arguments: {' '.join(extra)}{hint}")


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
