"""The demo: capture on the simulated rig, process every stage, evaluate, report.

The simulated rig (``sim`` in rigs.yaml) drives the real light-controller and PTP camera code
against simulated devices, so the demo exercises the whole chain a lab session goes through:
capture (object, chrome-sphere and dark frames as DNG), decode, calibrate from the sphere frames,
normals, integrate, report; then it scores the result against the scene's ground truth.
"""

import inspect
import shutil
import time
from pathlib import Path

import yaml

from .core.errors import SessionError, StageError
from .evaluate import evaluate_session
from .report import INDEX
from .runner import run_session
from .core.yamlio import load_yaml

__all__ = ["run_demo", "prepare_folder", "DEMO_MARK"]

#: Manifest key (under ``rig``) that marks a session made by the demo.
DEMO_MARK = "demo"


def prepare_folder(folder, force=False):
    """Make ``folder`` ready for a demo session: absent or empty; an old demo session is
    removed only with ``force``. Anything else is refused, so no user data is ever deleted."""
    folder = Path(folder)
    if not folder.exists() or (folder.is_dir() and not any(folder.iterdir())):
        return folder
    manifest = folder / "session.yaml"
    if not manifest.is_file():
        raise SessionError(f"{folder}: exists, is not empty and is not a session; choose an "
                           "empty or new folder for the demo")
    try:
        data = load_yaml(manifest.read_text(encoding="utf-8")) or {}
    except yaml.YAMLError:
        data = {}
    if not (isinstance(data, dict) and isinstance(data.get("rig"), dict)
            and data["rig"].get(DEMO_MARK)):
        raise SessionError(f"{manifest}: a session that the demo did not make; refusing to touch it")
    if not force:
        raise SessionError(f"{folder}: already holds a demo session; use --force to replace it "
                           "(or `psrig run` to reprocess it)")
    from .core.session import Session

    with Session.open(folder, writer="demo"):  # not under a command still writing it
        shutil.rmtree(folder)
    return folder


def _capture(folder, echo):
    """Capture a session on the simulated rig; returns the opened Session."""
    try:
        from rig.capture import capture_session
    except ModuleNotFoundError as exc:
        if exc.name != "rig.capture":
            raise
        raise StageError("capture: module rig.capture is missing from this installation") from None
    from rig.config import get_rig

    from .core.session import Session

    start = time.perf_counter()
    rig = get_rig("sim")
    # rig.capture was not written yet when this was: accept a folder or a Session first argument
    first = next(iter(inspect.signature(capture_session).parameters), "")
    if first == "session":
        capture_session(Session.create(folder, rig={"name": "sim"}), rig)
    else:
        capture_session(folder, rig)
    session = Session.open(folder, writer="demo")  # held until the demo is done
    session.manifest["rig"][DEMO_MARK] = True
    session.save()
    echo(f"capture: {len(session.frames())} frames in {time.perf_counter() - start:.1f} s")
    return session


def run_demo(folder, *, force=False, echo=print):
    """Capture on the simulated rig into ``folder`` and process it completely.

    Parameters
    ----------
    folder : path
        Session folder to create (absent or empty; an old demo session needs ``force``).
    force : bool
        Replace a previous demo session in ``folder``.
    echo : callable
        Receives one line per step.

    Returns
    -------
    dict
        ``session`` (path), ``report`` (path of index.html), ``scores`` (evaluate_session) and
        ``seconds`` (wall time of the whole demo).
    """
    start = time.perf_counter()
    folder = prepare_folder(folder, force)
    session = _capture(folder, echo)
    run_session(session.root, echo=echo)
    from .core.session import Session

    scores = evaluate_session(Session.open(folder))
    return {"session": str(folder), "report": str(Path(folder) / INDEX), "scores": scores,
            "seconds": time.perf_counter() - start}
