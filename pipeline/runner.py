"""The stage runner: decode, calibrate, normals, integrate and report, each only when needed.

Every stage function checks its own record (``session.stage_is_current``) and returns early
when its parameters and input hashes still match, so the runner simply calls them in order and
tells "up to date" from "ran" by whether the stage record changed. A changed parameter reruns
that stage; its new outputs change the input hashes of the stages after it, which rerun in turn;
the stages before it are untouched. A stage records itself only after all its outputs are
written (atomically), so interrupting a run leaves every finished stage valid.

Stage adapters live in :data:`RUNNERS` ({name: callable(session, options, force, jobs)}), which
tests may replace with stubs.
"""

import concurrent.futures
import contextlib
import os
import signal
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import PsrigError, SessionError, StageError, describe_os_error
from .lock import act_under, lifeline, watch_lifeline, worker_context
from .paths import LIGHTS
from .session import STAGES, Session

__all__ = ["run_session", "run_sessions", "lock_sessions", "run_stage", "check_stage_range", "RUNNERS", "StageOutcome",
           "SessionOutcome", "stage_options", "recorded_options"]


@dataclass
class StageOutcome:
    """What one stage did: ``ran`` (bool), ``seconds`` wall time, ``note`` (why it was skipped,
    or what a user should know of a run) and the ``warnings`` its record holds (when it ran)."""

    name: str
    ran: bool
    seconds: float
    note: str = ""
    warnings: list = field(default_factory=list)

    def describe(self):
        """The stage's one line: what it did, its note and its warnings."""
        if self.ran:
            line = f"{self.name}: ran in {self.seconds:.1f} s" + (f"; {self.note}" if self.note else "")
        else:
            line = f"{self.name}: up to date" + (f" ({self.note})" if self.note else "")
        return line + "".join(f"; warning: {w}" for w in self.warnings)


@dataclass
class SessionOutcome:
    """Result of one session: stage outcomes, and ``error`` (message) if a stage failed."""

    root: str
    stages: list = field(default_factory=list)
    error: str = ""


def _decode(session, options, force, jobs):
    from .decode import decode_session, describe_record

    before = session.stage("decode")
    record = decode_session(session, force=force, jobs=jobs, **options)
    return "; ".join(describe_record(record)) if record is not before else ""


def _calibrate(session, options, force, jobs):
    if options.get("from_session"):   # one sphere session's calibration for this one
        from calibration import calibrate_session

        calibrate_session(session, force=force, echo=lambda line: None, **options)
        return f"lights from {options['from_session']}"
    if not session.frames("sphere"):
        from calibration import lights_without_spheres

        return lights_without_spheres(session)
    from calibration import calibrate_session

    # what the calibration says (flagged lights) becomes the stage's note; its own "is up to
    # date" line would repeat the runner's
    said = []
    ran = calibrate_session(session, force=force, echo=said.append, **options)
    return "; ".join(said) if ran is not None else ""


def _normals(session, options, force, jobs):
    if not session.path(LIGHTS).is_file():
        raise StageError(f"{session.path(LIGHTS)}: missing; the calibrate stage makes it")
    from .photometric import normals_session, normals_summary

    record = normals_session(session, force=force, **options)   # its warnings are in its record
    return normals_summary(record) if record is not None else None


def _integrate(session, options, force, jobs):
    from .integrate import integrate_session

    integrate_session(session, force=force, **options)  # its warnings are in its record


def _report(session, options, force, jobs):
    from .report import report_session

    report_session(session, force=force, **options)


#: Stage adapters in running order; each returns an optional note or None.
RUNNERS = {"decode": _decode, "calibrate": _calibrate, "normals": _normals,
           "integrate": _integrate, "report": _report}


def stage_options(*, method=None, t_low=None, integrate_method=None, binning=None, circle=None, gamma=None,
                  sphere_mask=None, outline=None, from_session=None):
    """Per-stage keyword options from run-level settings (None = the stage's default)."""
    chosen = {"decode": {"binning": binning, "gamma": gamma},
              "calibrate": {"circle": circle, "sphere_mask": sphere_mask, "outline": outline,
                            "from_session": from_session},
              "normals": {"method": method, "t_low": t_low},
              "integrate": {"method": integrate_method}, "report": {}}
    return {stage: {k: v for k, v in opts.items() if v is not None} for stage, opts in chosen.items()}


def recorded_options(name, record):
    """Keyword options that reproduce a stage's recorded parameters ({} when none are recorded).

    ``psrig run`` starts from these, so a stage that was run by hand with its own settings (say
    ``psrig calibrate --outline F`` or ``psrig normals --t-low 0.3``) is neither redone nor
    overwritten with the defaults; options given to the run replace the recorded ones key by key.
    """
    params = dict((record or {}).get("params") or {})
    if not params or name not in _RECORDED:
        return {}
    return _RECORDED[name](params)


def _calibrate_kwargs(params):
    # hashes are recorded beside the files they check; the stage recomputes them
    # (and outline_frames names the session's outline frames, which the stage finds itself)
    kwargs = {k: v for k, v in params.items()
              if not k.endswith("_sha256") and k != "outline_frames" and v is not None}
    if "K" in kwargs:
        kwargs["K"] = np.asarray(kwargs["K"], float)
    return kwargs


def _decode_kwargs(params):
    from .decode import recorded_kwargs

    return recorded_kwargs(params)


def _integrate_kwargs(params):
    kwargs = {"method": params.get("method", "smooth"), **(params.get("options") or {})}
    if params.get("K") is not None:
        kwargs["K"] = np.asarray(params["K"], float)
    return kwargs


#: stage -> recorded params to keyword options (the report has nothing a user sets)
_RECORDED = {"decode": _decode_kwargs, "calibrate": _calibrate_kwargs, "normals": dict, "integrate": _integrate_kwargs}


def run_stage(session, name, options, force, jobs):
    """Run one stage (a name of :data:`RUNNERS`) with the options recorded for it, replaced key by
    key by ``options[name]``; returns a :class:`StageOutcome`. StageError names the stage."""
    # record_stage stores a new dict; a skipped stage leaves the old one in place (timestamps
    # have one-second resolution, too coarse to tell a fast rerun)
    before = session.stage(name)
    start = time.perf_counter()
    try:
        note = RUNNERS[name](session, {**recorded_options(name, before), **options.get(name, {})}, force, jobs)
    except PsrigError as exc:
        raise StageError(f"stage {name}: {exc}") from None
    except ModuleNotFoundError as exc:
        if not (exc.name or "").startswith(("pipeline.", "calibration.")):
            raise
        raise StageError(f"stage {name}: module {exc.name} is missing from this installation") from None
    except OSError as exc:   # a full disk, a read-only folder: the stage records nothing
        raise StageError(f"stage {name}: {describe_os_error(exc)}") from None
    seconds = time.perf_counter() - start
    record = session.stage(name)
    if record is not None and record.get("status", "ok") != "ok":
        from .decode import describe_failures   # only decode fails frame by frame
        failed = "; ".join(describe_failures(record.get("failed")))
        raise StageError(f"stage {name}: {session.root}: status {record['status']}"
                         + (f" ({failed})" if failed else ""))
    ran = record is not None and record is not before
    warnings = [str(w) for w in (record or {}).get("warnings") or []] if ran else []
    return StageOutcome(name, ran, seconds, note or "", warnings)


def check_stage_range(start, stop):
    """StageError unless ``start`` (--from) and ``stop`` (--to) are None or stage names."""
    for flag, value in (("--from", start), ("--to", stop)):
        if value is not None and value not in STAGES:
            raise StageError(f"{flag} {value!r}: not a stage; stages are {', '.join(STAGES)}")


def run_session(root, *, options=None, force=False, start=None, stop=None, jobs=None, echo=None, wait=False):
    """Run every stage of one session that is not up to date.

    Parameters
    ----------
    root : path
        Session folder.
    options : dict, optional
        {stage: {keyword: value}} passed to the stage functions (see :func:`stage_options`).
    force : bool
        Rerun every stage.
    start : str, optional
        Rerun this stage and every stage after it (earlier ones run only if not current).
    stop : str, optional
        Last stage to run (default: report).
    jobs : int, optional
        Worker processes inside a stage (decode).
    echo : callable, optional
        Called with one line per stage ("decode: up to date", "normals: ran in 3.2 s").
    wait : bool
        Wait for another command writing the session (its lock) instead of failing.

    Returns
    -------
    list of StageOutcome
        Raises StageError naming the stage (and the file) when one cannot run, SessionLocked
        when another command writes the session.
    """
    check_stage_range(start, stop)
    forced = set(STAGES if force else STAGES[STAGES.index(start):] if start else ())
    outcomes = []
    with Session.open(root, writer="run", wait=wait, on_wait=echo) as session:
        if session.swept and echo:
            echo(session.describe_swept(named=False))   # echo's lines name the session
        for name in STAGES[:STAGES.index(stop or STAGES[-1]) + 1]:
            outcome = run_stage(session, name, options or {}, name in forced, jobs)
            outcomes.append(outcome)
            if echo:
                echo(outcome.describe())
    return outcomes


def _run_one(root, options, force, start, stop, jobs, token):
    """Process-pool worker: one session, under the parent's lock (``token``); errors returned as
    text (they cross processes)."""
    outcome = SessionOutcome(str(root))
    # a Ctrl-C reaches every process of the terminal's group: a worker working on a session
    # stops it (its stages record what they finished); an idle one ignores it (_init_worker)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        act_under(root, token)
        outcome.stages = run_session(root, options=options, force=force, start=start, stop=stop,
                                     jobs=jobs)
    except PsrigError as exc:
        outcome.error = str(exc)
    except OSError as exc:
        outcome.error = f"{root}: {describe_os_error(exc)}"
    finally:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    return outcome


def _deferred_interrupt():
    from .decode.pool import _deferred_interrupt as deferred

    return deferred()


def _init_worker(reader):
    """Initializer of a ``run --jobs`` worker: it dies with its parent (:func:`watch_lifeline`),
    and a Ctrl-C finding it idle is the parent's to handle (no traceback from the worker)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    watch_lifeline(reader)


def _interrupt(processes):
    """Pass a Ctrl-C the parent got on to its workers (it may have been sent to it alone)."""
    for process in processes:
        with contextlib.suppress(OSError, AttributeError):
            os.kill(process.pid, signal.SIGINT)


def _isolated_worker(conn, reader, root, work, token):
    """Process of :func:`_run_isolated`: one session, its outcome sent on ``conn``."""
    watch_lifeline(reader)
    try:
        conn.send(_run_one(root, *work, token))
    except KeyboardInterrupt:
        sys.exit(130)   # the parent says "interrupted"; no traceback from here
    conn.close()


def _run_isolated(context, tokens, work, jobs):
    """Run each session of ``tokens`` ({root: lock token}) in a process of its own, ``jobs`` at
    a time; {root: SessionOutcome}, a session whose process died named as failed with how it
    died ("worker died: killed by signal 9 (SIGKILL)")."""
    import multiprocessing.connection

    reader = lifeline(context)
    waiting, running, outcomes = list(tokens), {}, {}
    try:
        while waiting or running:
            while waiting and len(running) < jobs:
                root = waiting.pop(0)
                receive, send = context.Pipe(duplex=False)
                process = context.Process(target=_isolated_worker, args=(send, reader, root, work, tokens[root]),
                                          name=f"psrig-run-{Path(root).name}", daemon=True)
                process.start()
                send.close()
                running[process.sentinel] = (root, process, receive)
            ready = multiprocessing.connection.wait(
                [conn for _, _, conn in running.values()] + list(running))
            for sentinel, (root, process, conn) in list(running.items()):
                if conn not in ready and sentinel not in ready:
                    continue
                try:
                    outcomes[root] = conn.recv()
                except (EOFError, OSError):
                    process.join()
                    outcomes[root] = SessionOutcome(root, error=f"{root}: {_death(process.exitcode)}; the stages "
                                                    "it finished are kept, run it again to go on")
                process.join()
                conn.close()
                del running[sentinel]
    finally:   # interrupted: the running sessions stop, recording what they finished
        _interrupt([process for _, process, _ in running.values()])
        for _, process, conn in running.values():
            process.join(timeout=30)
            if process.is_alive():
                process.kill()
                process.join()
            conn.close()
    return outcomes


def _death(exitcode):
    """How a worker process ended, from its exit code (negative: the signal that killed it)."""
    if exitcode is not None and exitcode < 0:
        try:
            name = f" ({signal.Signals(-exitcode).name})"
        except ValueError:
            name = ""
        return f"worker died: killed by signal {-exitcode}{name}"
    return f"worker died: exit status {exitcode}"


@contextlib.contextmanager
def lock_sessions(roots, command, *, wait=False, echo=None):
    """Context manager: {root: Session holding its lock, or a SessionOutcome with the error}
    for each root; every lock taken is released on leaving, however it is left."""
    sessions = {}
    try:
        yield _locked(roots, command, wait, echo, sessions)
    finally:
        for session in sessions.values():
            if isinstance(session, Session):
                session.release()


def _locked(roots, command, wait, echo, sessions):
    """Fill ``sessions`` as it goes (so that an interrupted wait still releases what it took)."""
    seen = {}
    for root in roots:
        say = (lambda line, root=root: echo(f"{root}: {line}")) if echo else None
        same = seen.setdefault(Path(root).resolve(), root)
        try:
            if same != root:
                raise SessionError(f"{root}: the same session as {same}, given twice")
            sessions[root] = Session.open(root, writer=command, wait=wait, on_wait=say)
        except PsrigError as exc:
            sessions[root] = SessionOutcome(root, error=str(exc))
            continue
        if sessions[root].swept and echo:
            echo(sessions[root].describe_swept())
    return sessions


def run_sessions(roots, *, options=None, force=False, start=None, stop=None, jobs=1, echo=None,
                 wait=False):
    """Run several sessions, ``jobs`` at a time in separate processes.

    Returns a list of SessionOutcome in the order of ``roots``; a failing session does not stop
    the others. With one job the sessions run in this process, one after the other. (A batch
    on Dask, with photometric stereo in pixel tiles, is :func:`pipeline.cluster.run_batch`.)
    With more, this process takes every session's lock (``wait``: waiting for other writers)
    and the worker processes act under it; they die with this process (:mod:`pipeline.lock`).
    """
    roots = [str(Path(r)) for r in roots]
    if jobs <= 1 or len(roots) == 1:
        outcomes = []
        for root in roots:
            say = (lambda line, root=root: echo(f"{root}: {line}")) if echo else None
            outcome = SessionOutcome(root)
            try:
                outcome.stages = run_session(root, options=options, force=force, start=start,
                                             stop=stop, jobs=None if len(roots) == 1 else 1,
                                             echo=say, wait=wait)
            except PsrigError as exc:
                outcome.error = str(exc)
            except OSError as exc:
                outcome.error = f"{root}: {describe_os_error(exc)}"
            outcomes.append(outcome)
        return outcomes
    outcomes = {}
    context = worker_context()
    with lock_sessions(roots, "run", wait=wait, echo=echo) as sessions:
        tokens = {root: session.lock.token for root, session in sessions.items()
                  if not isinstance(session, SessionOutcome)}
        outcomes.update({root: session for root, session in sessions.items() if isinstance(session, SessionOutcome)})
        # one decode worker per session: the sessions already share the cores
        work = (options, force, start, stop, 1)
        with concurrent.futures.ProcessPoolExecutor(jobs, mp_context=context, initializer=_init_worker,
                                                    initargs=(lifeline(context),)) as pool:
            with _deferred_interrupt():   # submitting starts workers (see decode.pool)
                futures = {root: pool.submit(_run_one, root, *work, token) for root, token in tokens.items()}
            try:
                for root, future in futures.items():
                    try:
                        outcomes[root] = future.result()
                    except concurrent.futures.process.BrokenProcessPool:
                        pass  # a worker died (OOM killer, kill -9): which session's, the pool cannot tell
            except KeyboardInterrupt:
                # start no other session; the running ones stop, recording what they finished
                pool.shutdown(wait=False, cancel_futures=True)
                _interrupt(list((getattr(pool, "_processes", None) or {}).values()))
                raise
        broken = [root for root in tokens if root not in outcomes]
        if broken:
            # each unfinished session again in a process of its own, so that a death is its own
            # (what its stages finished is recorded and is not redone)
            outcomes.update(_run_isolated(context, {root: tokens[root] for root in broken}, work, jobs))
    outcomes = [outcomes[root] for root in roots]
    if echo:
        for outcome in outcomes:
            for stage in outcome.stages:
                echo(f"{outcome.root}: {stage.describe()}")
    return outcomes
