"""psrig's YAML: aliases bounded when read, never written."""

import time

import numpy as np
import pytest
import yaml

from pipeline.core.errors import InputError
from pipeline.core.lightsio import LightSet, read_lights_yaml, write_lights_yaml
from pipeline.core.yamlio import MAX_EXPANSION, AliasRefused, YamlTooLarge, dump_yaml, load_yaml


def bomb(levels, fan=9):
    lines = ["l0: &l0 [" + ", ".join(["xxxxxxxx"] * fan) + "]"]
    lines += [f"l{i}: &l{i} [" + ", ".join([f"*l{i - 1}"] * fan) + "]" for i in range(1, levels)]
    return "\n".join(lines) + "\n"


def test_nested_aliases_are_refused_without_being_expanded():
    start = time.perf_counter()
    with pytest.raises(AliasRefused, match=r"line \d+: YAML aliases expand the document beyond"):
        load_yaml(bomb(12))  # 9**12 strings if built
    assert time.perf_counter() - start < 1


def test_an_alias_inside_its_own_node_is_refused():
    for text in ("a: &a [1, *a]\n", "a: &a {b: {c: *a}}\n"):
        with pytest.raises(AliasRefused, match="refers to a node that contains it"):
            load_yaml(text)


def test_anchors_that_share_a_part_of_a_file_are_read():
    text = "ring: &ring {elevation: 30, count: 8}\nrigs:\n  a: {rings: [*ring, *ring]}\n  b: {<<: *ring, count: 4}\n"
    data = load_yaml(text)
    assert data["rigs"]["a"]["rings"] == [{"elevation": 30, "count": 8}] * 2
    assert data["rigs"]["b"] == {"elevation": 30, "count": 4}
    assert load_yaml(bomb(3)) == yaml.safe_load(bomb(3))  # 9**3: within the bound
    assert MAX_EXPANSION >= 10


def test_text_beyond_the_size_bound_is_refused(monkeypatch):
    monkeypatch.setattr("pipeline.core.yamlio.MAX_YAML_BYTES", 100)
    with pytest.raises(YamlTooLarge):
        load_yaml("a: " + "x" * 200)


def test_psrig_writes_no_aliases(tmp_path):
    shared = [1.0, 2.0]
    assert "&" not in dump_yaml({"a": shared, "b": shared, "c": {"d": shared}})
    lights = LightSet(np.eye(3), extra={"x": shared, "y": shared})
    write_lights_yaml(tmp_path / "lights.yaml", lights)
    assert "&" not in (tmp_path / "lights.yaml").read_text()


def test_a_light_file_with_an_alias_bomb_is_an_input_error_naming_it(tmp_path):
    path = tmp_path / "lights.yaml"
    path.write_text("directions: [[0, 0, 1]]\n" + bomb(9))
    with pytest.raises(InputError, match=f"{path}: not valid YAML: line"):
        read_lights_yaml(path)
