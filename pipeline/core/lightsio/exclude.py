"""Lights left out by hand: ``calibration/exclude.yaml``, which no stage ever writes.

``lights.yaml`` is the calibrate stage's output: a rerun (a changed sphere frame, a new option,
the file itself edited) rewrites it. A light a user leaves out goes in ``exclude.yaml`` instead,
as ``lights: {index: why}`` (or a list of indices)::

    lights:
      3: misfired
      17: a reflection of the table

The normals stage leaves those lights out (the file is one of its inputs, so an edit reruns it)
and records them; ``psrig calibrate`` and ``psrig run`` say which lights are out by hand on
every run. Flags added by hand to a calibrated ``lights.yaml`` (not the calibration's own) are
carried into the rewritten file with a line saying to move them here.
"""

from ..errors import InputError
from ..paths import EXCLUDE
from ..yamlio import load_yaml

__all__ = ["read_exclude", "exclusion_note"]


def read_exclude(session, count=None):
    """{light index: why} from the session's ``calibration/exclude.yaml`` ({} when absent).

    Parameters
    ----------
    count : int, optional
        The number of lights: an index at or beyond it is refused, naming the file.
    """
    path = session.path(EXCLUDE)
    if not path.is_file():
        return {}
    try:
        data = load_yaml(path.read_text()) or {}
    except Exception as exc:  # a YAML error of any kind: name the file
        raise InputError(f"{path}: not valid YAML ({str(exc).splitlines()[0]})") from None
    if not isinstance(data, dict) or set(data) - {"lights"}:
        raise InputError(f"{path}: expected one key 'lights' (index: why, or a list of indices)")
    entries = data.get("lights") or {}
    if isinstance(entries, list):
        entries = {k: "" for k in entries}
    if not isinstance(entries, dict):
        raise InputError(f"{path}: key 'lights' must map light indices to reasons, or list indices")
    out = {}
    for key, why in entries.items():
        try:
            index = int(key)
        except (TypeError, ValueError):
            raise InputError(f"{path}: lights: {key!r} is not a light index (0-based)") from None
        if index < 0 or (count is not None and index >= count):
            raise InputError(f"{path}: lights: {index} is not a light of this session (0 .. {count - 1})"
                             if count is not None else f"{path}: lights: {index} is negative")
        out[index] = str(why or "no reason given")
    return dict(sorted(out.items()))


def exclusion_note(session):
    """'lights left out by hand (calibration/exclude.yaml): 3 (misfired), 17 (...)', or ''."""
    excluded = read_exclude(session)
    if not excluded:
        return ""
    return f"{len(excluded)} light(s) left out by hand ({EXCLUDE}): " + ", ".join(
        f"{index} ({why})" for index, why in excluded.items())
