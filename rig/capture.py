"""Capture a session: dark and ambient frames, one frame per light, then the chrome sphere.

:func:`capture_session` drives a rig's light controller and camera (the simulated rig's when the
rig is ``sim``) and stores every frame in a session folder exactly as the camera delivered it.

The rig's ``exposure:`` (shutter, iso, aperture) is set on the camera once it is open, before any
frame; an exposure the camera refuses or lacks stops the capture before the first frame, naming
the key and the value. The manifest records the request (``rig.exposure``), what the camera
reported back (``camera.exposure``: value, property, device value) and each frame's settings.

Order: ``dark_000..`` (lights OFF; the simulated rig lets no light reach the sensor),
``ambient_000..`` (lights OFF), ``object_000 .. object_{K-1}`` (light i ON, confirmed by the
controller, expose, download, atomic write; the manifest is saved at least every
:data:`MANIFEST_INTERVAL` seconds and when the capture stops), then ``sphere_000..`` the same way
once the chrome sphere is in place (real rigs ask first; ``sphere=False`` skips them), then,
with the rig's ``frames: outline: true``, ``outline_000``: lights OFF, the spheres lit evenly by
the room (real rigs ask first), on which calibration finds their outlines. The
lights are switched OFF in a ``finally``, on Ctrl-C and on SIGTERM (turned into
:class:`CaptureInterrupted` while the capture runs).

Resuming (``resume=True``) never loses or overwrites a capture:

- frames of the manifest must still match their sha256; a missing or changed file is an error
  naming it. It is NOT recaptured: the scene may have moved since, and a frame shot later would
  silently mix two states of the object. Restore the file or capture into a new session.
- a raw file that is not in the manifest (the process died between the raw file's atomic
  rename and the manifest update) is adopted when it parses as a complete raw file; anything
  else found in ``raw/`` is moved to ``raw/.partial/`` (never deleted) and recaptured.
- temporary files left by interrupted atomic writes are removed.
- a session of another rig, or of the same simulated rig with another ``scene:``, is refused.

Simulated sessions get their ground truth (``truth/``, the TRUE lights included) at the start;
the manifest's ``lights`` hold only the rig's NOMINAL lights, as for a real rig.
"""

from __future__ import annotations

import datetime as _dt
import os
import re
import sys
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pipeline.core.errors import PsrigError, SessionError, describe_os_error
from pipeline.core.progress import progress as progress_bar
from pipeline.core.session import FOLDERS, MANIFEST, Session, now_iso
from pipeline.core.signals import sigterm_raises
from rig.camera import CameraError, format_exposure
from rig.drivers import make_camera, make_light_controller
from rig.keepalive import LightHold
from rig.lights import LightError
from rig.rawtype import RawTypeError, raw_extension

__all__ = ["capture_session", "plan_frames", "check_raw_file", "CaptureError", "CaptureInterrupted",
           "open_devices", "set_camera_exposure", "set_light_levels", "preview_check",
           "Shot", "PARTIAL", "SPHERE_PROMPT", "OUTLINE_PROMPT",
           "MANIFEST_INTERVAL"]

PARTIAL = "raw/.partial"
SPHERE_PROMPT = "Place the chrome sphere where the object was (object removed), then press Enter"
OUTLINE_PROMPT = ("Light the sphere(s) evenly with the room light (the rig's lights stay off; camera and "
                  "spheres unmoved) for the outline photo, then press Enter")
_TEMP_FILE = re.compile(r"^\..+\.tmp(\.[^.]*)?$")  # pipeline.core.atomic's temporary names
#: Seconds between manifest saves during a capture (0: after every frame, the default; a manifest
#: save costs a few ms with libyaml). The raw files are written atomically at once either way; a
#: frame whose manifest entry was not saved yet when the process died is adopted on --resume
#: (losing only its camera file name).
MANIFEST_INTERVAL = 0.0
_TIFF_RAW = {".dng", ".tif", ".tiff", ".nef", ".nrw", ".cr2", ".arw", ".pef"}


class CaptureError(PsrigError):
    """A capture failed or cannot start; names the session, the frame and the light.

    Attributes
    ----------
    frame_id : str or None
    light : int or None
    """

    def __init__(self, message, frame_id=None, light=None):
        super().__init__(message)
        self.frame_id, self.light = frame_id, light


class CaptureInterrupted(KeyboardInterrupt):
    """SIGTERM arrived during a capture (handled like Ctrl-C: lights OFF, session kept)."""


@dataclass(frozen=True)
class Shot:
    """One planned frame: its id, kind, light (None for dark and ambient frames) and the extra
    keys its manifest entry gets."""

    frame_id: str
    kind: str
    light: int | None = None
    extra: dict = field(default_factory=dict)
    shutter: str | None = None  # a bracketed shot's shutter time, as the rig file writes it


@dataclass
class _Devices:
    lights: object
    camera: object
    sim: object = None
    exposure: dict = field(default_factory=dict)


def plan_frames(rig_config, sphere=True):
    """The frames a capture on ``rig_config`` takes, in order (list of :class:`Shot`)."""
    frames, count = rig_config.frames, rig_config.lights.count
    plan = [Shot(f"dark_{n:03d}", "dark") for n in range(frames.get("dark", 0))]
    # shot with the object in view: its ambient light is the object frames' (decode subtracts it
    # from those only; sphere frames, shot later in another scene, get the dark frames)
    plan += [Shot(f"ambient_{n:03d}", "ambient", extra={"applies_to": ["object"]})
             for n in range(frames.get("ambient", 0))]
    plan += [Shot(f"object_{i:03d}", "object", i) for i in range(count)]
    if sphere:
        plan += [Shot(f"sphere_{i:03d}", "sphere", i) for i in range(count)]
        if frames.get("outline", False):
            plan.append(Shot("outline_000", "outline"))
    return _bracketed(plan, rig_config.exposure.get("bracket"))


def _bracketed(plan, bracket):
    """Each shot once per shutter of ``bracket`` (None: the plan as it is), one light's
    exposures one after the other: ids ``<id>_b<n>``, the group (the unbracketed id), the
    index and the shutter recorded in each frame's ``bracket``."""
    if not bracket:
        return plan
    return [Shot(f"{shot.frame_id}_b{n}", shot.kind, shot.light,
                 {**shot.extra, "bracket": {"group": shot.frame_id, "index": n,
                                            "shutter": str(value), "of": len(bracket)}},
                 shutter=str(value))
            for shot in plan for n, value in enumerate(bracket)]


# -- the entry point ------------------------------------------------------------------------------

def capture_session(target, rig_config, *, resume=False, sim=None, progress=True, sphere=None,
                    on_prompt=None, echo=print, preview=False, max_clipped=None):
    """Capture (or, with ``resume``, complete) a session on a rig.

    Parameters
    ----------
    target : path or Session
        Session folder (new, empty, or an existing session to resume) or an open Session.
    rig_config : rig.config.RigConfig
        The rig (``rig.config.get_rig(name)``).
    resume : bool
        Complete an existing session (see the module docstring); without it a session that
        already holds frames is refused.
    sim : rig.sim.rig.SimulatedRig, optional
        The simulated rig to use (opened and closed here unless already open). Default: one is
        made for a simulated rig.
    progress : bool
        Show a progress bar (frames) on stderr when it is a terminal.
    sphere : bool, optional
        Shoot the sphere frames; default the rig's ``frames.sphere``.
    on_prompt : callable, optional
        ``on_prompt(message) -> bool`` asks the operator to place the sphere (real rigs);
        False skips the sphere frames. Default: a terminal prompt.
    echo : callable
        Receives one line per event (resume summary, adopted files, total time).
    preview : bool
        Before the first lit frame of a session, preview the brightest light and refuse to
        start when it clips more than ``max_clipped`` (default the rig's
        ``preview: max_clipped``); ``psrig capture`` turns it on unless told not to.

    Returns
    -------
    Session
    """
    start = time.perf_counter()
    sphere = bool(rig_config.frames.get("sphere", True) if sphere is None else sphere)
    session, root = _existing_session(target, rig_config, resume)
    with open_devices(rig_config, sim) as devices, sigterm_raises(CaptureInterrupted):
        devices.exposure = set_camera_exposure(rig_config, devices, echo)
        set_light_levels(rig_config, devices, echo)
        checked = None
        if preview and not (session and any(f.get("light") is not None for f in session.frames())):
            checked = preview_check(rig_config, devices, max_clipped, echo)
        session = (session or Session.create(root)).acquire("capture")
        if checked is not None:
            session.manifest["rig"]["preview"] = checked
        _record_rig(session, rig_config, devices, echo, devices.exposure)
        if devices.sim is not None and not _truth_complete(session):
            devices.sim.write_truth(session)
        plan = plan_frames(rig_config, sphere)
        todo = _reconcile(session, rig_config, plan, echo)
        taken = _capture_frames(session, rig_config, devices, todo, total=len(plan),
                                show=progress, on_prompt=on_prompt, echo=echo)
    echo(f"capture: {session.root}: {taken} frame{'s' * (taken != 1)} captured in "
         f"{time.perf_counter() - start:.1f} s, {len(session.frames())} in the session")
    return session


# -- before the devices: which session ----------------------------------------------------------

def _existing_session(target, rig_config, resume):
    """(Session or None, root): the session to continue, checked against the rig and ``resume``."""
    if isinstance(target, Session):
        session, root = target, target.root
    else:
        root = Path(target)
        if not (root / MANIFEST).is_file():
            if resume:
                _clear_stillborn(root)
            if root.exists() and (not root.is_dir() or any(root.iterdir())):
                raise SessionError(f"{root}: exists and is neither an empty folder nor a session; "
                                   "choose a new or empty folder")
            return None, root
        session = Session.open(root)
    recorded = session.manifest["rig"]
    if recorded.get("name") not in (None, rig_config.name):
        raise CaptureError(f"{session.root}: a session of rig {recorded['name']!r}; it cannot be "
                           f"continued with rig {rig_config.name!r}")
    if "scene" in recorded and recorded["scene"] != dict(rig_config.scene or {}):
        raise CaptureError(f"{session.root}: captured with scene {recorded['scene']!r}, the rig "
                           f"{rig_config.name!r} now has scene {dict(rig_config.scene or {})!r}")
    raw = session.path("raw")
    stored = raw.is_dir() and any(p.is_file() and not p.name.startswith(".") for p in raw.iterdir())
    if not resume and (session.frames() or stored):
        raise CaptureError(f"{session.root}: already holds {len(session.frames())} frames; use "
                           "--resume to complete it, or choose a new folder")
    return session, root


def _clear_stillborn(root):
    """Remove what a capture killed inside ``Session.create`` left: empty folders and temp files."""
    if not root.is_dir():
        return
    entries = list(root.iterdir())
    empty_dirs = [p for p in entries if p.is_dir() and p.name in FOLDERS and not any(p.iterdir())]
    temps = [p for p in entries if p.is_file() and _TEMP_FILE.match(p.name)]
    if entries and len(empty_dirs) + len(temps) == len(entries):
        for path in temps:
            path.unlink()
        for path in empty_dirs:
            path.rmdir()


# -- devices ------------------------------------------------------------------------------------

@contextmanager
def open_devices(rig_config, sim):
    """Yield the opened lights and camera (of ``sim``, a new simulated rig, or the hardware)."""
    if sim is None and rig_config.simulated_camera:
        from rig.sim.rig import SimulatedRig  # the simulator stays out of real rigs' imports

        sim = SimulatedRig(rig_config)
    if sim is not None:
        owned = not sim.is_open
        if owned:
            sim.open()
        try:
            yield _Devices(sim.lights, sim.camera, sim)
        finally:
            if owned:
                sim.close()
        return
    try:
        lights, camera = make_light_controller(rig_config.lights), make_camera(dict(rig_config.camera))
    except (LightError, CameraError) as exc:
        raise CaptureError(f"{rig_config.source}: rig '{rig_config.name}': {exc}") from None
    with lights, camera:  # the lights' context switches them OFF on the way out
        yield _Devices(lights, camera)



# -- the manifest ---------------------------------------------------------------------------------

def set_camera_exposure(rig_config, devices, echo):
    """Set the rig's ``exposure:`` on the camera (before any frame); what it reported back."""
    if not rig_config.exposure:
        return {}
    exposure = {k: v for k, v in rig_config.exposure.items() if k != "bracket"}
    if rig_config.exposure.get("bracket"):
        exposure["shutter"] = rig_config.exposure["bracket"][0]
    try:
        report = devices.camera.set_exposure(exposure)
    except CameraError as exc:
        raise CaptureError(f"{rig_config.source}: rig '{rig_config.name}': {exc}; nothing was "
                           "captured") from exc
    echo("capture: exposure set on the camera: "
         + ", ".join(rec["display"] for rec in report.values()))
    return report


def preview_check(rig_config, devices, max_clipped=None, echo=print):
    """Preview the rig's brightest light (or ``preview: light``); PreviewError when it clips
    more than ``max_clipped`` (default the rig's). Returns what to record in the manifest."""
    from rig.preview import brightest_light, check_clipping, take_preview

    limit = rig_config.preview["max_clipped"] if max_clipped is None else float(max_clipped)
    light = rig_config.preview.get("light", "auto")
    light = brightest_light(rig_config) if light == "auto" else int(light)
    shutter = (devices.exposure.get("shutter") or {}).get("value")
    (stats,) = take_preview(devices, [light], shutter=shutter)
    check_clipping(stats, limit)
    channel, share = stats.worst_clipped
    echo(f"capture: preview of light {light}: at most {100 * share:.2f} % clipped ({channel}), "
         f"allowed {100 * limit:.2f} %")
    return {"light": light, "clipped": stats.clipped, "max_clipped": limit,
            "percentile_99_9": {c: v[99.9] for c, v in stats.percentiles.items()},
            "focus": round(stats.focus, 6)}


def set_light_levels(rig_config, devices, echo):
    """``LEVEL i v`` for every light of the rig's ``lights: levels:`` (before any frame)."""
    levels = rig_config.lights.get("levels")
    if levels is None:
        return
    try:
        for index, level in enumerate(levels):
            devices.lights.set_level(index, int(level))
    except LightError as exc:
        raise CaptureError(f"{rig_config.source}: rig '{rig_config.name}': lights.levels: {exc}; "
                           "nothing was captured") from exc
    dark = [i for i, level in enumerate(levels) if level == 0]
    echo(f"capture: light levels set ({min(levels)}-{max(levels)} of 255)"
         + (f"; lights {', '.join(map(str, dark))} at level 0 will give dark frames" if dark else ""))


def _frame_exposure(rig_config, exposure):
    """A frame's ``exposure`` entry: the values the camera reported (the request where unset)."""
    out = {k: v for k, v in rig_config.exposure.items() if k != "bracket"}
    for key, rec in exposure.items():
        value = rec["value"]
        if key == "shutter":
            value = format_exposure(key, value).removesuffix(" s")
        elif key == "iso":
            value = int(round(value))
        out[key] = value
    return out


def _record_rig(session, rig_config, devices, echo, exposure=None):
    """Rig, camera and nominal lights into the manifest (a resumed session keeps its camera)."""
    lights = rig_config.lights
    session.manifest["rig"].update({
        "name": rig_config.name, "description": rig_config.description,
        "config": str(rig_config.source), "simulated": devices.sim is not None,
        "lights": {"driver": lights.driver, "count": int(lights.count), "port": lights.get("port")},
        "camera": dict(rig_config.camera),
        "exposure": dict(rig_config.exposure), "frames": dict(rig_config.frames),
        "raw_format": rig_config.raw_format, "scene": dict(rig_config.scene or {})})
    info = _camera_record(devices.camera)
    if exposure:  # the camera's own values, as read back after setting them
        info["exposure"] = {key: {k: v for k, v in rec.items() if k != "display"}
                            for key, rec in exposure.items()}
    old = session.manifest["camera"]
    if old and (old.get("model"), old.get("serial")) != (info["model"], info["serial"]):
        echo(f"capture: warning: {session.root} was begun with camera {old.get('model')} "
             f"#{old.get('serial')}; continuing with {info['model']} #{info['serial']}")
        info["earlier"] = old
    if old and exposure and old.get("exposure") and old["exposure"] != info["exposure"]:
        echo(f"capture: warning: {session.root} was begun with another exposure; the frames "
             "record each their own")
    session.manifest["camera"] = info
    session.manifest["lights"].update({
        "source": "nominal", "origin": f"rig '{rig_config.name}' ({rig_config.source})",
        "count": int(lights.count), "directions": np.round(lights.directions, 8).tolist(),
        "levels": None if lights.get("levels") is None else [int(v) for v in lights.levels],
        "positions": None if lights.get("positions") is None
        else np.round(np.asarray(lights.positions, float), 6).tolist()})
    session.save()


def _camera_record(camera):
    info = camera.device_info
    return {"manufacturer": info.get("manufacturer"), "model": info.get("model"),
            "serial": info.get("serial"), "device_version": info.get("device_version"),
            "ptp_version": info.get("ptp_version"),
            "vendor_extension_id": info.get("vendor_extension_id"), "path": info.get("path")}


def _truth_complete(session):
    # spheres.yaml is written last by SimulatedRig.write_truth: its record means all is there
    path = session.truth("spheres")
    return path is not None and path.is_file()


# -- resume: reconcile the folder with the manifest -------------------------------------------------

def _reconcile(session, rig_config, plan, echo):
    """Check and repair the session before capturing; returns the shots still to take."""
    _refuse_links(session)
    for folder in (session.root, session.path("raw"), session.path("truth")):
        for path in folder.glob(".*.tmp*") if folder.is_dir() else ():
            if path.is_file() and _TEMP_FILE.match(path.name):
                path.unlink()
    for frame in session.frames():
        try:
            session.verify_frame(frame)
        except SessionError as exc:
            raise CaptureError(f"{exc}. psrig never captures over a frame: restore the file, or "
                               "capture into a new session", frame["id"], frame.get("light")) from None
    session.hashes.save()
    _adopt_orphans(session, plan_frames(rig_config, sphere=True), echo)
    done = {f["id"] for f in session.frames()}
    todo = [shot for shot in plan if shot.frame_id not in done]
    if done:
        echo(f"capture: {session.root}: {len(plan) - len(todo)} of {len(plan)} frames present and "
             f"verified, {len(todo)} to capture")
    return todo


def _refuse_links(session):
    """psrig writes raw files itself, never through a link: any symbolic link in raw/ (an
    orphan pointing nowhere above all, which a write would silently replace) is refused."""
    raw = session.root / "raw"
    for path in sorted(raw.iterdir()) if raw.is_dir() and not raw.is_symlink() else ():
        if path.is_symlink():
            target = os.readlink(path)
            state = "which does not exist (an orphan link)" if not path.exists() else "a link"
            raise CaptureError(f"{session.root}: raw/{path.name} is a symbolic link to {target}, "
                               f"{state}; raw files are written by psrig, never through links: "
                               "remove it (or put the real file back in its place), then resume")


def _adopt_orphans(session, plan, echo):
    """Adopt complete raw files missing from the manifest; move anything else to raw/.partial/."""
    planned = {shot.frame_id: shot for shot in plan}
    known = {f["file"] for f in session.frames()}
    raw = session.path("raw")
    for path in sorted(raw.iterdir()) if raw.is_dir() else ():
        if not path.is_file() or path.name.startswith(".") or session.rel(path) in known:
            continue
        shot = planned.get(path.stem)
        problem = None if shot and not session.has_frame(shot.frame_id) else "not a frame of this capture"
        problem = problem or check_raw_file(path)
        if problem is None:
            stamp = _dt.datetime.fromtimestamp(path.stat().st_mtime, _dt.timezone.utc)
            session.adopt_frame(shot.kind, session.rel(path), light=shot.light, frame_id=shot.frame_id,
                                captured_at=stamp.replace(microsecond=0).isoformat(), **shot.extra)
            echo(f"capture: adopted {session.rel(path)} (written before the last capture stopped)")
        else:
            moved = _quarantine(session, path)
            echo(f"capture: moved {session.rel(path)} to {session.rel(moved)}: {problem}")


def _quarantine(session, path):
    """Move ``path`` into raw/.partial/ under a free name; returns the new path."""
    folder = session.path(PARTIAL)
    folder.mkdir(parents=True, exist_ok=True)
    target, n = folder / path.name, 1
    while target.exists():
        target, n = folder / f"{path.name}.{n}", n + 1
    os.replace(path, target)
    return target


def check_raw_file(path):
    """Why ``path`` is not a complete raw file, or None when it is.

    TIFF-based raws (DNG, NEF, CR2, ARW, ...) are parsed with tifffile: every IFD (sub-IFDs
    included) must parse and its image data must lie inside the file. Other formats must be
    unpacked by rawpy.
    """
    path = Path(path)
    if path.suffix.lower() in _TIFF_RAW:
        return _check_tiff(path)
    try:
        import rawpy

        with rawpy.imread(str(path)) as raw:
            raw.raw_image  # noqa: B018 - unpacking reads every byte of the mosaic
    except Exception as exc:  # LibRaw raises a zoo of its own types for broken files
        return f"rawpy cannot read it ({type(exc).__name__}: {exc})"
    return None


def _check_tiff(path):
    import tifffile

    size = path.stat().st_size
    try:
        with tifffile.TiffFile(path) as tif:
            pages, found = list(tif.pages), False
            while pages:
                page = pages.pop()
                ends = np.add(page.dataoffsets, page.databytecounts)
                if len(ends) and ends.max() > size:
                    return f"image data ends at byte {int(ends.max())}, the file has {size}"
                found |= bool(len(ends))
                pages.extend(getattr(page, "pages", None) or [])
    except Exception as exc:  # tifffile reports damage with several exception types
        return f"not a complete TIFF/DNG ({type(exc).__name__}: {exc})"
    return None if found else "no image data in it"


# -- capturing ------------------------------------------------------------------------------------

def _capture_frames(session, rig_config, devices, todo, *, total, show, on_prompt, echo):
    """Take the shots of ``todo`` (of ``total`` planned); lights OFF afterwards whatever happens.

    Returns the number of frames taken (sphere frames the operator declined are not).
    """
    ok, asked, saved, before = False, set(), time.monotonic(), len(session.frames())
    try:
        with progress_bar(total=total, desc="capture", unit="frame",
                          disable=None if show else True) as bar:
            bar.update(total - len(todo))
            for shot in todo:
                if shot.kind in _PROMPTS and shot.kind not in asked:
                    asked.add(shot.kind)
                    if not _scene_ready(devices, shot.kind, on_prompt):
                        echo(f"capture: {shot.kind} frames skipped; --resume captures them later")
                        break
                _capture_one(session, rig_config, devices, shot)
                if time.monotonic() - saved >= MANIFEST_INTERVAL:
                    session.save()
                    saved = time.monotonic()
                bar.update(1)
        ok = True
    finally:
        try:
            _lights_off(devices.lights, raise_errors=ok)
        finally:
            session.save()
    return len(session.frames()) - before


#: frame kind -> what the operator is asked before the first frame of that kind
_PROMPTS = {"sphere": SPHERE_PROMPT, "outline": OUTLINE_PROMPT}


def _scene_ready(devices, kind, on_prompt):
    """Lights off, then the scene for ``kind`` frames: the simulator switches scene, an
    operator is asked (False: skip those frames)."""
    devices.lights.off()
    if devices.sim is not None:
        devices.sim.set_scene(devices.sim.scene_for(kind))
        return True
    prompt = _PROMPTS[kind]
    if on_prompt is not None:
        return bool(on_prompt(prompt))
    if not sys.stdin or not sys.stdin.isatty():
        skip = "skip the sphere with --no-sphere" if kind == "sphere" else "set the rig's frames: outline: false"
        raise CaptureError(f"{prompt!r} needs a terminal; answer it in advance with --yes, or {skip}")
    answer = input(f"{prompt} (or type 'skip'): ")
    return answer.strip().lower() not in ("skip", "s", "n", "no")


def _capture_one(session, rig_config, devices, shot):
    """Light, expose, download, store one frame; errors name the frame and the light."""
    what = f"frame {shot.frame_id}" + ("" if shot.light is None else f" (light {shot.light})")
    if devices.sim is not None:
        devices.sim.before_frame(shot.frame_id, shot.kind)
    try:
        _set_shutter(devices, shot)
        image = _expose_held(devices, shot, what)
    except (LightError, CameraError) as exc:
        dark, left_on = _switch_off(devices.lights)
        error = CaptureError(
            f"{session.root}: {what}: {exc}. Stopped: {dark}; the {len(session.frames())} frames "
            "captured so far are kept: run the capture again with --resume to complete the session",
            shot.frame_id, shot.light)
        error.lights_left_on = left_on
        raise error from exc
    if image.size != len(image.data):
        raise CaptureError(f"{session.root}: {what}: the camera delivered {len(image.data)} of "
                           f"{image.size} bytes; not stored", shot.frame_id, shot.light)
    try:  # psrig names the file: the camera's name is only metadata (it may hold anything)
        suffix = "." + raw_extension(image.data, rig_config.raw_format)
    except RawTypeError as exc:
        raise CaptureError(f"{session.root}: {what}: the camera delivered a file "
                           f"({_printable(image.filename)}) that is {exc}; not stored",
                           shot.frame_id, shot.light) from None
    levels = rig_config.lights.get("levels")
    extra = dict(shot.extra)
    if levels is not None and shot.light is not None:
        extra["level"] = int(levels[shot.light])
    try:
        session.add_frame(shot.kind, image.data, light=shot.light, suffix=suffix, frame_id=shot.frame_id,
                          save=False, exposure=_frame_exposure(rig_config, devices.exposure),
                          captured_at=now_iso(),
                          camera_file=_printable(image.filename), **extra)
    except OSError as exc:   # a full disk: said in one line, the frames before are kept
        raise CaptureError(f"{what}: cannot store {describe_os_error(exc)}; not stored. The "
                           f"{len(session.frames())} frames captured so far are kept: free some space, then "
                           "run the capture again with --resume", shot.frame_id, shot.light) from None


def _set_shutter(devices, shot):
    """Set a bracketed shot's shutter on the camera when it differs from the one set."""
    current = (devices.exposure.get("shutter") or {}).get("requested")
    if shot.shutter is None or str(current) == shot.shutter:
        return
    report = devices.camera.set_exposure({"shutter": shot.shutter})
    devices.exposure = {**devices.exposure, **report}


def _printable(name):
    """The camera's file name as manifest metadata: control characters escaped, bounded."""
    text = "".join(c if c.isprintable() else repr(c)[1:-1] for c in str(name))
    return text[:200]


#: Exposures of a frame whose light did not hold (watchdog, interlock) before it is refused.
LIGHT_ATTEMPTS = 2


def _expose_held(devices, shot, what):
    """Light ``shot.light`` (or all off), expose with the light held, download; the image.

    A frame whose light was not lit all through the exposure is shot again once, then refused
    (:class:`rig.lights.LightError` naming the frame), never stored.
    """
    problems = []
    for _ in range(LIGHT_ATTEMPTS):
        if shot.light is None:
            devices.lights.off()
        else:
            devices.lights.on(shot.light)
        with LightHold(devices.lights, shot.light, _longest_wait(devices)) as hold:
            image = devices.camera.capture()
        problem = hold.problem()
        if problem is None:
            return image
        problems.append(problem)
    raise LightError(f"{what}: {'; then '.join(problems)}; the frame was not stored "
                     f"({LIGHT_ATTEMPTS} exposures)")


def _longest_wait(devices):
    """Real seconds an exposure may take at most: the camera's timeout plus the shutter."""
    shutter = (devices.exposure.get("shutter") or {}).get("value") or 0.0
    return float(getattr(devices.camera, "timeout", 30.0)) + float(shutter) + 5.0


def _switch_off(lights):
    """Switch the lights off after a failed frame; (what the operator is told of the lights,
    the warning when some may still be on, else None).

    "The lights are switched off" is said only when the controller acknowledged the OFF."""
    if not getattr(lights, "is_open", True):
        return "the light controller is gone (its watchdog switches the lights off)", None
    try:
        lights.off()
    except LightError as exc:
        warning = left_on_warning(lights, exc)
        return warning, warning
    return "the lights are switched off", None


def left_on_warning(lights, exc):
    """The operator's warning that lights may still be on after ``exc`` refused the OFF."""
    which = lights.describe_maybe_lit() if hasattr(lights, "describe_maybe_lit") else "the lights"
    which = which or "the lights"
    verb = "may still be on" if which != "the lights" else "may not be switched off"
    return (f"{which} {verb} (switching the lights off failed: {exc}): check the rig and switch "
            "them off by hand")


def _lights_off(lights, raise_errors):
    """OFF, confirmed; a failure is raised only when nothing else is already being raised (the
    one being raised then says which lights may be on, in ``lights_left_on`` and a note)."""
    if not getattr(lights, "is_open", True):
        return  # a vanished controller cannot be told; its watchdog darkens it
    in_flight = sys.exc_info()[1]
    try:
        lights.off()
    except LightError as exc:
        warning = left_on_warning(lights, exc)
        if raise_errors or in_flight is None:
            raise CaptureError(f"capture finished but {warning}") from exc
        if getattr(in_flight, "lights_left_on", None) is None:   # not said already
            in_flight.lights_left_on = warning
            in_flight.add_note(f"also, {warning}")
        return
    if getattr(in_flight, "lights_left_on", None) is not None:
        in_flight.add_note("the lights were switched off after all")
        in_flight.lights_left_on = None
