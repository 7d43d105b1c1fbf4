"""One sphere calibration for many object sessions: ``psrig calibrate SESSION --from CAL``.

The lights of another session (its ``calibration/lights.yaml``, from its own calibrate stage or
imported) become this session's, for its object frames in light order. The source's path and
the sha256 of its lights.yaml are the stage's parameters, so a recalibrated source makes the
next ``psrig run`` redo this stage and everything after it. Near-light positions are kept only
when both sessions' frames have the same size: they are in the source's pixels.
"""

import time
from pathlib import Path

from pipeline.decode import frame_size
from pipeline.core.errors import InputError, PsrigError, StageError
from pipeline.core.lightsio import LightSet, read_lights_yaml, write_lights_yaml, write_lp
from pipeline.core.paths import LIGHTS, LIGHTS_LP
from pipeline.core.session import Session, file_sha256

__all__ = ["reuse_calibration"]


#: how many sessions a chain of --from may pass through before psrig stops following it
CHAIN_LIMIT = 64


def _source(session, path):
    """(Session, lights.yaml path) of the session to take the lights from."""
    try:
        other = Session.open(path)
    except PsrigError as exc:
        raise InputError(f"--from {path}: {exc}") from None
    _check_chain(session, other, path)
    lights = other.path(LIGHTS)
    if not lights.is_file():
        raise InputError(f"--from {path}: it has no {LIGHTS}; calibrate it first (psrig run {path} --to calibrate)")
    record = other.stage("calibrate")
    if record is not None and record.get("status", "ok") != "ok":
        raise InputError(f"--from {path}: its calibrate stage ended {record.get('status')!r}")
    return other, lights


def _check_chain(session, other, path):
    """Refuse a source that is this session, or takes its lights (through other sessions'
    --from) from this session: such a calibration would never be up to date."""
    if other.real_root == session.real_root:
        raise InputError(f"--from {path}: that is this session; give another, calibrated session")
    seen, current = {other.real_root}, other
    for _ in range(CHAIN_LIMIT):
        upstream = ((current.stage("calibrate") or {}).get("params") or {}).get("from_session")
        if not upstream:
            return
        try:
            current = Session.open(upstream)
        except PsrigError:
            return  # a vanished upstream is the source's own business, not a loop
        if current.real_root == session.real_root:
            raise InputError(f"--from {path}: takes its lights from this session (psrig calibrate ... --from "
                             f"{session.root}); calibrate one of the two from its sphere frames")
        if current.real_root in seen:
            return  # a loop among other sessions: theirs to mend, and it never reaches this one
        seen.add(current.real_root)
    raise InputError(f"--from {path}: its lights come through more than {CHAIN_LIMIT} sessions' --from")


def _frame_size(session):
    """(height, width) of a session's first frame as decoded, or None when it has none."""
    frames = session.frames()
    return frame_size(session.path(frames[0]["file"])) if frames else None


def reuse_calibration(session, source, *, force=False, echo=print):
    """Write ``source``'s lights as ``session``'s (see the module docstring).

    Parameters
    ----------
    session : pipeline.core.session.Session
    source : path
        The calibrated session.
    force : bool
    echo : callable

    Returns
    -------
    LightSet or None (up to date)
    """
    other, lights_path = _source(session, source)
    params = {"from_session": str(Path(source).expanduser().absolute()),
              "from_session_sha256": file_sha256(lights_path)}
    if not force and session.stage_is_current("calibrate", params, {}):
        echo(f"{session.root}: calibrate is up to date (lights from {source})")
        return None
    start = time.perf_counter()
    lights = read_lights_yaml(lights_path)
    objects = sorted(session.stage_frames("object"), key=lambda f: f["light"])
    if not objects:
        raise StageError(f"{session.root}: no object frames to give the lights of {source} to")
    if len(lights) != len(objects) or objects[-1]["light"] != len(lights) - 1:
        raise InputError(f"--from {source}: {len(lights)} lights for {len(objects)} object frames "
                         f"(lights 0 .. {objects[-1]['light']}); the sessions must be shot under the same lights")
    positions, note = lights.positions, ""
    if positions is not None and _frame_size(session) != _frame_size(other):
        positions, note = None, "; near-light positions dropped (the frames differ in size from the source's)"
    reused = LightSet(lights.directions, lights.intensities, positions=positions, flags=dict(lights.flags),
                      source=f"calibration of session {other.root} (lights.yaml sha256 "
                             f"{params['from_session_sha256'][:12]}): {lights.source}{note}",
                      extra=dict(lights.extra))
    write_lights_yaml(session.path(LIGHTS), reused)
    write_lp(session.path(LIGHTS_LP), [f.get("source", Path(f["file"]).name) for f in objects], reused.directions)
    session.record_stage("calibrate", params, {}, [LIGHTS, LIGHTS_LP], seconds=time.perf_counter() - start,
                         flagged=reused.flags, light_model=reused.extra.get("light_model", "directional"),
                         source_session=str(other.root))
    echo(f"{session.root}: lights from {other.root} ({len(reused)} lights{note})")
    return reused
