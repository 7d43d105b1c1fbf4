import pytest

from pipeline.core.errors import InputError
from pipeline.core.registry import Registry


def test_lookup_names_the_known_choices():
    methods = Registry("integration method")

    @methods.register("smooth")
    def smooth():
        return 1

    methods.register("bilateral", object())
    assert methods["smooth"] is smooth
    assert methods.names() == ["bilateral", "smooth"]
    with pytest.raises(InputError, match=r"unknown integration method 'smoth'; known: bilateral, smooth"):
        methods["smoth"]
    assert "smoth" not in methods and "smooth" in methods


def test_error_class_is_the_callers():
    class Oops(Exception):
        pass

    with pytest.raises(Oops):
        Registry("camera driver", error=Oops)["x"]


def test_entry_point_plugins_load_lazily_and_broken_ones_are_named(monkeypatch):
    import importlib.metadata as md

    good = md.EntryPoint("good", "json:dumps", "psrig.test")
    bad = md.EntryPoint("bad", "no_such_module_psrig:thing", "psrig.test")
    monkeypatch.setattr(md, "entry_points", lambda group: [good, bad] if group == "psrig.test" else [])
    drivers = Registry("test driver", entry_points="psrig.test")
    drivers.register("builtin", 1)
    import json
    assert drivers["good"] is json.dumps
    assert "bad" not in drivers and "bad" in drivers.broken()
    with pytest.raises(InputError, match="'bad' is installed but cannot be loaded"):
        drivers["bad"]
