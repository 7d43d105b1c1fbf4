"""The ``psrig`` command line.

Each sub-command lives in its own module of this package and exposes ``register(subparsers)``,
which adds its parser and sets ``func`` (called with the parsed arguments, returning an exit
code or None). :data:`COMMANDS` lists them in the order ``psrig --help`` shows them.
"""

import argparse
import importlib
import os
import signal
import sys

from .. import __version__
from ..core.errors import PsrigError, describe_os_error
from ..core.signals import sigterm_raises
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
    try:   # imports every command's module (and what its options read): a Ctrl-C may land here
        parser = build_parser()
        args, extra = parser.parse_known_args(argv)
    except KeyboardInterrupt:
        print("psrig: interrupted", file=sys.stderr)
        return 130
    if extra:
        _unknown(parser, args, extra)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        with sigterm_raises(Terminated):
            code = args.func(args)
        sys.stdout.flush()  # a closed pipe shows here, not in the interpreter's exit
    except Terminated:
        print(f"psrig {args.command}: terminated (SIGTERM)", file=sys.stderr)
        return 128 + signal.SIGTERM
    except PsrigError as exc:
        # notes carry what happened while the error unwound (lights that stayed on)
        notes = "".join(f"; {note}" for note in getattr(exc, "__notes__", ()))
        print(f"psrig {args.command}: error: {exc}{notes}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"psrig {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return _closed_pipe()
    except OSError as exc:   # a full disk, a read-only or protected folder, a lost mount
        print(f"psrig {args.command}: error: {describe_os_error(exc)}", file=sys.stderr)
        return 1
    return int(code or 0)


def _unknown(parser, args, extra):
    """Refuse an option (or word) the command does not take (SystemExit 2): with the command's
    own usage (argparse would show psrig's top-level one), the options it does take (a misspelt
    stage option must not look like a missing one) and the commands that take it (an option
    given to the wrong command)."""
    target, path = parser, []
    while (action := _subparsers(target)) is not None and getattr(args, action.dest, None) in action.choices:
        path.append(getattr(args, action.dest))
        target = action.choices[path[-1]]
    if not path:
        parser.error(f"unrecognized arguments: {' '.join(extra)}")
    command = " ".join(path)
    word = next((e for e in extra if e.startswith("-")), extra[0]).split("=")[0]
    flags = sorted({s for a in target._actions for s in a.option_strings if s.startswith("--")} - {"--help"})
    owners = _owners(parser, word, command) if word.startswith("-") else []
    hint = f" ({word} is an option of psrig {', psrig '.join(owners[:4])}{' ...' if len(owners) > 4 else ''})" \
        if owners else ""
    target.error(f"unrecognized arguments: {' '.join(extra)}{hint}; psrig {command} takes: {', '.join(flags)}")


def _owners(parser, option, command):
    """The commands (and sub-commands) other than ``command`` that take ``option``."""
    owners = []
    for name, sub in (_subparsers(parser).choices.items() if _subparsers(parser) else ()):
        inner = _subparsers(sub)
        for full, leaf in ([(f"{name} {k}", v) for k, v in inner.choices.items()] if inner else [(name, sub)]):
            if option in leaf._option_string_actions and full != command:
                owners.append(full)
    return owners


def _subparsers(parser):
    """The sub-command action of ``parser``, or None."""
    return next((a for a in parser._actions if isinstance(a, argparse._SubParsersAction)), None)


class Terminated(KeyboardInterrupt):
    """SIGTERM arrived: the command stops as on Ctrl-C (what it finished is recorded, its
    worker processes and their semaphores are released)."""


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
