"""Named implementations of one family, and the one way to look them up.

Every family of interchangeable parts in psrig (photometric-stereo methods, reflectance models,
integration methods, raw decoding paths, rig drivers) is a :class:`Registry`: a read-only
mapping from name to implementation, filled with :meth:`Registry.register`, whose lookup
raises one clear error that lists the names it knows.

    METHODS = Registry("integration method")

    @METHODS.register("smooth")
    def smooth(normals, mask): ...

    METHODS["smoth"]   # InputError: unknown integration method 'smoth'; known: smooth

A registry may also name a group of Python entry points (``entry_points="psrig.cameras"``): the
implementations that installed distributions declare under that group are added the first time
the registry is read, so a third-party part is ``pip install``-able. A plugin that fails to load
is reported by name when it is asked for, and does not hide the others.
"""

from collections.abc import Mapping

from .errors import InputError

__all__ = ["Registry"]


class Registry(Mapping):
    """A mapping ``name -> implementation`` with registration and a lookup that names the choices.

    Parameters
    ----------
    kind : str
        What the names are, for messages ("photometric stereo method").
    error : type, optional
        Exception raised for an unknown name (default :class:`pipeline.core.errors.InputError`).
    entry_points : str, optional
        Group of Python entry points whose objects are registered on first use.
    """

    def __init__(self, kind, *, error=InputError, entry_points=None):
        self.kind = kind
        self.error = error
        self.group = entry_points
        self._items = {}
        self._broken = {}   # plugin name -> why it could not be loaded
        self._loaded = entry_points is None

    def register(self, name, obj=None):
        """Register ``obj`` under ``name``; without ``obj``, a decorator that does so."""
        if obj is not None:
            self._items[name] = obj
            return obj

        def decorate(func):
            self._items[name] = func
            return func
        return decorate

    def _load_plugins(self):
        if self._loaded:
            return
        self._loaded = True
        from importlib.metadata import entry_points

        for point in entry_points(group=self.group):
            if point.name in self._items:
                continue   # a built-in name is not replaced by a plugin
            try:
                self._items[point.name] = point.load()
            except Exception as exc:  # a broken plugin must not stop the built-in parts
                self._broken[point.name] = f"{point.value}: {type(exc).__name__}: {exc}"

    def __getitem__(self, name):
        self._load_plugins()
        try:
            return self._items[name]
        except (KeyError, TypeError):
            pass
        if name in self._broken:
            raise self.error(f"{self.kind} {name!r} is installed but cannot be loaded "
                             f"({self._broken[name]})")
        raise self.error(f"unknown {self.kind} {name!r}; known: {', '.join(self.names())}")

    def __contains__(self, name):
        self._load_plugins()
        return name in self._items

    def __iter__(self):
        self._load_plugins()
        return iter(self._items)

    def __len__(self):
        self._load_plugins()
        return len(self._items)

    def names(self):
        """The registered names, sorted."""
        return sorted(self)

    def broken(self):
        """{name: reason} of entry-point plugins that failed to load."""
        self._load_plugins()
        return dict(self._broken)
