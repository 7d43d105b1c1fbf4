"""Reprocess many sessions on a Dask distributed cluster, with photometric stereo in pixel tiles.

>>> outcomes = run_batch(roots, scheduler="tcp://host:8786")     # an existing cluster
>>> outcomes = run_batch(roots, jobs=4)                          # a LocalCluster of 4 workers
>>> print(summary_table(outcomes))

Each session is a chain of tasks: a *head* task runs decode and calibrate and plans the normals
stage (:func:`pipeline.photometric.tiles.plan_normals`: scratch stack, shared shape fitted once);
one task per pixel tile solves its rows from the memory-mapped stack; a *tail* task assembles
the tiles into ``normals/``, records the stage, and runs integrate and report. Every file is
written by the task that computed it, atomically, so a worker killed mid-task leaves no partial
output and Dask's rerun of the task writes the same bytes once. The tail is safe to run again
after a worker died in it: it finds the normals it recorded (or, their scratch gone, solves the
session whole) and goes on. Workers must see the session folders at the same paths as the
client (a shared file system).

The client holds every session's lock for the whole batch (:mod:`pipeline.core.lock`); its tasks
act under it (:func:`pipeline.core.lock.act_under` with the lock's token), so a task still running
after its client died writes nothing to the session's manifest.

Dask is an optional dependency (``psrig[cluster]``): it is imported only inside these functions.
"""

import contextlib
import logging
import signal
import threading
import time
import uuid
import warnings
from pathlib import Path

from .core.errors import InputError, PsrigError, StageError
from .core.lock import act_under
from .photometric import WHOLE_IMAGE, assemble_normals, normals_summary, plan_normals, run_tile
from .core.progress import progress
from .runner import SessionOutcome, check_stage_range, lock_sessions, run_stage, wanted_options
from .core.session import STAGES, Session
from .core.stage import Outcome

__all__ = ["run_batch", "open_client", "summary_table", "TILE_PIXELS", "CONNECT_TIMEOUT"]

#: Default pixels per tile: about 100 MB of float64 observations at 50 lights.
TILE_PIXELS = 1 << 18
#: How long to try reaching a scheduler given by address.
CONNECT_TIMEOUT = "10s"


@contextlib.contextmanager
def open_client(scheduler=None, jobs=2):
    """A dask.distributed Client: to ``scheduler`` (address), or to a new LocalCluster.

    The LocalCluster (``scheduler`` None or ``"local"``) has ``jobs`` single-threaded worker
    processes and no dashboard; it is shut down on exit.
    """
    try:
        from distributed import Client, LocalCluster
    except ImportError:
        raise InputError("--scheduler needs Dask: pip install 'psrig[cluster]' "
                         "(dask[distributed])") from None
    if scheduler and scheduler != "local":
        try:
            client = Client(scheduler, timeout=CONNECT_TIMEOUT)
        except (OSError, TimeoutError) as exc:
            raise InputError(f"--scheduler {scheduler}: cannot reach the Dask scheduler ({exc})") from None
        with client:
            yield client
        return
    with _workers_ignore_ctrl_c(), warnings.catch_warnings():
        # the scheduler's HTTP server takes another port when 8787 is taken (another user's
        # cluster on this machine) and says so: nothing for psrig's user to do
        warnings.filterwarnings("ignore", message=r"Port \d+ is already in use")
        # its workers' own logs are silenced: psrig reports every task's failure itself, and a
        # batch stopped by Ctrl-C made each worker log its lost scheduler with a traceback
        cluster = LocalCluster(n_workers=max(1, jobs), threads_per_worker=1, processes=True,
                               dashboard_address=None, silence_logs=logging.CRITICAL)
    with cluster, Client(cluster) as client:
        yield client


@contextlib.contextmanager
def _workers_ignore_ctrl_c():
    """Start worker processes ignoring SIGINT (an ignored signal stays ignored in a child, and
    Python then installs no handler of its own): a Ctrl-C reaches the terminal's whole process
    group, and each Dask worker printed its traceback; the client alone stops the batch."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def _stage_names(stop):
    return STAGES[:STAGES.index(stop or STAGES[-1]) + 1]


def _session_head(root, token, options, forced, stop, tile_pixels):
    """Task: stages up to normals, under the client's lock ``token``; returns (SessionOutcome,
    TilePlan or None).

    With no plan (normals up to date, or not asked for) the session is finished here.
    """
    outcome = SessionOutcome(root)
    try:
        act_under(root, token)
        session = Session.open(root, writer="run")
        for name in _stage_names(stop):
            if name != "normals":
                outcome.stages.append(run_stage(session, name, options, name in forced, 1))
                continue
            start = time.perf_counter()
            try:
                wanted = wanted_options(name, session.stage(name), options.get(name, {}))
                plan = plan_normals(session, wanted, force=name in forced,
                                    tile_pixels=tile_pixels)
            except PsrigError as exc:
                raise StageError(f"stage normals: {exc}") from None
            if plan == WHOLE_IMAGE:   # not to be tiled: the serial stage, in this task
                outcome.stages.append(run_stage(session, name, options, True, 1))
            elif plan is not None:
                return outcome, plan
            else:
                outcome.stages.append(Outcome(name, False, session.stage(name), seconds=time.perf_counter() - start))
    except PsrigError as exc:
        outcome.error = str(exc)
    return outcome, None


def _session_tail(outcome, plan, token, options, forced, stop, tiles):
    """Task (after every tile of ``plan``): assemble normals, then the stages after it.

    Run again after a worker died in it, it finds the normals it recorded, or solves them whole
    when an earlier attempt had already removed the tiles' scratch.
    """
    del tiles  # only a dependency: the tile files are found from the plan
    try:
        act_under(plan.root, token)
        try:
            assembled = assemble_normals(plan)
        except PsrigError as exc:
            raise StageError(f"stage normals: {exc}") from None
        session = Session.open(plan.root, writer="run")
        if assembled == WHOLE_IMAGE:  # only a whole solve can make these normals
            run_stage(session, "normals", options, True, 1)
        record = session.stage("normals")   # the line and warnings the serial executor gives
        outcome.stages.append(Outcome("normals", True, record, normals_summary(record),
                                      [str(w) for w in record.get("warnings") or []], time.time() - plan.run.started))
        names = _stage_names(stop)
        for name in names[names.index("normals") + 1:]:
            outcome.stages.append(run_stage(session, name, options, name in forced, 1))
    except PsrigError as exc:
        outcome.error = str(exc)
    return outcome


def run_batch(roots, *, scheduler=None, jobs=2, options=None, force=False, start=None, stop=None,
              echo=None, tile_pixels=TILE_PIXELS, tile_hook=None, show_progress=True, wait=False):
    """Run every stage that is not up to date on each session, on a Dask cluster.

    Parameters
    ----------
    roots : list of path
        Session folders (seen by the workers at the same paths).
    scheduler : str, optional
        Address of a running Dask scheduler; None or "local": a LocalCluster of ``jobs`` workers.
    options, force, start, stop
        As :func:`pipeline.runner.run_session`.
    echo : callable, optional
        Called with one line per stage of each finished session ("ROOT: normals: ran in 3.2 s").
    tile_pixels : int
        Object pixels per photometric-stereo tile (rounded to whole solver chunks).
    tile_hook : callable, optional
        ``hook(plan, tile)`` run in the worker after a tile is solved, before it is written.
    show_progress : bool
        A bar of finished sessions and tiles over their total (the total grows as sessions are
        planned).
    wait : bool
        Wait for other commands writing a session instead of failing it.

    Returns
    -------
    list of SessionOutcome
        In the order of ``roots``; a failing session does not stop the others.
    """
    check_stage_range(start, stop)
    roots = [str(Path(r)) for r in roots]
    options = options or {}
    forced = set(STAGES if force else STAGES[STAGES.index(start):] if start else ())
    with lock_sessions(roots, "run", wait=wait, echo=echo) as sessions, open_client(scheduler, jobs) as client, \
            progress(total=len(roots), desc="sessions+tiles", unit="task", disable=not show_progress) as bar:
        outcomes = _drive(client, sessions, options, forced, stop, tile_pixels, tile_hook, bar, echo)
    return [outcomes[root] for root in roots]


class _Outcomes(dict):
    """{root: SessionOutcome}; echoes a session's stage lines when it is stored (finished)."""

    def __init__(self, echo):
        super().__init__()
        self.echo = echo

    def __setitem__(self, root, outcome):
        outcome.root = root
        super().__setitem__(root, outcome)
        for stage in outcome.stages if self.echo else ():
            self.echo(f"{root}: {stage.describe()}")


def _drive(client, sessions, options, forced, stop, tile_pixels, tile_hook, bar, echo):
    """Submit heads of the locked ``sessions`` ({root: Session or SessionOutcome with the
    error}); on each finished head submit its tiles and tail; collect outcomes."""
    from distributed import as_completed

    batch = uuid.uuid4().hex[:8]
    kinds, partial, outcomes = {}, {}, _Outcomes(echo)
    tokens = {root: s.lock.token for root, s in sessions.items() if isinstance(s, Session)}
    for root, failed in sessions.items():
        if root not in tokens:
            outcomes[root] = failed
            bar.update(1)

    def submit(kind, root, func, *args):
        future = client.submit(func, *args, pure=False, key=f"psrig-{kind}-{batch}-{len(kinds)}")
        kinds[future.key] = (kind, root)
        return future

    # workers may run in another folder: they get absolute paths, the user's spelling is kept
    pending = as_completed([submit("head", root, _session_head, str(Path(root).absolute()), tokens[root],
                                   options, forced, stop, tile_pixels) for root in tokens])
    for future in pending:
        kind, root = kinds[future.key]
        if future.status != "finished":
            if kind != "tile":  # a failed tile fails its tail, which reports it
                outcome = partial.get(root) or SessionOutcome(root)
                outcome.error = _task_error(root, kind, future.exception())
                outcomes[root] = outcome
                bar.update(1)
            continue
        if kind == "tile":
            bar.update(1)
            continue
        outcome, plan = future.result() if kind == "head" else (future.result(), None)
        if plan is None:
            outcomes[root] = outcome
            bar.update(1)
            continue
        partial[root] = outcome
        tiles = [submit("tile", root, run_tile, plan, tile, tile_hook) for tile in plan.tiles]
        bar.total += len(tiles)
        bar.refresh()
        pending.update(tiles)
        pending.add(submit("tail", root, _session_tail, outcome, plan, tokens[root], options, forced, stop,
                           tiles))
    return outcomes


def _task_error(root, kind, exc):
    """One line for a task that raised (a PsrigError from a tile) or was lost (KilledWorker)."""
    if isinstance(exc, PsrigError):
        return f"stage normals: {exc}"
    return f"{root}: {kind} task failed: {type(exc).__name__}: {exc}"


def summary_table(outcomes):
    """A plain-text table: per session, the stages that ran, total seconds, and the error."""
    rows = [("session", "stages run", "time", "error")]
    for outcome in outcomes:
        ran = ", ".join(s.name for s in outcome.stages if s.ran) or "-"
        seconds = sum(s.seconds for s in outcome.stages)
        rows.append((outcome.root, ran, f"{seconds:.1f} s", outcome.error or "-"))
    widths = [max(len(row[i]) for row in rows) for i in range(3)]
    return "\n".join("  ".join(cell.ljust(w) for cell, w in zip(row[:3], widths)) + "  " + row[3]
                     for row in rows)
