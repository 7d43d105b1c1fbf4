"""The stage runner: decode, calibrate, normals, integrate and report, each only when needed.

Every stage (:class:`pipeline.core.stage.Stage`) checks its own record (``session.stage_is_current``)
and returns an :class:`pipeline.core.stage.Outcome` that says whether it ran, so the runner simply
runs them in order, each with its recorded options replaced by the ones given. A changed
parameter reruns that stage; its new outputs change the input hashes of the stages after it,
which rerun in turn; the stages before it are untouched. A stage records itself only after all
its outputs are written (atomically), so interrupting a run leaves every finished stage valid.

The stages are :data:`RUNNERS` ({name: Stage}), which tests may replace with stubs. This module
is the serial executor; :mod:`pipeline.cluster` runs the same stages on Dask.
"""

import concurrent.futures
import contextlib
import os
import signal
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from calibration.stage import CALIBRATE
from .decode.stage import DECODE
from .core.errors import PsrigError, SessionError, StageError, describe_os_error
from .integrate.stage import INTEGRATE
from .core.lock import act_under, lifeline, watch_lifeline, worker_context
from .photometric import NORMALS
from .report.stage import REPORT
from .core.session import STAGES, Session
from .core.stage import Outcome

__all__ = ["run_session", "run_sessions", "lock_sessions", "run_stage", "check_stage_range", "RUNNERS", "StageOutcome",
           "SessionOutcome", "stage_options", "recorded_options", "wanted_options", "STAGE_OBJECTS"]


#: What one stage did (:class:`pipeline.core.stage.Outcome`), by the name this module gave it first.
StageOutcome = Outcome


@dataclass
class SessionOutcome:
    """Result of one session: stage outcomes, and ``error`` (message) if a stage failed."""

    root: str
    stages: list = field(default_factory=list)
    error: str = ""


#: The stages (:class:`pipeline.core.stage.Stage`) in running order, by name. Tests may replace one
#: with a plain callable ``(session, options, force, jobs) -> note``: :func:`run_stage` then
#: tells "ran" from "current" by whether the stage's record changed.
STAGE_OBJECTS = {"decode": DECODE, "calibrate": CALIBRATE, "normals": NORMALS, "integrate": INTEGRATE,
                 "report": REPORT}
RUNNERS = dict(STAGE_OBJECTS)


def stage_options(*, method=None, t_low=None, integrate_method=None, binning=None, circle=None, gamma=None,
                  sphere_mask=None, outline=None, from_session=None):
    """Per-stage keyword options from a few run-level settings (None = the stage's default);
    ``psrig run`` itself builds them from every stage's declared options."""
    chosen = {"decode": {"binning": binning, "gamma": gamma},
              "calibrate": {"circle": circle, "sphere_mask": sphere_mask, "outline": outline,
                            "from_session": from_session},
              "normals": {"method": method, "t_low": t_low},
              "integrate": {"method": integrate_method}, "report": {}}
    return {stage: {k: v for k, v in opts.items() if v is not None} for stage, opts in chosen.items()}


def recorded_options(name, record):
    """Keyword options that reproduce a stage's recorded parameters ({} when none are recorded):
    the stage's `pipeline.core.stage.Stage.replay`.

    ``psrig run`` starts from these, so a stage that was run by hand with its own settings (say
    ``psrig calibrate --outline F`` or ``psrig normals --t-low 0.3``) is neither redone nor
    overwritten with the defaults; options given to the run replace the recorded ones key by key.
    """
    return STAGE_OBJECTS[name].replay(record) if name in STAGE_OBJECTS else {}


def wanted_options(name, record, given):
    """The options a stage runs with: its recorded ones replaced by ``given``
    (`pipeline.core.stage.Stage.merge`)."""
    return STAGE_OBJECTS[name].merge(recorded_options(name, record), given)


def run_stage(session, name, options, force, jobs):
    """Run one stage (a name of :data:`RUNNERS`) with the options recorded for it, replaced key by
    key by ``options[name]``; returns an :class:`pipeline.core.stage.Outcome`. StageError names the stage."""
    before = session.stage(name)
    start = time.perf_counter()
    try:
        done = RUNNERS[name](session, wanted_options(name, before, options.get(name, {})), force, jobs)
    except PsrigError as exc:
        raise StageError(f"stage {name}: {exc}") from None
    except ModuleNotFoundError as exc:
        if not (exc.name or "").startswith(("pipeline.", "calibration.")):
            raise
        raise StageError(f"stage {name}: module {exc.name} is missing from this installation") from None
    except OSError as exc:   # a full disk, a read-only folder: the stage records nothing
        raise StageError(f"stage {name}: {describe_os_error(exc)}") from None
    if not isinstance(done, Outcome):   # a plain callable: its note, and the record tells whether it ran
        record = session.stage(name)
        ran = record is not None and record is not before
        warnings = [str(w) for w in (record or {}).get("warnings") or []] if ran else []
        done = Outcome(name, ran, record, done or "", warnings)
    done.seconds = time.perf_counter() - start
    record = done.record
    if record is not None and record.get("status", "ok") != "ok":
        from .decode import describe_failures   # only decode fails frame by frame
        failed = "; ".join(describe_failures(record.get("failed")))
        raise StageError(f"stage {name}: {session.root}: status {record['status']}"
                         + (f" ({failed})" if failed else ""))
    return done


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
    from .decode.pool import deferred_interrupt as deferred

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
    and the worker processes act under it; they die with this process (:mod:`pipeline.core.lock`).
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
