"""Options as data: each stage's and each method's settings declared once.

A set of options is a frozen dataclass deriving from :class:`Options` whose fields are made with
:func:`option`: a default, a one-line help, and how a value is checked and spelt on the command
line. From that one declaration come

- validation (:meth:`Options.check`): an unknown or misspelt name is an error that lists the
  known ones, in the Python API as on the command line; a value outside its choices or range is
  an error naming the option;
- the command-line flags and their help (:meth:`Options.add_arguments`), for the stage's own
  command and, with the same names, for ``psrig run``;
- what the stage record keeps (:meth:`Options.record`) and how ``psrig run`` replays it.

>>> from dataclasses import dataclass
>>> @dataclass(frozen=True)
... class Demo(Options):
...     kind = "demo option"
...     level: float = option(0.5, "how much", low=0.0, high=1.0)
>>> Demo.check({"level": 0.2})
{'level': 0.2}
>>> Demo.check({"levle": 0.2})
Traceback (most recent call last):
...
pipeline.core.errors.InputError: unknown demo option 'levle'; known: level
"""

import argparse
import dataclasses
from dataclasses import dataclass

from .errors import InputError

__all__ = ["Options", "OptionSpec", "option", "switch", "SWITCH"]

#: how an auto/on/off switch on the command line reads in the API
SWITCH = {"auto": None, "on": True, "off": False}


@dataclass(frozen=True)
class OptionSpec:
    """How one option is checked and spelt on the command line.

    Attributes
    ----------
    help : str
        One line; ``psrig STAGE --help`` appends the default.
    choices : tuple, optional
        The values the API takes.
    flag : str, optional
        The command-line flag (default ``--`` and the name with ``-`` for ``_``); '' for none.
    cli : dict, optional
        Command-line word -> API value (e.g. :data:`SWITCH`); the flag takes only these words.
    parse : callable, optional
        Turns the command-line text into the API value (raises InputError or ValueError).
    low, high : float, optional
        Inclusive bounds of a number; ``above`` an exclusive lower bound.
    kind : type, optional
        The value's type (float, int, bool, str); taken from the default when not given.
    metavar : str, optional
    const : optional
        The flag takes no value and sets this one (``--grey`` sets channels 'grey').
    recorded : bool
        False for a setting of how the stage runs, not of what it makes (a memory budget): left
        out of the stage record, so that changing it does not rerun the stage.
    default_text : str, optional
        How the help states a default that the code decides (e.g. "0.05 under a narrow cone").
    """

    help: str
    choices: tuple = None
    flag: str = None
    cli: dict = None
    parse: object = None
    low: float = None
    high: float = None
    above: float = None
    kind: type = None
    metavar: str = None
    default_text: str = None
    const: object = None
    recorded: bool = True


def option(default, help, **spec):
    """A dataclass field that is an option: ``default``, one line of ``help``, and the
    :class:`OptionSpec` keywords."""
    return dataclasses.field(default=default, metadata={"psrig": OptionSpec(help, **spec)})


def switch(default, help, **spec):
    """An auto/on/off option (API: None, True, False)."""
    return option(default, help, cli=SWITCH, **spec)


class Options:
    """Base of every declared set of options (use with ``@dataclass(frozen=True)``).

    Class attributes: ``kind`` names the options in messages ("normals option").
    """

    kind = "option"

    @classmethod
    def specs(cls):
        """{name: (default, OptionSpec)} in declaration order."""
        return {f.name: (f.default, f.metadata["psrig"]) for f in dataclasses.fields(cls) if "psrig" in f.metadata}

    @classmethod
    def names(cls):
        """The declared names, sorted."""
        return sorted(cls.specs())

    @classmethod
    def defaults(cls):
        """{name: default}."""
        return {name: default for name, (default, _) in cls.specs().items()}

    @classmethod
    def check(cls, given, *, where=None):
        """``given`` (a mapping) checked: every name declared, every value valid; returns a new
        dict of the given items, unchanged. InputError names the option and, for an unknown
        one, every known name."""
        specs = cls.specs()
        prefix = f"{where}: " if where else ""
        for name, value in given.items():
            if name not in specs:
                raise InputError(f"{prefix}unknown {cls.kind} {name!r}; known: {', '.join(sorted(specs))}")
            _check_value(cls.kind, name, value, *specs[name], prefix)
        return dict(given)

    @classmethod
    def of(cls, given=None, *, where=None):
        """An instance from a mapping of given options (checked); the rest, and those given as
        None, at their defaults."""
        return cls(**{k: v for k, v in cls.check(given or {}, where=where).items() if v is not None})

    def given(self):
        """{name: value} of the options that differ from their defaults."""
        defaults = self.defaults()
        return {k: getattr(self, k) for k in defaults if getattr(self, k) != defaults[k]}

    def record(self):
        """What the stage record keeps: the options that differ from their defaults (but those
        declared ``recorded=False``)."""
        specs = self.specs()
        return {k: v for k, v in self.given().items() if specs[k][1].recorded}

    @classmethod
    def help_line(cls, name):
        """The option's help with its default, as ``--help`` shows it."""
        default, spec = cls.specs()[name]
        shown = spec.default_text
        if shown is None and default is False and spec.cli is None:
            return spec.help   # a flag that is off unless given
        if shown is None:
            words = {v: k for k, v in (spec.cli or {}).items()}
            shown = words.get(default, default)
        return f"{spec.help} (default: {shown})" if shown is not None else spec.help

    @classmethod
    def table(cls):
        """The options as a Markdown table (option, flag, default, what it does): docs/design.md
        holds one per stage, and a test checks that they match the declarations."""
        rows = ["| option | flag | default | what it does |", "|---|---|---|---|"]
        for name, (default, spec) in cls.specs().items():
            words = {v: k for k, v in (spec.cli or {}).items()}
            shown = spec.default_text if spec.default_text is not None else words.get(default, default)
            flag = f"`{cls.flag(name)}`" if cls.flag(name) else "(API only)"
            rows.append(f"| `{name}` | {flag} | {shown} | {spec.help} |")
        return "\n".join(rows)

    @classmethod
    def flag(cls, name):
        """The option's command-line flag."""
        spec = cls.specs()[name][1]
        return spec.flag if spec.flag is not None else "--" + name.replace("_", "-")

    @classmethod
    def add_arguments(cls, parser, *, skip=(), rename=None, first=()):
        """Add a flag for every option (but ``skip``) to ``parser`` (or an argument group).

        Flags not given leave no attribute (argparse.SUPPRESS), so :meth:`from_args` returns
        only what the user said; ``rename`` maps an option name to another flag (``psrig run``
        spells the integration method ``--integrate-method``); ``first`` are added first.
        """
        rename = rename or {}
        specs = cls.specs()
        for name in [*first, *(n for n in specs if n not in first)]:
            default, spec = specs[name]
            flag = rename.get(name, cls.flag(name))
            if name in skip or not flag:
                continue
            kwargs = dict(dest=_dest(cls, name), default=argparse.SUPPRESS, help=cls.help_line(name).replace("%", "%%"))
            kind = spec.kind or type(default)
            if spec.const is not None:
                kwargs.update(action="store_const", const=spec.const)
            elif spec.cli:
                kwargs.update(choices=tuple(spec.cli))
            elif kind is bool and spec.parse is None:
                kwargs.update(action="store_true")
            elif spec.choices and spec.parse is None:
                kwargs.update(choices=spec.choices)
            else:
                kwargs.update(type=spec.parse or _text_parser(kind),
                              metavar=spec.metavar or (None if spec.choices else name.upper()))
                if spec.choices:
                    kwargs.update(choices=spec.choices)
            parser.add_argument(flag, **kwargs)
        return parser

    @classmethod
    def from_args(cls, args):
        """{name: API value} of the options given on the command line (see :meth:`add_arguments`)."""
        given = {}
        for name, (_, spec) in cls.specs().items():
            dest = _dest(cls, name)
            if hasattr(args, dest):
                value = getattr(args, dest)
                given[name] = spec.cli[value] if spec.cli else value
        return cls.check(given)


def _dest(cls, name):
    # one namespace holds every stage's options in `psrig run`: the attribute names the set
    return f"{cls.__name__}.{name}"


def _text_parser(kind):
    if kind in (float, int):
        return kind
    return str


def _check_value(kind, name, value, default, spec, prefix):
    if value is None:
        return
    label = f"{prefix}{kind} {name}"
    if spec.cli and value not in spec.cli.values():
        raise InputError(f"{label} must be one of {', '.join(map(repr, spec.cli.values()))}, got {value!r}")
    if spec.choices and value not in spec.choices:
        raise InputError(f"{label} must be one of {', '.join(map(str, spec.choices))}, got {value!r}")
    number = (spec.kind or type(default)) in (float, int) and not isinstance(value, bool)
    if number:
        try:
            value = float(value)
        except (TypeError, ValueError):
            raise InputError(f"{label} must be a number, got {value!r}") from None
        low = f"({spec.above}" if spec.above is not None else f"[{spec.low if spec.low is not None else '-inf'}"
        if value != value or (spec.low is not None and value < spec.low) or \
                (spec.above is not None and value <= spec.above) or (spec.high is not None and value > spec.high):
            raise InputError(f"{label} must be in {low}, {spec.high if spec.high is not None else 'inf'}], "
                             f"got {value!r}")
