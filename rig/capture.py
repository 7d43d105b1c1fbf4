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
import signal
import sys
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pipeline.errors import PsrigError, SessionError
from pipeline.progress import progress as progress_bar
from pipeline.session import FOLDERS, MANIFEST, Session, now_iso
from rig.camera import CameraError, format_exposure, make_camera
from rig.lights import LightError, make_light_controller

__all__ = ["capture_session", "plan_frames", "check_raw_file", "CaptureError", "CaptureInterrupted",
           "Shot", "PARTIAL", "SPHERE_PROMPT", "OUTLINE_PROMPT",
           "MANIFEST_INTERVAL"]

PARTIAL = "raw/.partial"
SPHERE_PROMPT = "Place the chrome sphere where the object was (object removed), then press Enter"
OUTLINE_PROMPT = ("Light the sphere(s) evenly with the room light (the rig's lights stay off; camera and "
                  "spheres unmoved) for the outline photo, then press Enter")
_TEMP_FILE = re.compile(r"^\..+\.tmp(\.[^.]*)?$")  # pipeline.atomic's temporary names
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
    return plan


# -- the entry point ------------------------------------------------------------------------------

def capture_session(target, rig_config, *, resume=False, sim=None, progress=True, sphere=None,
                    on_prompt=None, echo=print):
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

    Returns
    -------
    Session
    """
    start = time.perf_counter()
    sphere = bool(rig_config.frames.get("sphere", True) if sphere is None else sphere)
    session, root = _existing_session(target, rig_config, resume)
    with _open_devices(rig_config, sim) as devices, _sigterm_as_interrupt():
        devices.exposure = _set_exposure(rig_config, devices, echo)
        session = (session or Session.create(root)).acquire("capture")
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
def _open_devices(rig_config, sim):
    """Yield the opened lights and camera (of ``sim``, a new simulated rig, or the hardware)."""
    if sim is None and rig_config.is_simulated:
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
    if rig_config.camera.get("driver") == "sim":
        raise CaptureError(f"{rig_config.source}: rig '{rig_config.name}': camera.driver: a simulated "
                           "camera needs simulated lights too (lights.driver: sim)")
    try:
        lights, camera = make_light_controller(rig_config.lights), make_camera(dict(rig_config.camera))
    except (LightError, CameraError) as exc:
        raise CaptureError(f"{rig_config.source}: rig '{rig_config.name}': {exc}") from None
    with lights, camera:  # the lights' context switches them OFF on the way out
        yield _Devices(lights, camera)


@contextmanager
def _sigterm_as_interrupt():
    """Turn SIGTERM into :class:`CaptureInterrupted` (a KeyboardInterrupt) inside the block."""
    if threading.current_thread() is not threading.main_thread():
        yield  # only the main thread may install signal handlers
        return

    def interrupt(signum, frame):
        raise CaptureInterrupted("terminated (SIGTERM)")

    previous = signal.signal(signal.SIGTERM, interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous if previous is not None else signal.SIG_DFL)


# -- the manifest ---------------------------------------------------------------------------------

def _set_exposure(rig_config, devices, echo):
    """Set the rig's ``exposure:`` on the camera (before any frame); what it reported back."""
    if not rig_config.exposure:
        return {}
    try:
        report = devices.camera.set_exposure(dict(rig_config.exposure))
    except CameraError as exc:
        raise CaptureError(f"{rig_config.source}: rig '{rig_config.name}': {exc}; nothing was "
                           "captured") from exc
    echo("capture: exposure set on the camera: "
         + ", ".join(rec["display"] for rec in report.values()))
    return report


def _frame_exposure(rig_config, exposure):
    """A frame's ``exposure`` entry: the values the camera reported (the request where unset)."""
    out = dict(rig_config.exposure)
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
    _adopt_orphans(session, plan_frames(rig_config, sphere=True), echo)
    done = {f["id"] for f in session.frames()}
    todo = [shot for shot in plan if shot.frame_id not in done]
    if done:
        echo(f"capture: {session.root}: {len(plan) - len(todo)} of {len(plan)} frames present and "
             f"verified, {len(todo)} to capture")
    return todo


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
        if shot.light is None:
            devices.lights.off()
        else:
            devices.lights.on(shot.light)
        image = devices.camera.capture()
    except (LightError, CameraError) as exc:
        dark = ("the lights are switched off" if getattr(devices.lights, "is_open", True)
                else "the light controller is gone (its watchdog switches the lights off)")
        raise CaptureError(
            f"{session.root}: {what}: {exc}. Stopped: {dark}; the {len(session.frames())} frames "
            "captured so far are kept: run the capture again with --resume to complete the session",
            shot.frame_id, shot.light) from exc
    if image.size != len(image.data):
        raise CaptureError(f"{session.root}: {what}: the camera delivered {len(image.data)} of "
                           f"{image.size} bytes; not stored", shot.frame_id, shot.light)
    suffix = Path(image.filename).suffix.lower() or f".{rig_config.raw_format}"
    session.add_frame(shot.kind, image.data, light=shot.light, suffix=suffix, frame_id=shot.frame_id,
                      save=False, exposure=_frame_exposure(rig_config, devices.exposure),
                      captured_at=now_iso(),
                      camera_file=image.filename, **shot.extra)


def _lights_off(lights, raise_errors):
    """OFF, confirmed; a failure is raised only when nothing else is already being raised."""
    if not getattr(lights, "is_open", True):
        return  # a vanished controller cannot be told; its watchdog darkens it
    in_flight = sys.exc_info()[1]
    try:
        lights.off()
    except LightError as exc:
        if raise_errors or in_flight is None:
            raise CaptureError(f"capture finished but switching the lights off failed: {exc}") from exc
        in_flight.add_note(f"also, switching the lights off failed: {exc}")
