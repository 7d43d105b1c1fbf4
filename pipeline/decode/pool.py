"""Decoding many frames in a process pool: one task = one frame file -> EXR + saturation PNG.

Tasks are plain dicts so they cross process boundaries; a failing frame returns its reason
instead of raising, so the other frames are still decoded. A ``merge`` task (the exposures of
one bracket, decoded here or read back, -> their merged frame, :mod:`pipeline.decode.merge`)
is written the same way. Workers return paths and sha256, never arrays: the bytes are hashed
in memory as they are written, so nothing is read back.

A worker decodes straight into the bytes of the output EXR (uncompressed float32,
:class:`pipeline.decode.exr.ExrBuffer`), writes them to a temporary file on a second thread
while it hashes them, then encodes, writes and hashes the 1-bit mask. In a pool the worker
leaves the second half of each atomic write (fsync, rename, fsync of the folder) to threads of
the calling process and goes on with the next frame: a 12 MP frame is 144 MB, and waiting for
the disk would otherwise idle a core for about as long as decoding takes. The stage waits for
every commit before it returns, so nothing is recorded before it is on disk.
"""

import concurrent.futures as futures
import contextlib
import hashlib
import json
import os
import signal
import threading

import cv2
import numpy as np

from ..core.atomic import atomic_commit, atomic_write_begin, atomic_write_bytes, discard_temp
from .exr import ExrBuffer, encode_exr
from .formats import frame_format
from .frame import check_options, decode_frame
from .merge import merge_linear
from .raw import decode_raw
from ..core.errors import ImageFileError, PsrigError, describe_os_error
from ..core.imageio import read_image, read_mask
from ..core.lock import lifeline, watch_lifeline, worker_context
from ..core.progress import progress
from ..core.yamlio import plain

__all__ = ["run_tasks", "decode_task", "write_saturation", "encode_saturation", "start_pool",
           "prepare_pool", "release_workspace", "deferred_interrupt"]

_RGB = ("R", "G", "B")
_io = None
# Buffers reused from one frame to the next in this process (output file bytes, decoder work
# arrays): about 240 MB for 12 MP frames, allocated once instead of page-faulted per frame.
_workspace = {}


def encode_saturation(saturated):
    """PNG bytes of a bool (H, W) mask: 1-bit greyscale, read back as 0 / 255 (255 = saturated).

    1 bit per pixel gives zlib an eighth of the bytes of an 8-bit mask: a 12 MP mask encodes
    in 0.017 s instead of 0.07 s (8-bit, zlib level 1), and readers expand it to 0 / 255.
    """
    ok, data = cv2.imencode(".png", saturated.view(np.uint8) * np.uint8(255),
                            [cv2.IMWRITE_PNG_BILEVEL, 1, cv2.IMWRITE_PNG_COMPRESSION, 1])
    if not ok:
        raise ImageFileError("cannot encode the saturation mask")
    return data


def write_saturation(path, saturated):
    """Write a bool (H, W) mask as a PNG (255 = saturated), atomically; returns its sha256."""
    data = encode_saturation(np.ascontiguousarray(saturated, dtype=bool))
    _write(path, data)
    return hashlib.sha256(data).hexdigest()


def _commit(temps, receipt=None):
    """Finish the atomic writes {final path: temporary file}; None or the error message.
    Every temporary file is committed or removed. Then, when all are in place, write
    ``receipt`` (:func:`write_receipt`)."""
    error = None
    for path, tmp in temps.items():
        if error is not None:
            discard_temp(tmp)
            continue
        try:
            atomic_commit(tmp, path)
        except OSError as exc:
            error = f"cannot write {describe_os_error(exc)}"
    if error is None and receipt is not None and temps:
        write_receipt(receipt)
    return error


def write_receipt(receipt):
    """Write a frame's receipt (a dict with ``path``, JSON) beside its outputs, once they are in
    place: what it was decoded from and with, and its outputs' hashes, so that a run killed
    before recording the frame adopts it instead of decoding it again (:mod:`.stage`).

    Renamed into place but not fsynced: a receipt lost to a power cut costs a decode, never a
    wrong frame (the outputs' hashes are checked before one is adopted). A receipt that cannot
    be written is no error (the frame is recorded as usual)."""
    try:
        tmp = atomic_write_begin(receipt["path"], json.dumps(plain(receipt)).encode())
        os.replace(tmp, receipt["path"])
    except (OSError, PsrigError):
        pass


def _write(path, data, commit=True):
    """Atomic write of ``data``; with ``commit`` False only the first half (temporary file,
    returned; finish with :func:`pipeline.core.atomic.atomic_commit`). Disk errors become
    ImageFileError naming the file."""
    try:
        if commit:
            atomic_write_bytes(path, data)
            return None
        return atomic_write_begin(path, data)
    except OSError as exc:
        raise ImageFileError(f"cannot write {describe_os_error(exc)}") from None


def _init_worker(lifeline):
    # Each worker is one of ``jobs`` processes: OpenCV threads on top would oversubscribe.
    cv2.setNumThreads(1)
    # It works under its parent's session lock: it must not outlive the parent (a SIGKILLed
    # parent would otherwise leave it, the fork server and the resource tracker running).
    watch_lifeline(lifeline)
    # A Ctrl-C reaches the terminal's whole process group: the parent stops the decode (it
    # starts no further frame and records those done); a worker, idle or not, prints nothing.
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _io_thread():
    """One writer thread per process (created on first use, reused by every task)."""
    global _io
    if _io is None:
        _io = futures.ThreadPoolExecutor(max_workers=1, thread_name_prefix="psrig-decode-io")
    return _io


def _subtract(frame_id, planes, saturated, reference):
    """Subtract the mean dark/ambient frame (H, W, C) from the planes, in place; its
    saturated pixels are saturated here too."""
    mean = np.load(reference["mean"], mmap_mode="r")
    shape = planes[0].shape + (len(planes),)
    if mean.shape != shape:
        raise PsrigError(f"frame {frame_id!r}: size {shape} differs from the "
                         f"{reference['kind']} frame's {mean.shape}")
    for channel, plane in enumerate(planes):
        plane -= mean[:, :, channel]
    saturated |= np.load(reference["saturated"], mmap_mode="r")
    return saturated


def _decode(task):
    """Decode a task's frame (or merge its exposures: a ``merge`` task) into an
    :class:`ExrBuffer`; returns (exr, planes, saturated, info)."""
    options = check_options(**task["options"])
    height, width = task["size"]
    if "merge" in task:
        exposures = [_exposure(member, options, (height, width), task.get("decided"))
                     for member in task["merge"]]
        return _buffered(*merge_linear(task, exposures), (height, width))
    source = task["source"]
    if (options["method"], options["channels"], options["binning"]) == ("mosaic", "rgb", 1) \
            and os.path.isfile(source) and frame_format(source).kind == "raw":
        # The default path: demosaic straight into the file's bytes.
        exr = _exr_buffer(height, width, _RGB)
        planes = [exr.planes[name] for name in _RGB]
        _, saturated, info = decode_raw(source, out=planes,
                                        scratch=_workspace.setdefault("decoder", {}))
        return exr, planes, saturated, info
    linear, saturated, info = decode_frame(source, **{k: options[k] for k in ("method", "channels",
                                                                              "binning", "gamma")},
                                           decided=task.get("decided"))
    return _buffered(linear, saturated, info, (height, width))


def _exposure(member, options, size, decided=None):
    """(linear (H, W, C), saturated (H, W), info) of one exposure of a merge task: decoded
    from its raw file minus its reference, or read from its decoded outputs."""
    if "linear" in member:
        return read_image(member["linear"]), read_mask(member["saturation"]), {}
    source = member["source"]
    linear, saturated, info = decode_frame(source, **{k: options[k] for k in ("method", "channels",
                                                                              "binning", "gamma")},
                                           decided=decided)
    _check_size(linear, size)
    if member.get("reference"):
        planes = [linear[:, :, channel] for channel in range(linear.shape[2])]
        saturated = _subtract(member["id"], planes, saturated, member["reference"])
    return linear, saturated, {**info, "file": member["file"]}


def _check_size(linear, size):
    if tuple(linear.shape[:2]) != tuple(size):
        raise PsrigError(f"decoded to {linear.shape[:2]}, expected {tuple(size)} like the other frames")


def _buffered(linear, saturated, info, size):
    """(exr, planes, saturated, info) of a decoded (H, W, C) frame copied into this process's
    reusable :class:`ExrBuffer`."""
    height, width = size
    _check_size(linear, size)
    names = _RGB if linear.shape[2] == 3 else ("Y",)
    exr = _exr_buffer(height, width, names)
    exr.fill(linear, names)
    return exr, [exr.planes[name] for name in names], saturated, info


def _exr_buffer(height, width, names):
    """This process's reusable :class:`ExrBuffer` for that size and channels."""
    key = (height, width, tuple(names))
    if _workspace.get("exr_key") != key:
        _workspace["exr"] = None  # free the old one first
        _workspace["exr"], _workspace["exr_key"] = ExrBuffer(height, width, names), key
    return _workspace["exr"]


def release_workspace():
    """Free this process's reused buffers and writer thread (after the last frame of a run)."""
    global _io
    _workspace.clear()
    if _io is not None:
        _io.shutdown()
        _io = None


def decode_task(task, *, commit=True):
    """Decode one frame and write its outputs.

    Parameters
    ----------
    task : dict
        ``id``, ``source`` (frame file), ``linear`` and ``saturation`` (output paths),
        ``options`` (for :func:`decode_frame`), ``reference`` (None or dict with ``kind``,
        ``mean`` and ``saturated`` .npy paths), ``size`` (expected (H, W)) and ``decided``
        (None or what ``--gamma auto`` decided for 8-bit files declaring no transfer); or, instead of
        ``source`` and ``reference``, ``merge`` (the exposures of a bracket, each decoded
        here or read from its outputs) and ``reference_shutter``
        (:func:`pipeline.decode.merge.merge_task`).
    commit : bool
        True: the outputs are in place (fsync, rename) on return. False: they are written to
        temporary files beside them, returned in ``temps`` for :func:`pipeline.core.atomic.atomic_commit`.

    Returns
    -------
    (id, info or None, error message or None, hashes, temps)
        ``hashes`` = {output path: sha256 hex} of the two files, ``temps`` = {output path:
        temporary file} still to commit (both {} on failure).
    """
    temps = {}
    try:
        exr, planes, saturated, info = _decode(task)
        if task.get("reference"):
            saturated = _subtract(task["id"], planes, saturated, task["reference"])
        data, info["exr"] = encode_exr(exr, task["options"].get("compression", "auto"),
                                       task["options"].get("half", False))
        writing = _io_thread().submit(_write, task["linear"], data, commit)
        try:
            digest = hashlib.sha256(data).hexdigest()
            mask = encode_saturation(np.ascontiguousarray(saturated, dtype=bool))
            temps[task["saturation"]] = _write(task["saturation"], mask, commit)
        finally:
            temps[task["linear"]] = writing.result()
        hashes = {task["linear"]: digest, task["saturation"]: hashlib.sha256(mask).hexdigest()}
        # The EXR is committed first: a frame whose EXR cannot be written leaves no mask.
        temps = {path: temps[path] for path in hashes}
    except PsrigError as exc:
        for tmp in temps.values():
            if tmp is not None:
                discard_temp(tmp)
        message = str(exc)
        if f"{task['id']!r}" not in message:
            message = f"frame {task['id']!r}: {message}"
        return task["id"], None, message, {}, {}
    return task["id"], info, None, hashes, ({} if commit else temps)


def _context():
    # Workers start from a clean single-threaded server (no inherited OpenImageIO/OpenEXR
    # threads) that has already imported the decoder.
    return worker_context(preload=["pipeline.decode.pool"])


def prepare_pool():
    """Launch the fork server now, without waiting for it: it imports the decoder (about
    0.3 s) in its own process while the caller goes on (hashing inputs, reading headers), and
    the workers of :func:`start_pool` then fork from it at once. It serves this process until
    it exits, as it would after the first pool anyway."""
    _context()


def start_pool(jobs):
    """A process pool of up to ``jobs`` decode workers (started as tasks arrive), each killed
    as soon as this process ends (:func:`pipeline.core.lock.watch_lifeline`).

    Use it as a context manager and pass it to :func:`run_tasks` to reuse the same workers
    for several batches (reference frames, then lit frames).
    """
    context = _context()
    return futures.ProcessPoolExecutor(max_workers=jobs, mp_context=context,
                                       initializer=_init_worker, initargs=(lifeline(context),))


def run_tasks(tasks, *, jobs=None, show=True, desc="decode", pool=None, on_done=None, on_tick=None):
    """Run :func:`decode_task` over ``tasks``: in ``pool`` when given, else in-process for
    one job and in a new pool for more. Returns once every output is on disk.

    Parameters
    ----------
    on_done : callable, optional
        ``on_done(frame_id, info, error, hashes)``, called in this thread for each frame as soon
        as its outputs are on disk (or it failed), so the caller can record it before the rest
        are done.
    on_tick : callable, optional
        Called in this thread about every :data:`TICK` seconds while pooled frames are
        decoded, so the caller can record frames reported a while ago.

    Returns
    -------
    dict
        {frame id: (info or None, error or None, {output path: sha256})}
    """
    jobs = min(jobs or os.cpu_count() or 1, len(tasks))
    bar = progress(total=len(tasks), desc=desc, unit="frame", disable=None if show else True)
    finished = _Finished(on_done, on_tick)
    # fsync mostly waits on the disk (GIL released): a few threads keep it busy while the
    # next frames are decoded (in the pool, or here with one job).
    with bar, futures.ThreadPoolExecutor(max_workers=max(jobs, 2),
                                         thread_name_prefix="psrig-commit") as committer:
        try:
            if pool is None and jobs <= 1:
                _run_here(tasks, finished, committer, bar)
            else:
                with (start_pool(jobs) if pool is None else contextlib.nullcontext(pool)) as running:
                    _run_pooled(running, tasks, finished, committer, bar)
        finally:
            # also when interrupted: what is on disk is reported, so that it is recorded
            finished.drain(wait=True)
    return finished.results


def _receipt(task, outcome):
    """The receipt of a decoded frame (its task's ``receipt`` with the info and the outputs'
    hashes), or None."""
    info, error, hashes = outcome[:3]
    if error or not task.get("receipt"):
        return None
    return {**task["receipt"], "info": info, "outputs": {os.path.basename(p): h for p, h in hashes.items()}}


def _run_here(tasks, finished, committer, bar):
    try:
        for task in tasks:
            finished.drain()   # what is committed is reported before the next frame starts
            frame_id, *outcome = decode_task(task, commit=False)
            with deferred_interrupt():   # a commit started is a commit reported
                finished.add(frame_id, tuple(outcome),
                             committer.submit(_commit, outcome[3], _receipt(task, outcome)))
            bar.update()
    finally:
        release_workspace()  # this is the caller's process: give the memory back


#: Seconds between looks at the commits of a pooled decode while no frame arrives: a frame
#: committed is reported (and recorded when due) within this time, not when the next one arrives.
TICK = 0.25


def _run_pooled(running, tasks, finished, committer, bar):
    # submitting starts the workers: an interrupt while one is being started left it reading
    # semaphores its parent had removed by then (a traceback); it is held until all are started
    with deferred_interrupt():
        pending = {running.submit(decode_task, task, commit=False): task for task in tasks}
    try:
        waiting = set(pending)
        while waiting:
            done, waiting = futures.wait(waiting, timeout=TICK, return_when=futures.FIRST_COMPLETED)
            for future in done:
                outcome = _outcome(future)
                task = pending[future]
                with deferred_interrupt():   # a commit started is a commit reported
                    finished.add(task["id"], outcome, committer.submit(_commit, outcome[3], _receipt(task, outcome)))
                bar.update()
            finished.drain()
            finished.tick()
    except BaseException:
        for future in pending:  # interrupted: start no further frame
            future.cancel()
        raise


class _Finished:
    """Frames decoded whose commits may still run: each is reported (``on_done``) and kept in
    ``results`` once its commit is over, in the order the frames finished."""

    def __init__(self, on_done, on_tick=None):
        self.on_done, self.on_tick, self.waiting, self.results = on_done, on_tick, [], {}

    def tick(self):
        """Let the caller record what is due while no frame arrives."""
        if self.on_tick is not None:
            with deferred_interrupt():
                self.on_tick()

    def add(self, frame_id, outcome, commit):
        self.waiting.append((frame_id, outcome, commit))
        self.drain()

    def drain(self, wait=False):
        while self.waiting and (wait or self.waiting[0][2].done()):
            futures.wait([self.waiting[0][2]])   # Ctrl-C still ends this wait
            with deferred_interrupt():   # ... but never splits a committed frame from its report
                frame_id, (info, error, hashes, _), commit = self.waiting.pop(0)
                failure = commit.result()
                error = error or (failure and f"frame {frame_id!r}: {failure}")
                self.results[frame_id] = (None, error, {}) if error else (info, None, hashes)
                if self.on_done is not None:
                    self.on_done(frame_id, *self.results[frame_id])


@contextlib.contextmanager
def deferred_interrupt():
    """Hold a Ctrl-C (SIGINT) back until the block is over, then raise it.

    A Ctrl-C lands between any two bytecodes of the main thread: between a frame's commit being
    queued and its being listed, or between its listing and its report, it left a decoded frame
    on disk that the interrupted run's record did not list (seen once in a full test run).
    Elsewhere than in the main thread (where Python delivers signals) this does nothing.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    held = []
    # SIGTERM too: the command line turns it into an interrupt (pipeline.cli)
    previous = {sig: signal.signal(sig, lambda number, frame: held.append((number, frame)))
                for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        if held:
            number, frame = held[0]
            handler = previous[number]
            if callable(handler):
                handler(number, frame)
            elif handler == signal.SIG_DFL and number == signal.SIGINT:
                raise KeyboardInterrupt
            elif handler == signal.SIG_DFL:
                signal.raise_signal(number)


def _outcome(future):
    """(info, error, hashes, temps) of a finished pool task."""
    try:
        _, info, error, hashes, temps = future.result()
    except Exception as exc:  # a crashed worker (LibRaw abort on a corrupt file) fails its frame only
        return None, f"decoder crashed: {type(exc).__name__}: {exc}", {}, {}
    return info, error, hashes, temps
