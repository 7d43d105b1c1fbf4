"""YAML in psrig's files: what may be written (plain types) and how it is read (safely).

Manifests, stage records, light files and rig files are YAML read with safe loading only.
What goes into them is first made plain (:func:`plain`): numpy scalars and arrays become
Python numbers and lists, tuples lists, paths strings, mapping keys strings, so that the file
holds no Python tags and reads back equal to what was compared.

They are read with :func:`load_yaml`, which bounds what aliases (``*name``, merge keys
``<<: *name`` included) may expand to: a few kilobytes of nested aliases expand to gigabytes in
memory (a 79 KB manifest made a 742 MB report page). Anchors that share a part of a hand-written
rig file expand a little and are fine; a document that expands to more than
:data:`MAX_EXPANSION` times the nodes it holds, or an alias inside the node it names, is
refused. psrig itself writes no aliases (:func:`dump_yaml`).
"""

from pathlib import PurePath

import numpy as np
import yaml

__all__ = ["plain", "load_yaml", "dump_yaml", "AliasRefused", "YamlTooLarge", "MAX_YAML_BYTES",
           "MAX_EXPANSION"]

# libyaml's safe loader and dumper when PyYAML has them (same text, ~5x faster: a capture saves
# the manifest after every frame), else PyYAML's pure-Python safe ones.
_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
_DUMPER = getattr(yaml, "CSafeDumper", yaml.SafeDumper)
#: Largest YAML text psrig reads (a 10,000-frame manifest is about 3 MB).
MAX_YAML_BYTES = 64 << 20
#: Aliases may make a document at most this many times the nodes it holds (plus _SLACK nodes).
MAX_EXPANSION = 10
_SLACK = 100_000


class AliasRefused(yaml.YAMLError):
    """YAML aliases (``*name``) that expand too far, or into themselves; callers report it like
    any YAML error (adding the file's name)."""


class YamlTooLarge(yaml.YAMLError):
    """YAML text beyond :data:`MAX_YAML_BYTES`."""


def plain(value, decimals=None):
    """A YAML-safe copy of ``value``, recursively.

    Parameters
    ----------
    value
        Mappings, sequences, numpy arrays and scalars, paths and plain values, nested.
    decimals : int, optional
        Round numpy arrays to this many decimals (rig geometry in files people read).
    """
    if isinstance(value, dict):
        return {str(k): plain(v, decimals) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(v, decimals) for v in value]
    if isinstance(value, np.ndarray):
        return (value if decimals is None else np.round(value, decimals)).tolist()
    if isinstance(value, PurePath):
        return str(value)
    if isinstance(value, np.generic):
        return value.item()
    return value


def load_yaml(text, loader=None):
    """Parse YAML text with a safe loader, bounding alias expansion and size.

    Parameters
    ----------
    text : str
    loader : yaml loader class, optional
        A subclass of ``yaml.SafeLoader`` with checks of its own (rig files refuse duplicate
        keys); default libyaml's safe loader.

    Returns
    -------
    The document (plain Python types), None for empty text.

    Raises
    ------
    yaml.YAMLError
        Invalid YAML; :class:`AliasRefused` naming the line of the alias at fault;
        :class:`YamlTooLarge`. Callers add the file's name.
    """
    if len(text) > MAX_YAML_BYTES:
        raise YamlTooLarge(f"{len(text) / 2**20:.0f} MB of YAML is more than the "
                           f"{MAX_YAML_BYTES >> 20} MB psrig reads")
    # an alias needs an anchor: text without '&' has none, and is parsed only once
    if "&" in text:
        _check_aliases(text)
    return yaml.load(text, Loader=loader or _LOADER)


def _check_aliases(text):
    """Count the nodes the document expands to, from its events (nothing is built)."""
    sizes, open_nodes, written, expanded = {}, [], 0, 0
    for event in yaml.parse(text, Loader=_LOADER):
        if isinstance(event, (yaml.ScalarEvent, yaml.AliasEvent, yaml.CollectionStartEvent)):
            written += 1
            if isinstance(event, yaml.AliasEvent):
                if event.anchor not in sizes:  # still open: the alias is inside its own node
                    raise AliasRefused(f"line {event.start_mark.line + 1}: alias *{event.anchor} "
                                       "refers to a node that contains it")
                size = sizes[event.anchor]
            else:
                size = 1
            if isinstance(event, yaml.CollectionStartEvent):
                open_nodes.append([event.anchor, 1])
                continue
            if event.anchor and isinstance(event, yaml.ScalarEvent):
                sizes[event.anchor] = 1
            expanded += size
            if open_nodes:
                open_nodes[-1][1] += size
        elif isinstance(event, yaml.CollectionEndEvent):
            anchor, size = open_nodes.pop()
            expanded += 1
            if anchor:
                sizes[anchor] = size
            if open_nodes:
                open_nodes[-1][1] += size
        if expanded > MAX_EXPANSION * written + _SLACK:
            raise AliasRefused(f"line {event.start_mark.line + 1}: YAML aliases expand the "
                               f"document beyond {MAX_EXPANSION} times its {written} nodes; "
                               "psrig refuses it (a small file could take gigabytes)")


class _PlainDumper(_DUMPER):
    """Writes a value shared by several keys out at each (no anchors and aliases)."""

    def ignore_aliases(self, data):
        return True


def dump_yaml(data):
    """YAML text of plain data (:func:`plain`), keys in insertion order, with no aliases, with
    libyaml when present."""
    return yaml.dump(data, Dumper=_PlainDumper, sort_keys=False, allow_unicode=True)
