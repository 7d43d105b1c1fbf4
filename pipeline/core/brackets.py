"""Exposure brackets in a session: which frames are one bracket, and how the stages see them.

A bracketed capture (a rig's ``exposure: {bracket: [1/60, 1/15]}``) shoots every frame once
per shutter time: frames ``<group>_b<n>``, each with ``bracket: {group, index, shutter, of}``
in the manifest (``shutter`` as the rig file wrote it, ``of`` the bracket's length). Decode
merges the exposures of a group (each minus the dark or ambient frame of its own shutter) into
``linear/<group>.exr`` (:mod:`pipeline.decode.merge`); every later stage sees the group as ONE
frame whose id is the group's
(:func:`stage_view`, :meth:`pipeline.core.session.Session.stage_frames`).

The manifest is checked here (:func:`check_brackets`, called for every manifest read or
written): the frames of a group share their kind and light and differ in index and shutter,
a group's id is no other frame's, and a kind's frames are all bracketed or none (frames of
one kind must end on one scale).
"""

import re
from dataclasses import dataclass

from .errors import ManifestError

__all__ = ["BracketGroup", "bracket_groups", "check_brackets", "stage_view", "shutter_seconds",
           "frame_shutter", "reference_shutter", "same_shutter", "format_seconds", "FRAME_ID"]

#: What a frame id (and so a bracket group's, which names the merged frame's files) may be.
FRAME_ID = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")

#: two recorded shutter times closer than this (relative) are the same one
_SAME = 1e-6


def shutter_seconds(value):
    """Seconds of a recorded shutter time (``1/60``, ``'1/60'``, ``'1/60 s'``, ``0.5``, ``'2'``).

    Raises
    ------
    ValueError
        When ``value`` is not a positive, finite time.
    """
    if isinstance(value, bool):
        raise ValueError(f"{value!r} is not a shutter time")
    if isinstance(value, (int, float)):
        seconds = float(value)
    else:
        text = str(value).strip().lower().removesuffix("s").strip()
        num, slash, den = text.partition("/")
        try:
            seconds = float(num) / float(den) if slash else float(text)
        except (ValueError, ZeroDivisionError):
            raise ValueError(f"{value!r} is not a shutter time") from None
    if not 0 < seconds < float("inf"):
        raise ValueError(f"{value!r} is not a positive shutter time")
    return seconds


def format_seconds(seconds):
    """A shutter time as people write it: ``1/60 s`` below a second, ``2 s`` above."""
    if seconds < 1 and abs(1 / seconds - round(1 / seconds)) < 1e-3 * (1 / seconds):
        return f"1/{round(1 / seconds)} s"
    return f"{seconds:g} s"


def same_shutter(a, b):
    """True when two shutter times (s, or None for unbracketed frames) are the same."""
    if a is None or b is None:
        return a is b
    return abs(a - b) <= _SAME * max(a, b)


def frame_shutter(frame):
    """The bracket shutter time (s) of a manifest frame, or None when it is not bracketed."""
    bracket = frame.get("bracket")
    return None if bracket is None else shutter_seconds(bracket["shutter"])


def reference_shutter(frames):
    """The shutter time (s) merged frames are scaled to: the shortest of the session's
    bracketed frames (one scale for every group, so that frames of different lights compare),
    or None when nothing is bracketed."""
    shutters = [frame_shutter(f) for f in frames if f.get("bracket") is not None]
    return min(shutters) if shutters else None


@dataclass(frozen=True)
class BracketGroup:
    """The exposures of one frame (one light, one kind) shot at each shutter of a bracket.

    Attributes
    ----------
    id : str
        The group's id (the frame id an unbracketed capture would have given), which the
        merged frame takes.
    kind : str
    light : int or None
    frames : tuple of dict
        The exposures present in the manifest, by bracket index.
    of : int or None
        The bracket's length as captured (None when the manifest does not say).
    """

    id: str
    kind: str
    light: object
    frames: tuple
    of: object = None

    @property
    def shutters(self):
        """Shutter times (s) of :attr:`frames`."""
        return tuple(frame_shutter(f) for f in self.frames)

    def missing(self):
        """Indexes of the bracket not among :attr:`frames` (a capture stopped mid-bracket)."""
        present = {f["bracket"]["index"] for f in self.frames}
        return [n for n in range(self.of or 0) if n not in present]

    def as_frame(self):
        """The merged frame as the stages after decode see it (a manifest-like dict): ``id``,
        ``kind``, ``light``, ``file`` (the first exposure's raw file), ``merged_from`` (the
        exposures' ids), ``shutters`` (as recorded) and an ambient frame's ``applies_to``."""
        first = self.frames[0]
        frame = {"id": self.id, "kind": self.kind, "light": self.light, "file": first["file"],
                 "merged_from": [f["id"] for f in self.frames],
                 "shutters": [str(f["bracket"]["shutter"]) for f in self.frames]}
        if "applies_to" in first:
            frame["applies_to"] = first["applies_to"]
        return frame


def bracket_groups(frames):
    """The bracket groups of manifest frames, in the order their first exposure appears.

    Frames are expected checked (:func:`check_brackets`).
    """
    groups = {}
    for frame in frames:
        if frame.get("bracket") is not None:
            groups.setdefault(frame["bracket"]["group"], []).append(frame)
    out = []
    for group_id, members in groups.items():
        members = sorted(members, key=lambda f: f["bracket"]["index"])
        first = members[0]
        out.append(BracketGroup(group_id, first["kind"], first.get("light"), tuple(members),
                                first["bracket"].get("of")))
    return out


def stage_view(frames):
    """Frames as the stages after decode see them: each bracket group as one frame
    (:meth:`BracketGroup.as_frame`, where its first exposure stands), the others as they are."""
    groups = {g.id: g for g in bracket_groups(frames)}
    out, seen = [], set()
    for frame in frames:
        bracket = frame.get("bracket")
        if bracket is None:
            out.append(frame)
        elif bracket["group"] not in seen:
            seen.add(bracket["group"])
            out.append(groups[bracket["group"]].as_frame())
    return out


def _check_entry(frame, where):
    """One frame's ``bracket:`` entry: group (a frame id), index (>= 0), shutter, of (>= 1)."""
    bracket = frame["bracket"]
    if not isinstance(bracket, dict):
        raise ManifestError(f"{where}.bracket: expected a mapping (group, index, shutter, of), got {bracket!r}")
    group, index, of = bracket.get("group"), bracket.get("index"), bracket.get("of")
    if not isinstance(group, str) or not FRAME_ID.match(group):
        raise ManifestError(f"{where}.bracket.group: expected the id of the frame bracketed, got {group!r}")
    if isinstance(index, bool) or not isinstance(index, int) or index < 0:
        raise ManifestError(f"{where}.bracket.index: expected a number >= 0, got {index!r}")
    if of is not None and (isinstance(of, bool) or not isinstance(of, int) or not index < of):
        raise ManifestError(f"{where}.bracket.of: expected the bracket's length (> index {index}), got {of!r}")
    try:
        shutter_seconds(bracket.get("shutter"))
    except ValueError as exc:
        raise ManifestError(f"{where}.bracket.shutter: {exc}") from None


def check_brackets(frames, where):
    """Raise :class:`pipeline.core.errors.ManifestError`, naming the frames, when the manifest's
    brackets cannot be merged: see the module docstring."""
    for i, frame in enumerate(frames):
        if frame.get("bracket") is not None:
            _check_entry(frame, f"{where}: frames[{i}]")
    ids = {f["id"] for f in frames}
    for group in bracket_groups(frames):
        first = group.frames[0]
        for frame in group.frames[1:]:
            if (frame["kind"], frame.get("light")) != (first["kind"], first.get("light")):
                raise ManifestError(
                    f"{where}: frames {first['id']!r} and {frame['id']!r} are exposures of bracket "
                    f"{group.id!r} but differ in kind or light ({first['kind']} light {first.get('light')}, "
                    f"{frame['kind']} light {frame.get('light')}); an exposure bracket is one frame")
        indexes, shutters = [f["bracket"]["index"] for f in group.frames], group.shutters
        for n, (index, shutter) in enumerate(zip(indexes, shutters)):
            twin = next((m for m in range(n) if indexes[m] == index or same_shutter(shutters[m], shutter)), None)
            if twin is not None:
                raise ManifestError(f"{where}: frames {group.frames[twin]['id']!r} and {group.frames[n]['id']!r} "
                                    f"of bracket {group.id!r} share their index or shutter time")
        if group.id in ids:
            raise ManifestError(f"{where}: bracket group {group.id!r} (of {first['id']!r}) is also a frame's id; "
                                "the merged frame takes the group's id")
    _check_kinds_uniform(frames, where)


def _check_kinds_uniform(frames, where):
    """A kind's frames are all bracketed or none: merged frames are on the reference shutter's
    scale, a frame shot once on its own shutter's."""
    first = {}  # (kind, bracketed) -> its first frame
    for frame in frames:
        first.setdefault((frame["kind"], frame.get("bracket") is not None), frame)
    for (kind, bracketed), frame in first.items():
        if bracketed and (kind, False) in first:
            raise ManifestError(f"{where}: {kind} frames {frame['id']!r} (an exposure bracket) and "
                                f"{first[(kind, False)]['id']!r} (a single exposure) mix; a kind's frames "
                                "are all exposure brackets or none")
