"""The decode stage: every frame of a session -> ``linear/<id>.exr`` + ``linear/<id>_sat.png``.

Dark, ambient and outline frames are decoded as they are. Lit frames (object, sphere, target) have the
mean ambient frame subtracted when the session has one (it already holds the dark signal), else
the mean dark frame when it has one. A frame that cannot be decoded is recorded under
``failed`` (status 'partial') while the others are decoded; a rerun decodes only what is
missing or stale. Raw files are only read.

Exposure brackets (:mod:`pipeline.core.brackets`): each exposure has the ambient (else dark) frames
shot at ITS shutter time subtracted (a lit exposure for which the session has references only
at other shutter times is refused, named: a dark signal grows with the exposure), and the
exposures of each group are merged into ``linear/<group>.exr`` (:mod:`pipeline.decode.merge`),
recorded under ``merged`` ({group: exposures, shutters, reference shutter, share of pixels
from each, measured ratios}). Lit exposures are decoded and merged in one worker task (only
the merge is written); dark, ambient and outline exposures are decoded to ``linear/`` first
(references are means of them), then merged. A group with an exposure missing, failed or
without a reference of its shutter is not merged (``failed``). Merges are reused by the next
run while what they read is unchanged, so a re-shot exposure re-merges its group only.

Defaults: the unbiased ``mosaic`` path at full size (``binning=1``, bilinear demosaic, which is
linear and unbiased away from sharp edges). ``binning=2`` interpolates nothing and is faster
at half the resolution (a quarter of the output to write and hash).

With ``jobs`` > 1 the frames are decoded in a ``forkserver`` process pool (one pool for the
reference frames and the lit frames); like any multiprocessing code, a calling script needs an
``if __name__ == "__main__":`` guard. Workers demosaic straight into the bytes of the output EXR,
hash what they write and leave the fsync-and-rename of each file to threads of this process
(:mod:`pipeline.decode.pool`), so the stage record's hashes come without reading any output
back. 12 MP frames, 2 cores, jobs 2 (benchmarks/decode.py, load average about 2): about
0.2 s per frame at full size, CPU about 0.28 s per frame (decode 0.15, sha256 0.08).
"""

import contextlib
import json
import os
import shutil
import time

from .autotransfer import decide_transfer
from .record import assumed, describe as describe_record, recorded_kwargs
from .transfer import describe_transfer, undeclared_8bit
from .frame import check_options, decode_frame, frame_size
from .merge import decoded_inputs, lit_inputs, merge_task, unmergeable
from .pool import prepare_pool, run_tasks, start_pool
from .references import REFERENCE_KINDS, previous_references, references, shutter_label, write_reference
from ..core.brackets import bracket_groups, frame_shutter, reference_shutter
from ..core.atomic import sweep_tree
from ..core.errors import InputError, PsrigError, StageError
from ..core.paths import DECODE_SCRATCH
from ..settings.decode import DecodeOptions
from ..core.stage import Stage
from ..core.yamlio import plain

__all__ = ["decode_frame", "decode_session", "REFERENCE_KINDS", "DecodeStage", "DECODE"]

#: An interrupted run loses at most this many manifest saves' worth of decoding (see _Run).
RECORD_SHARE = 20
#: ... and at most this many seconds' worth, however long a save takes.
RECORD_INTERVAL = 1.0
_LIT_KINDS = ("object", "sphere", "target")


def _verify(session, frames):
    """{raw rel: sha256} of present frame files and {id: reason} of missing ones.

    A file whose hash differs from the manifest stops the stage: captures must not change.
    """
    inputs, failed = {}, {}
    for frame in frames:
        if not session.path(frame["file"]).is_file():
            failed[frame["id"]] = f"{frame['file']}: raw file of frame {frame['id']!r} is missing"
            continue
        inputs[frame["file"]] = session.verify_frame(frame)
    session.hashes.save()
    return inputs, failed


def _sizes(session, frames, binning, failed):
    """Output size of every frame not failed yet; unreadable headers join ``failed``."""
    sizes = {}
    for frame in frames:
        if frame["id"] in failed:
            continue
        try:
            sizes[frame["id"]] = frame_size(session.path(frame["file"]), binning)
        except PsrigError as exc:
            failed[frame["id"]] = str(exc)
    distinct = sorted(set(sizes.values()))
    if len(distinct) > 1:
        examples = ", ".join(f"{next(i for i, s in sizes.items() if s == size)} is "
                             f"{size[1]}x{size[0]}" for size in distinct)
        raise StageError(f"{session.root}: frames differ in size ({examples}); all frames of "
                         "a session must have the same size")
    return sizes


def _reusable(session, previous, params, inputs, frame, references):
    """True when the previous run's outputs of ``frame`` are still valid (a previous run that was
    interrupted included: its record lists the frames it finished); ``references`` are the
    frames subtracted from it now (lit frames)."""
    if not previous or previous.get("params") != params or not _same_raw(previous, inputs, frame):
        return False
    if frame["kind"] in _LIT_KINDS:
        if previous_references(previous, frame["kind"]) != [f["id"] for f in references]:
            return False
        # a re-shot dark or ambient frame changes what is subtracted: decode again
        if not all(_same_raw(previous, inputs, f) for f in references):
            return False
    return _outputs_intact(session, previous, frame)


def _same_raw(previous, inputs, frame):
    """True when ``previous`` decoded ``frame`` from this very file (not one another frame's
    ``file:`` now names) with this hash."""
    return (previous.get("inputs", {}).get(frame["file"]) == inputs.get(frame["file"])
            and (previous.get("frames") or {}).get(frame["id"], {}).get("file") == frame["file"])


def _outputs_intact(session, previous, frame):
    """True when the outputs of ``frame`` (dict or id) are on disk as ``previous`` recorded them."""
    recorded = previous.get("outputs", {})
    for path in (session.linear_path(frame), session.saturation_path(frame)):
        rel = session.rel(path)
        if rel not in recorded or not path.is_file() or session.hash_inputs([rel])[rel] != recorded[rel]:
            return False
    return True


def _merge_reusable(session, previous, params, group, digest):
    """True when the previous run merged ``group`` from what ``digest`` (:mod:`.merge`) covers,
    and its outputs are intact."""
    if not previous or previous.get("params") != params:
        return False
    entry = (previous.get("merged") or {}).get(group.id) or {}
    return entry.get("inputs_sha256") == digest and _outputs_intact(session, previous, group.id)


def _task(session, frame, options, size, reference=None, receipt=None, decided=None):
    return {"id": frame["id"], "source": str(session.path(frame["file"])),
            "linear": str(session.linear_path(frame)),
            "saturation": str(session.saturation_path(frame)),
            "options": options, "size": size, "reference": reference, "receipt": receipt,
            "decided": _decision(decided)}


def receipt_path(session, frame_id):
    """Where a frame's receipt lies until the stage record lists the frame: hidden, in linear/."""
    return session.linear_path(frame_id).with_name(f".{frame_id}.receipt.json")


def _receipt_base(session, params, inputs, frame, references, decided=None):
    """What a frame's receipt says before it is decoded: its file and hash, the options, the
    frames subtracted from it (ids, files, hashes) and the transfer decided from the data."""
    return {"path": str(receipt_path(session, frame["id"])), "frame": frame["id"], "file": frame["file"],
            "source_sha256": inputs.get(frame["file"]), "params": plain(params),
            "references": [[f["id"], f["file"], inputs.get(f["file"])] for f in references],
            "decided": plain(_decision(decided))}


def _adoptable(session, params, inputs, frame, references, decided=None):
    """(info, {output rel: sha256}) of a frame a killed run decoded and renamed into place but
    did not record, from its receipt, when the receipt matches this run (same file and hash,
    options and subtracted frames) and the outputs on disk still have its hashes; else None."""
    path = receipt_path(session, frame["id"])
    try:
        receipt = json.loads(path.read_text(encoding="utf-8"))
        base = _receipt_base(session, params, inputs, frame, references, decided)
        if any(receipt.get(key) != base[key] for key in ("frame", "file", "source_sha256", "params", "references",
                                                          "decided")):
            return None
        outputs = {}
        for output in (session.linear_path(frame), session.saturation_path(frame)):
            rel = session.rel(output)
            digest = receipt["outputs"][output.name]
            if not output.is_file() or session.hash_inputs([rel])[rel] != digest:
                return None
            outputs[rel] = digest
        return dict(receipt["info"]), outputs
    except (OSError, ValueError, KeyError, TypeError, AttributeError, PsrigError):
        return None


def _decision(decided):
    """What a decoded frame depends on of a transfer decision (a record's or a new one)."""
    return {"transfer": decided["transfer"], "why": decided["why"]} if decided else None


def _decide_transfer(session, frames, params, failed):
    """``--gamma auto`` for 8-bit image frames that declare no transfer: decided from the
    object frames (:mod:`.autotransfer`); None when the option names a transfer, when no
    object frame is such a file, or when there are too few of them to tell."""
    if params["gamma"] != "auto":
        return None
    objects = [f for f in frames if f["kind"] == "object" and f["id"] not in failed]
    paths = [session.path(f["file"]) for f in objects]
    if not paths or not undeclared_8bit(paths[0]):
        return None
    # what decode subtracts from the object frames (ambient, else dark) is in the model too
    kind = "ambient" if any(f["kind"] == "ambient" for f in frames) else "dark"
    unlit = [session.path(f["file"]) for f in frames if f["kind"] == kind and f["id"] not in failed
             and f.get("bracket") is None]
    unlit = unlit if unlit and all(undeclared_8bit(p) for p in unlit) else []
    return decide_transfer([p for p in paths if undeclared_8bit(p)], unlit)


class _Run:
    """State of one decode run: options, hashes, what succeeded (infos) and what failed.

    Each frame is recorded in the stage record (status 'incomplete') soon after its outputs are
    on disk, so a run interrupted at any moment is resumed by the next one from there: the
    record is saved after a frame unless the last save was less than :data:`RECORD_SHARE`
    saves ago (a manifest save costs about 10 ms; 12 MP frames take 0.25 s each), and always
    when the run is interrupted by Ctrl-C or an error.
    """

    def __init__(self, session, params, inputs, sizes, failed, previous, jobs, show, decided=None):
        self.session, self.params, self.inputs, self.sizes = session, params, inputs, sizes
        self.failed, self.jobs, self.show = failed, jobs, show
        self.decided = decided  # what --gamma auto decided from the data (autotransfer), or None
        if previous and _decision(previous.get("transfer_decision")) != _decision(decided):
            previous = None  # frames decoded under another decided transfer are not reusable
        self.previous = previous
        self.frames = session.frames()
        self.files = {f["id"]: f["file"] for f in self.frames}
        self.reference_shutter = reference_shutter(self.frames)  # what every merge is scaled to
        self.infos = {}
        self.hashes = {}  # {output rel: sha256} of every output of a frame in infos (or merged)
        self.merged = {}  # {bracket group: what its merge did (merge.merge_linear's info + inputs)}
        self.merge_inputs = {}  # {bracket group: sha256 of what its queued merge reads}
        self.subtracted = {}
        self.tasks = []
        self.pool = None
        self.started = time.perf_counter()
        self.unrecorded = 0  # frames finished since the stage record was last saved
        self.saved_at, self.save_cost = 0.0, 0.0
        self.receipts = []  # receipts of frames finished since the record was last saved
        self.adopted = []  # frames a killed run left decoded, taken from their receipts
        self.force = False

    def decode(self, frames, reference=None, references=()):
        """Decode the frames whose outputs are not reusable; collect infos and failures."""
        self.queue(frames, reference, references)
        self.decode_queued()

    def queue(self, frames, reference=None, references=()):
        """Plan the decoding of the frames whose outputs are not reusable (one pool for all);
        ``references`` are the frames whose mean (``reference``) is subtracted from them."""
        for frame in frames:
            if _reusable(self.session, self.previous, self.params, self.inputs, frame, references):
                self.infos[frame["id"]] = self.previous.get("frames", {}).get(frame["id"], {})
                self._keep_outputs(frame["id"])
            elif (adopted := self._adopt(frame, references)) is not None:
                info, outputs = adopted
                self.hashes.update(outputs)
                self.infos[frame["id"]] = {**info, "file": frame["file"]}
                self.adopted.append(frame["id"])
                self.receipts.append(frame["id"])
                self.unrecorded += 1
            else:
                self.tasks.append(_task(self.session, frame, dict(self.params), self.sizes[frame["id"]], reference,
                                        _receipt_base(self.session, self.params, self.inputs, frame, references,
                                                      self.decided), self.decided))

    def _adopt(self, frame, references):
        """A frame's receipt (:func:`_adoptable`), unless decoding is forced."""
        if self.force:
            return None
        return _adoptable(self.session, self.params, self.inputs, frame, references, self.decided)

    def queue_merge(self, group, digest, members):
        """Plan the merge of a bracket ``group`` unless the previous run's still holds
        (``digest``: what it reads, :mod:`.merge`); ``members()`` gives its task's exposures."""
        if _merge_reusable(self.session, self.previous, self.params, group, digest):
            self.merged[group.id] = self.previous["merged"][group.id]
            self._keep_outputs(group.id)
            return
        self.merge_inputs[group.id] = digest
        task = merge_task(self.session, group, members(), self.reference_shutter,
                          dict(self.params), self.sizes[group.frames[0]["id"]])
        self.tasks.append({**task, "decided": _decision(self.decided)})

    def fail_merge(self, group, problem):
        """``group`` cannot be merged: say why, and remove an earlier run's merge of it (of
        other exposures: it must not pass for this one's)."""
        self.failed[group.id] = problem
        for path in (self.session.linear_path(group.id), self.session.saturation_path(group.id)):
            path.unlink(missing_ok=True)

    def _keep_outputs(self, frame_id):
        for path in (self.session.linear_path(frame_id), self.session.saturation_path(frame_id)):
            rel = self.session.rel(path)
            self.hashes[rel] = self.previous["outputs"][rel]

    def decode_queued(self):
        tasks, self.tasks = self.tasks, []
        if not tasks:
            return
        results = run_tasks(tasks, jobs=self.jobs, show=self.show, pool=self._pool(len(tasks)),
                            on_done=self.finished, on_tick=self.record_due)
        if any(error and error.startswith("decoder crashed") for _, error, _ in results.values()):
            self.close()  # a crashed worker breaks its pool: the next batch gets a new one

    def finished(self, frame_id, info, error, hashes):
        """A frame's (or a bracket's merged) outputs are on disk, or it failed: keep it, and
        record it when due."""
        if error:
            self.failed[frame_id] = error
        else:
            # hashes before infos: a Ctrl-C between the two must not leave a frame counted as
            # done without its hashes (the interrupt's own record lists the done frames' hashes)
            self.hashes.update({self.session.rel(path): digest for path, digest in hashes.items()})
            if frame_id in self.merge_inputs:
                self.merged[frame_id] = {**info, "inputs_sha256": self.merge_inputs[frame_id]}
            else:
                self.infos[frame_id] = {**info, "file": self.files[frame_id]}
                self.receipts.append(frame_id)
        self.unrecorded += 1
        self.record_due()

    def record_due(self):
        """Record the frames finished since the last save when :data:`RECORD_SHARE` saves'
        worth of time, or :data:`RECORD_INTERVAL`, has passed since it."""
        if self.unrecorded and time.perf_counter() - self.saved_at >= min(RECORD_SHARE * self.save_cost,
                                                                         RECORD_INTERVAL):
            self.record_progress()

    def record_progress(self):
        """Save the frames finished so far as an 'incomplete' stage record (if any is new)."""
        if not self.unrecorded:
            return
        start = time.perf_counter()
        _record(self.session, self.frames, self, time.perf_counter() - self.started, status="incomplete")
        self.saved_at = time.perf_counter()
        self.save_cost, self.unrecorded = self.saved_at - start, 0
        self.drop_receipts()

    def drop_receipts(self):
        """Remove the receipts of the frames the saved record lists (they are its now)."""
        for frame_id in self.receipts:
            receipt_path(self.session, frame_id).unlink(missing_ok=True)
        self.receipts = []

    def _pool(self, count):
        """The run's process pool, started on the first batch that needs one and reused for
        the next (starting workers costs about 0.3 s)."""
        jobs = self.jobs or os.cpu_count() or 1
        if self.pool is None and jobs > 1 and count > 1:
            self.pool = start_pool(jobs)
        return self.pool

    def close(self):
        """Stop the pool's workers (they exit; the fork server stays for later runs)."""
        if self.pool is not None:
            self.pool.shutdown()
            self.pool = None

    def needs_work(self, frames, references):
        return any(not _reusable(self.session, self.previous, self.params, self.inputs, f, references)
                   and self._adopt(f, references) is None for f in frames)


def decode_session(session, *, method="mosaic", channels="rgb", binning=1, gamma="auto",
                   compression="auto", half=False, jobs=None, force=False, progress=True):
    """Decode every frame of a session into ``linear/``.

    Parameters
    ----------
    session : Session
    method, channels, binning, gamma
        As for :func:`decode_frame`; recorded as the stage's params.
    compression : {'auto', 'zip', 'none'}
        How ``linear/`` EXRs are written (:func:`pipeline.decode.exr.encode_exr`).
    half : bool
        Half-float EXRs (lossy) instead of float32.
    jobs : int, optional
        Worker processes (default: one per core; 1 decodes in this process).
    force : bool
        Decode everything again even when the stage record is current.
    progress : bool
        Show a progress bar on stderr.

    Returns
    -------
    dict
        The stage record: status 'ok', 'partial' (``failed`` = {frame id: reason}) or
        'failed'; ``subtracted`` (kind and frame ids; ``by_shutter`` for brackets),
        ``frames_not_raw``, per-frame ``frames`` info, ``merged`` ({bracket group: info},
        bracketed sessions only), ``seconds``, and what was assumed: ``transfer`` ({transfer and why: frame ids} of
        image files), ``postprocessed`` ({sensor: frame ids} of raw files the mosaic path
        cannot decode), ``linear_bytes`` and ``compression`` ({'zip' or 'none': count});
        ``transfer_decision`` when ``gamma='auto'`` decided the transfer of 8-bit files
        that declare none from the object frames (:func:`.autotransfer.decide_transfer`:
        chosen transfer, whether a guess, the candidates' rank-3 residuals, the message).
    """
    start = time.perf_counter()
    params = check_options(method, channels, binning, gamma, compression, half)
    if jobs is not None and (isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1):
        raise InputError(f"jobs: expected a number of processes >= 1, got {jobs!r}")
    binning = params["binning"]
    frames = session.frames()
    if not frames:
        raise StageError(f"{session.root}: the session has no frames to decode")
    pooled = (jobs or os.cpu_count() or 1) > 1 and len(frames) > 1
    if pooled and force:
        prepare_pool()  # the fork server boots while the inputs are hashed
    inputs, failed = _verify(session, frames)
    # what decode reads from the manifest: which file each frame is, its kind (what is
    # subtracted from it) and an ambient frame's applies_to
    # (and each exposure's bracket, for bracketed sessions only: other records stay current)
    keys = ("id", "kind", "file", "applies_to") + (("bracket",) if bracket_groups(frames) else ())
    inputs.update(session.manifest_input("decode", frames, keys))
    if not force and not failed and session.stage_is_current("decode", params, inputs):
        return session.stage("decode")
    if pooled:
        prepare_pool()  # ... or while the headers are read (no-op when already running)
    sizes = _sizes(session, frames, binning, failed)
    decided = _decide_transfer(session, frames, params, failed)
    run = _Run(session, params, inputs, sizes, failed, None if force else session.stage("decode"),
               jobs, progress, decided)
    run.started, run.force = start, force
    scratch = session.path(DECODE_SCRATCH)
    try:
        with contextlib.closing(run):
            _decode_all(session, frames, run, scratch)
    except BaseException:
        try:
            run.record_progress()  # interrupted: the next run starts from what is on disk
        finally:   # also when that save fails (a full disk, a manifest refused)
            # the pool is shut down: the temporaries its workers were writing are nobody's now
            sweep_tree(session.path("linear"), recursive=False)
        raise
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    record = _record(session, frames, run, time.perf_counter() - start)
    run.drop_receipts()
    return record


def _decode_all(session, frames, run, scratch):
    """The unlit frames (every exposure of a bracket), then each lit kind minus its reference
    (mean ambient or dark frame), and the merges of the brackets: in one batch."""
    unlit = [f for f in frames if f["kind"] not in _LIT_KINDS and f["id"] not in run.failed]
    lit = [f for f in frames if f["kind"] in _LIT_KINDS and f["id"] not in run.failed]
    run.decode(unlit)
    groups = bracket_groups(frames)
    for group in groups:
        if group.kind not in _LIT_KINDS:
            _queue_unlit_bracket(session, run, group)
    for lit_kind in sorted({f["kind"] for f in lit}):
        single = [f for f in lit if f["kind"] == lit_kind and f.get("bracket") is None]
        if single:
            _queue_lit(session, run, unlit, single, lit_kind, scratch / lit_kind / "single")
        brackets = [g for g in groups if g.kind == lit_kind]
        if brackets:
            _queue_lit_brackets(session, run, unlit, brackets, lit_kind, scratch / lit_kind)
    run.decode_queued()


def _queue_lit(session, run, unlit, frames, lit_kind, folder):
    """Queue single-exposure lit ``frames`` of one kind with their reference, and note what
    is subtracted from them."""
    kind, chosen, problem = references(unlit, run.infos, lit_kind)
    if problem:
        for frame in frames:
            run.failed[frame["id"]] = f"frame {frame['id']!r}: {problem}"
        return
    reference = None
    if chosen and run.needs_work(frames, chosen):
        reference = write_reference(session, chosen, kind, folder)
    run.queue(frames, reference, chosen)
    run.subtracted[lit_kind] = {"kind": kind, "frames": [f["id"] for f in chosen]}


def _queue_unlit_bracket(session, run, group):
    """Queue the merge of a dark, ambient or outline bracket from its decoded exposures."""
    problem = unmergeable(group, run.failed)
    digest = None if problem else decoded_inputs(session, group, run.hashes, run.reference_shutter)
    if digest is None:
        run.fail_merge(group, problem or f"frame {group.id!r}: not merged: an exposure was not decoded")
        return
    run.queue_merge(group, digest, lambda: [
        {"id": f["id"], "shutter": shutter, "linear": str(session.linear_path(f)),
         "saturation": str(session.saturation_path(f))} for f, shutter in zip(group.frames, group.shutters)])


def _queue_lit_brackets(session, run, unlit, groups, lit_kind, folder):
    """Queue the merges of lit brackets of one kind: each exposure decoded in the worker minus
    the reference of its own shutter time (written once per shutter, when a merge needs it)."""
    by_label, written = {}, {}
    for group in groups:
        for exposure in group.frames:
            label = shutter_label(exposure)
            if label not in by_label:
                by_label[label] = references(unlit, run.infos, lit_kind, frame_shutter(exposure))
    _note_subtracted(run, lit_kind, by_label)

    def reference_of(label):
        kind, chosen, _ = by_label[label]
        if chosen and label not in written:
            written[label] = write_reference(session, chosen, kind, folder / str(len(written)))
        return written.get(label)

    for group in groups:
        problems = [f"frame {group.id!r} (exposure {f['id']!r}): {by_label[shutter_label(f)][2]}"
                    for f in group.frames if by_label[shutter_label(f)][2]]
        problem = unmergeable(group, run.failed) or "; ".join(problems)
        if problem:
            run.fail_merge(group, problem)
            continue
        chosen = {f["id"]: by_label[shutter_label(f)][1] for f in group.frames}
        digest = lit_inputs(group, run.inputs, chosen, run.reference_shutter)
        run.queue_merge(group, digest, lambda group=group: [
            {"id": f["id"], "shutter": shutter, "file": f["file"], "source": str(session.path(f["file"])),
             "reference": reference_of(shutter_label(f))} for f, shutter in zip(group.frames, group.shutters)])


def _note_subtracted(run, lit_kind, by_label):
    """The record's ``subtracted`` entry of a bracketed lit kind: each shutter's own, and all."""
    entry = {"kind": None, "frames": [], "by_shutter": {}}
    for label, (kind, chosen, _) in by_label.items():
        ids = [f["id"] for f in chosen]
        entry["by_shutter"][label] = {"kind": kind, "frames": ids}
        entry["kind"] = entry["kind"] or kind
        entry["frames"] += [i for i in ids if i not in entry["frames"]]
    run.subtracted[lit_kind] = entry


def _kind_of_file(info):
    """What a decoded frame file was, as the mixed-input warning names it."""
    if info.get("raw", True):
        return "camera raw"
    transfer = f", decoded as {describe_transfer(info['transfer'])}" if "transfer" in info else ""
    return f"{info.get('bits', '?')}-bit {str(info.get('format', 'image')).upper()}{transfer}"


def _mixed_inputs(frames, decoded, named=6):
    """A warning naming the lit frames of one kind whose files differ from the others' (bit
    depth, format, transfer): one 8-bit frame among 16-bit ones is decoded on another scale and
    curve, and the normals stage can only rescale it."""
    warnings = []
    for kind in _LIT_KINDS:
        groups = {}
        for frame in frames:
            if frame["kind"] == kind and frame["id"] in decoded:
                groups.setdefault(_kind_of_file(decoded[frame["id"]]), []).append(frame["id"])
        if len(groups) < 2:
            continue
        usual = max(groups, key=lambda key: len(groups[key]))
        odd = [(key, ids) for key, ids in groups.items() if key != usual]
        listed = "; ".join(f"{', '.join(ids[:named])}{f' and {len(ids) - named} more' if len(ids) > named else ''} "
                           f"{'is' if len(ids) == 1 else 'are'} {key}" for key, ids in odd)
        warnings.append(f"mixed {kind} frames: {listed}, while the other {len(groups[usual])} are {usual}; "
                        "frames of one capture should be one kind of file (was a frame replaced or re-exported?)")
    return warnings


def _record(session, frames, run, seconds, status=None):
    done = [f for f in frames if f["id"] in run.infos]
    merged = {group: run.merged[group] for group in sorted(run.merged)}
    # what each frame decoded here was, whether kept in linear/ (infos) or only merged
    decoded = {**{f["id"]: run.infos[f["id"]] for f in done},
               **{i: e for info in merged.values() for i, e in (info.get("exposures") or {}).items()}}
    # Hashes come from the workers (computed on the bytes they wrote) or from the previous
    # record (checked by _reusable): no output is read back here.
    outputs = {rel: run.hashes[rel] for frame in [f["id"] for f in done] + list(merged)
               for rel in (session.rel(session.linear_path(frame)), session.rel(session.saturation_path(frame)))}
    subtracted = run.subtracted
    status = status or ("ok" if not run.failed else ("partial" if done else "failed"))
    extra = {"merged": merged} if merged else {}
    if run.adopted:   # decoded by a run killed before it recorded them (their receipts)
        extra["adopted"] = list(run.adopted)
    if run.decided:
        extra["transfer_decision"] = run.decided
    warnings = [w for info in merged.values() for w in info.get("warnings") or []]
    warnings += _mixed_inputs(frames, decoded)
    if warnings:  # where psrig run and the report look for them
        extra["warnings"] = warnings
    return session.record_stage(
        "decode", run.params, run.inputs, outputs, status=status, seconds=seconds,
        failed={k: run.failed[k] for k in sorted(run.failed)},
        frames_not_raw=[i for i, info in decoded.items() if not info.get("raw", True)],
        **assumed({**decoded, **merged}),
        # top level: what the object frames got (earlier records' form); by_kind: every lit kind
        subtracted={**subtracted.get("object", {"kind": None, "frames": []}), "by_kind": subtracted},
        frames={f["id"]: run.infos[f["id"]] for f in done}, **extra)


class DecodeStage(Stage):
    """The ``decode`` stage (:class:`pipeline.core.stage.Stage`): :func:`decode_session`."""

    name = "decode"
    Options = DecodeOptions
    reads = ("raw/: every frame the manifest lists (its sha256)",
             "session.yaml: each frame's id, kind, file, applies_to and bracket")

    def work(self, session, options, *, force, jobs):
        before = session.stage(self.name)
        record = decode_session(session, force=force, jobs=jobs, **options)
        # a current record is returned as it was: the same object
        ran = record is not before
        return ran, "; ".join(describe_record(record)) if ran else ""

    def replay(self, record):
        params = (record or {}).get("params")
        return recorded_kwargs(params) if params else {}


#: the stage object the runner and the scheduler run
DECODE = DecodeStage()
